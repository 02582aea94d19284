//! Random numbers of one user-side path: a counter-based hash stream per path, addressed by
//! the caller's key (seed, pixel, and the sample and branch, or the replica and the path's
//! index), the same for any thread count. Optionally the numbers of a path's first vertex come
//! from padded 2-D point sets ([`super::padded`]) shared by a pixel's paths of the same branch
//! contact, so they are stratified over the pixel; each point is marginally uniform, so an
//! estimator using them keeps its expectation. The camera-side driver
//! ([`crate::render`]) makes the keys; the user-side path tracer
//! ([`crate::world::integrator`]) draws from them.

use super::{hash, mix64, to_unit};

/// Random numbers of one user-side path: `hash(key, n)` for n = 1, 2, ….
#[derive(Clone, Copy, Debug)]
pub struct PathRng {
    key: u64,
    n: u64,
    /// Until the first vertex is done: the padded sets' key, this sample's index and the
    /// pixel's sample count.
    padded: Option<(u64, u32, u32)>,
}

impl PathRng {
    /// A stream addressed by `words` (e.g. seed, pixel, sample, branch).
    pub fn new(words: &[u64]) -> PathRng {
        PathRng {
            key: hash(words),
            n: 0,
            padded: None,
        }
    }

    /// The key of the padded sets shared by the samples addressed by `words` (e.g. seed,
    /// pixel, branch contact), for [`Self::with_padded`].
    pub fn padded_key(words: &[u64]) -> u64 {
        // hash(words ++ [tag]), the tag keeping these keys apart from the streams' own.
        mix64(hash(words) ^ mix64(0x00DA_DDED))
    }

    /// The same stream, except that [`Self::pair`] takes point `index` of the `n`-point padded
    /// sets keyed by `key` ([`Self::padded_key`]; with the slot) until
    /// [`Self::end_first_vertex`]. Ignored unless `index` < `n`.
    pub fn with_padded(mut self, key: u64, index: u64, n: u32) -> PathRng {
        if index < u64::from(n) {
            self.padded = Some((key, index as u32, n));
        }
        self
    }

    /// Two numbers in [0, 1) for purpose `slot` (at the first vertex: a light's index, or
    /// [`crate::world::integrator::BSDF_SLOT`]): a padded pair where one is set up, else the next two of the stream.
    #[inline]
    pub fn pair(&mut self, slot: u64) -> [f64; 2] {
        match self.padded {
            Some((key, index, n)) => super::padded::pair(hash(&[key, slot]), index, n),
            None => [self.uniform(), self.uniform()],
        }
    }

    /// One number in [0, 1) for purpose `slot`: the first of a padded pair where one is set
    /// up, else the next of the stream.
    #[inline]
    pub fn single(&mut self, slot: u64) -> f64 {
        match self.padded {
            Some(_) => self.pair(slot)[0],
            None => self.uniform(),
        }
    }

    /// Ends the padded part: later pairs come from the stream.
    #[inline]
    pub fn end_first_vertex(&mut self) {
        self.padded = None;
    }

    /// The key of the ray the path traces next (for stochastic alpha, `crate::world::coverage`):
    /// a hash of the stream's state that does not advance it, so scenes without blended
    /// materials draw exactly the numbers they drew before.
    #[inline]
    pub fn ray_key(&self) -> u64 {
        mix64(self.key ^ mix64(self.n ^ 0xA1FA_0000_0000_0000))
    }

    /// The next uniform number in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        self.n += 1;
        to_unit(mix64(self.key ^ mix64(self.n)))
    }
}
