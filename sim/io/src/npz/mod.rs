//! Hand-written NumPy `.npy` / `.npz` writer and reader, with support for
//! `scipy.sparse` CSR matrices as stored by `scipy.sparse.save_npz`; no Python
//! is needed.
//!
//! The `.npy` layout follows the NumPy format specification
//! (`numpy/lib/format.py`, "A Simple File Format for NumPy Arrays", NEP 1):
//! the magic string `\x93NUMPY`, a major and minor version byte, the length of
//! the header (little-endian `u16` in version 1.0, `u32` in 2.0 and 3.0), and
//! the header itself, a Python dict literal such as
//! `{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }` padded with
//! spaces and terminated by `\n` so that the array data starts at a multiple
//! of 64 bytes. The raw array data follows in C order. We write version 1.0
//! (2.0 only if a header would not fit in 65535 bytes) and read 1.0, 2.0 and
//! 3.0, little-endian and C-order data only (Fortran order is accepted where it
//! is the same layout, for 0-d and 1-D arrays).
//!
//! A `.npz` file is a zip archive with one `<name>.npy` entry per array.
//! `scipy.sparse.save_npz` (scipy `sparse/_matrix_io.py`) stores a CSR matrix
//! as the entries `format` (a 0-d `|S3` array holding `b"csr"`), `shape`
//! (`<i8`, shape `(2,)`), `data`, `indices`, `indptr` and, for the sparse
//! *array* classes only, a 0-d boolean `_is_array`; `load_npz` reads them back
//! with `np.load(allow_pickle=False)`, so nothing here ever involves pickles.
//! Our writer omits `_is_array` (scipy then builds a `csr_matrix`), stores
//! `indices` and `indptr` with one common dtype (`<i4` when it suffices, as
//! scipy itself would convert them to, otherwise `<i8`), and writes
//! uncompressed entries with fixed timestamps so that equal inputs give
//! byte-identical files. The reader accepts stored and deflated entries
//! (`save_npz` deflates by default), files from `np.save`/`np.savez`, and checks
//! every CSR invariant, reporting anything wrong as [`IoError::Format`] with a
//! one-line message that names the offending entry; it never panics on corrupt
//! input and never allocates more than the input's actual size justifies.
//!
//! [`IoError::Format`]: crate::IoError::Format

mod csr;
mod literal;
mod npy;

pub use self::csr::{
    CsrParts, MAX_MEMBER_BYTES, decode_csr_npz, encode_csr, encode_csr_npz, read_csr_npz,
};
pub use self::npy::{decode_npy_f32, encode_npy_f32, read_npy_f32};

/// Python `repr` of a shape tuple: `()`, `(3,)`, `(2, 3)`.
fn shape_repr(shape: &[usize]) -> String {
    match shape {
        [] => "()".to_owned(),
        [n] => format!("({n},)"),
        _ => {
            let parts: Vec<String> = shape.iter().map(usize::to_string).collect();
            format!("({})", parts.join(", "))
        }
    }
}

/// What the tests of more than one file use.
#[cfg(test)]
mod test_support {
    use std::path::Path;

    pub(super) fn p() -> &'static Path {
        Path::new("test.npz")
    }

    /// Small deterministic generator (SplitMix64).
    pub(super) struct Rng(pub(super) u64);
    impl Rng {
        pub(super) fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        pub(super) fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
    }
}
