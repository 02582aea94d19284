//! Resource limits on sizes a user controls, checked before any work starts.
//!
//! Model: every job's memory is dominated by a few arrays whose sizes follow from the inputs
//! (sensor crop, channels and spectral bins, object size, grid points, samples, frames), and
//! its run time by the number of camera paths (pixels × samples per pixel, times the jobs
//! that repeat it). Each front end estimates these before allocating and refuses, with one
//! line naming the setting, a job beyond the limits below: nothing then aborts on a failed
//! allocation or runs for weeks by accident. The limits are generous for this machine class
//! (tens of GiB of memory, tens of cores) and far above every documented use; jobs larger
//! than them should be split (dataset shards, smaller sweeps).
//! Assumptions: the estimates count the dominant arrays only (within a small factor of the
//! true peak); threads beyond [`MAX_THREADS`] give no speed on any machine this targets.

/// Most worker threads `--threads` accepts.
pub const MAX_THREADS: usize = 1024;

/// Most camera paths (pixels × samples per pixel, summed over the renders of one job): 2^40,
/// about three days at the 4.4 M paths/s of two cores.
pub const MAX_CAMERA_PATHS: u128 = 1 << 40;

/// Largest memory estimate of one job's dominant arrays: 16 GiB.
pub const MAX_JOB_BYTES: u128 = 16 << 30;

/// Working range of user-side coordinates: every vertex, object position and light position
/// must lie within ±`MAX_COORD_MM` (10 km) of the plate, and every size below it. The BVH works
/// in f32 and its builder misbehaves on boxes near f32's overflow; 10 km is far beyond any
/// scene this camera images (its depth of field ends within metres) and keeps f32 boxes exact
/// to ~1 mm there.
pub const MAX_COORD_MM: f64 = 1.0e7;

/// Largest emitted radiance of a surface (RGB component times every scale), relative to the
/// display's white: larger values overflow the f32 images (frontal.exr) once multiplied by a
/// spectrum, and no real emitter in front of a screen is 10¹² times brighter than it.
pub const MAX_EMISSION: f64 = 1.0e12;

/// Most pixels of a texture or environment map (8192 × 4096): decoding holds at most about
/// 32 bytes a pixel at once (the decoded rows, the f32 values and the f32 texels), so a texture
/// takes at most 1 GiB while it is loaded and 12 bytes a pixel (384 MiB) afterwards.
pub const MAX_TEXTURE_PIXELS: usize = 8192 * 4096;

/// Checks that every component of `v` lies within ±[`MAX_COORD_MM`]; `setting` names the key.
pub fn check_coords(setting: &str, v: &[f64]) -> Result<(), LimitError> {
    if v.iter().all(|x| x.abs() <= MAX_COORD_MM) {
        Ok(())
    } else {
        Err(LimitError::new(
            setting,
            format!("{v:?} lies outside the working range of ±{MAX_COORD_MM:e} mm (10 km)"),
        ))
    }
}

/// A job beyond a limit: the setting to blame and what is wrong, on one line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{setting}: {message}")]
pub struct LimitError {
    /// The flag or key the user controls, e.g. `--threads` or `sensor.crop_px`.
    pub setting: String,
    /// What is wrong, with the numbers.
    pub message: String,
}

impl LimitError {
    fn new(setting: &str, message: String) -> Self {
        LimitError {
            setting: setting.to_string(),
            message,
        }
    }
}

/// Checks a `--threads` value: 1..=[`MAX_THREADS`].
pub fn check_threads(threads: usize) -> Result<(), LimitError> {
    if (1..=MAX_THREADS).contains(&threads) {
        Ok(())
    } else {
        Err(LimitError::new(
            "--threads",
            format!("must be in 1..={MAX_THREADS}, got {threads}"),
        ))
    }
}

/// Checks that `paths` camera paths (e.g. pixels × spp × renders) stay within
/// [`MAX_CAMERA_PATHS`]; `setting` names what to lower.
pub fn check_paths(setting: &str, paths: u128) -> Result<(), LimitError> {
    if paths <= MAX_CAMERA_PATHS {
        Ok(())
    } else {
        Err(LimitError::new(
            setting,
            format!(
                "the job needs {paths} camera paths, more than the {MAX_CAMERA_PATHS} accepted (days of tracing); lower the samples per pixel or the crop"
            ),
        ))
    }
}

/// Checks that a memory estimate of `bytes` stays within [`MAX_JOB_BYTES`]; `setting` names
/// what to lower and `what` the arrays concerned.
pub fn check_bytes(setting: &str, what: &str, bytes: u128) -> Result<(), LimitError> {
    if bytes <= MAX_JOB_BYTES {
        Ok(())
    } else {
        Err(LimitError::new(
            setting,
            format!(
                "{what} would need {} GiB, more than the {} GiB accepted",
                crate::numfmt::sig6(bytes as f64 / f64::from(1u32 << 30)),
                MAX_JOB_BYTES >> 30
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_have_a_range() {
        assert!(check_threads(1).is_ok());
        assert!(check_threads(MAX_THREADS).is_ok());
        let e = check_threads(MAX_THREADS + 1).unwrap_err();
        assert_eq!(e.setting, "--threads");
        assert!(e.to_string().contains("1..=1024, got 1025"), "{e}");
        assert!(check_threads(0).is_err());
    }

    #[test]
    fn paths_and_bytes_limits_are_inclusive() {
        assert!(check_paths("--spp", MAX_CAMERA_PATHS).is_ok());
        let e = check_paths("--spp", MAX_CAMERA_PATHS + 1).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("--spp: the job needs 1099511627777")
        );
        assert!(check_bytes("sensor.crop_px", "the capture", MAX_JOB_BYTES).is_ok());
        let e = check_bytes("sensor.crop_px", "the capture", 3 * MAX_JOB_BYTES).unwrap_err();
        assert_eq!(
            e.to_string(),
            "sensor.crop_px: the capture would need 48 GiB, more than the 16 GiB accepted"
        );
    }
}
