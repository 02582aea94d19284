//! The parallel row loop that every image-shaped job shares (the render, H and its depth stack,
//! the camera-side table, the frontal ground truth): rows on the current rayon pool, the results
//! returned in row order (so every reduction over them runs in a fixed order and the output is
//! the same for any thread count), one progress tick per finished row, and cancellation checked
//! once per row before the row's work starts.

use rayon::prelude::*;

use crate::cancel::Token;
use crate::progress::Progress;

/// Runs `row(r)` for every `r` in `0..n` in parallel and returns the results in row order.
/// Once `cancel` is set, rows not yet started return `skipped(r)` without work (the job's
/// result is then discarded by its front end). Progress over the rows is shown under `what`
/// when `show` (a bar on a terminal, plain lines otherwise).
pub fn par_rows<T: Send>(
    n: usize,
    show: bool,
    what: &str,
    cancel: &Token,
    row: impl Fn(usize) -> T + Sync + Send,
    skipped: impl Fn(usize) -> T + Sync + Send,
) -> Vec<T> {
    let pb = Progress::new(show, n as u64, what);
    let out = (0..n)
        .into_par_iter()
        .map(|r| {
            if cancel.is_cancelled() {
                return skipped(r);
            }
            let v = row(r);
            pb.inc(1);
            v
        })
        .collect();
    pb.finish_and_clear();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

    /// Results come back in row order for any pool size, and a set flag skips every row.
    #[test]
    fn rows_in_order_and_cancelled_rows_skipped() {
        for threads in [1, 2, 5] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let v = pool.install(|| {
                par_rows(
                    100,
                    false,
                    "rows",
                    &Token::default(),
                    |r| r * r,
                    |_| usize::MAX,
                )
            });
            assert_eq!(v, (0..100).map(|r| r * r).collect::<Vec<_>>());
        }
        let flag = Arc::new(AtomicBool::new(true));
        let worked = AtomicUsize::new(0);
        let token = crate::cancel::with_flag(flag, crate::cancel::current);
        let v = par_rows(
            10,
            false,
            "rows",
            &token,
            |r| {
                worked.fetch_add(1, Ordering::Relaxed);
                r
            },
            |_| 7,
        );
        assert_eq!(v, vec![7; 10]);
        assert_eq!(worked.load(Ordering::Relaxed), 0);
    }
}
