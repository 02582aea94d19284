//! Shards: the part of a dataset one run makes (`I/N`, or from a cluster engine's environment).

use serde::{Deserialize, Serialize};

/// Which part of a dataset a run makes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Index, 0-based.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

/// Most shards of one dataset (a SLURM array holds at most a few hundred thousand tasks; a
/// larger N is a typo, and every shard writes a manifest).
pub const MAX_SHARDS: usize = 1_000_000;

impl Shard {
    /// Parses `I/N` (0 ≤ I < N ≤ [`MAX_SHARDS`]).
    pub fn parse(spec: &str) -> Result<Shard, String> {
        let (i, n) = spec
            .split_once('/')
            .ok_or_else(|| format!("{spec:?} is not I/N"))?;
        let (i, n) = (
            i.trim()
                .parse::<usize>()
                .map_err(|_| format!("{spec:?}: I is not an integer"))?,
            n.trim()
                .parse::<usize>()
                .map_err(|_| format!("{spec:?}: N is not an integer"))?,
        );
        if n == 0 || i >= n {
            return Err(format!("{spec:?}: need 0 <= I < N"));
        }
        if n > MAX_SHARDS {
            return Err(format!("{spec:?}: N must be at most {MAX_SHARDS}"));
        }
        Ok(Shard { index: i, count: n })
    }

    /// The shard from the environment of a cluster engine: SLURM job arrays
    /// (`SLURM_ARRAY_TASK_ID` − `SLURM_ARRAY_TASK_MIN`, `SLURM_ARRAY_TASK_COUNT`) or a
    /// Kubernetes Indexed Job (`JOB_COMPLETION_INDEX`, with the count in
    /// `STSCAM_SHARD_COUNT`). `None` if neither is set.
    pub fn from_env(get: impl Fn(&str) -> Option<String>) -> Result<Option<Shard>, String> {
        let num = |k: &str| -> Result<Option<usize>, String> {
            match get(k) {
                None => Ok(None),
                Some(v) => v
                    .trim()
                    .parse::<usize>()
                    .map(Some)
                    .map_err(|_| format!("environment variable {k}={v:?} is not an integer")),
            }
        };
        if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let count = num("SLURM_ARRAY_TASK_COUNT")?
                .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let index = id
                .checked_sub(min)
                .ok_or("SLURM_ARRAY_TASK_ID is below SLURM_ARRAY_TASK_MIN")?;
            return Shard::parse(&format!("{index}/{count}"))
                .map(Some)
                .map_err(|e| format!("from SLURM_ARRAY_TASK_*: {e} (use a contiguous --array)"));
        }
        if let Some(index) = num("JOB_COMPLETION_INDEX")? {
            let count = num("STSCAM_SHARD_COUNT")?.ok_or(
                "JOB_COMPLETION_INDEX is set but STSCAM_SHARD_COUNT (the Job's completions) is not",
            )?;
            return Shard::parse(&format!("{index}/{count}"))
                .map(Some)
                .map_err(|e| format!("from JOB_COMPLETION_INDEX: {e}"));
        }
        Ok(None)
    }

    /// Sample ids of this shard among `samples`.
    pub fn range(&self, samples: usize) -> std::ops::Range<usize> {
        self.index * samples / self.count..(self.index + 1) * samples / self.count
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_ranges_tile_the_samples() {
        for samples in [1, 7, 300] {
            for count in 1..6 {
                let mut next = 0;
                for index in 0..count {
                    let r = Shard { index, count }.range(samples);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, samples);
            }
        }
        assert!(Shard::parse("3/3").is_err());
        assert_eq!(Shard::parse("2/3").unwrap(), Shard { index: 2, count: 3 });
        assert!(Shard::parse("0/1000000").is_ok());
        let e = Shard::parse("0/1000000000000").unwrap_err();
        assert!(e.contains("at most 1000000"), "{e}");
    }

    #[test]
    fn shard_from_cluster_environments() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| pairs.iter().find(|p| p.0 == k).map(|p| p.1.to_string())
        };
        assert_eq!(Shard::from_env(env(&[])).unwrap(), None);
        assert_eq!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "5"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("SLURM_ARRAY_TASK_MIN", "3")
            ]))
            .unwrap(),
            Some(Shard { index: 2, count: 4 })
        );
        assert_eq!(
            Shard::from_env(env(&[
                ("JOB_COMPLETION_INDEX", "1"),
                ("STSCAM_SHARD_COUNT", "3")
            ]))
            .unwrap(),
            Some(Shard { index: 1, count: 3 })
        );
        assert!(Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "1")])).is_err());
        assert!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "4"),
                ("SLURM_ARRAY_TASK_COUNT", "4")
            ]))
            .is_err()
        );
    }
}
