//! Progress of long jobs on stderr: a bar on a terminal, a plain line at most every
//! [`DEFAULT_INTERVAL_S`] seconds otherwise (CI and batch-system logs), nothing when hidden.
//!
//! Model: a job announces its length in units (rows, samples, grid points, frames) and
//! counts finished units from any thread. On a terminal an `indicatif` bar redraws in place;
//! when stderr is not a terminal one line `WHAT: DONE/TOTAL (P %), T s elapsed, ETA E s` is
//! printed when at least the interval has passed since the last line (the first after one
//! interval), so a short job prints nothing and a day-long one a few thousand lines. The
//! interval can be changed with the environment variable `STSCAM_PROGRESS_INTERVAL_S`
//! (seconds, ≥ 0). Progress never changes an output file.
//!
//! A front end that shows progress its own way (the Python module's `progress=` callback)
//! runs the job inside [`with_observer`]: the job's outermost [`Progress`] created on that
//! thread then also counts into the shared [`Observer`], which the front end polls; progress
//! objects nested inside it (a render inside a dataset) do not. Like the cancellation token
//! (`crate::cancel`), the observer is thread-local, so the CLI and tests never see one.

use std::cell::RefCell;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Seconds between two plain progress lines when stderr is not a terminal.
pub const DEFAULT_INTERVAL_S: f64 = 10.0;

/// Environment variable overriding [`DEFAULT_INTERVAL_S`].
pub const INTERVAL_ENV: &str = "STSCAM_PROGRESS_INTERVAL_S";

/// Progress of one job (shareable between threads): what is shown on stderr, and the
/// front end's [`Observer`] if this is the outermost progress of an observed job.
#[derive(Debug)]
pub struct Progress {
    view: View,
    observer: Option<Arc<Observer>>,
}

/// How progress is shown on stderr.
#[derive(Debug)]
enum View {
    /// Nothing is shown.
    Hidden,
    /// A bar on a terminal.
    Bar(indicatif::ProgressBar),
    /// Plain periodic lines.
    Lines(Lines),
}

/// State of the plain periodic lines.
#[derive(Debug)]
pub struct Lines {
    what: String,
    len: u64,
    pos: AtomicU64,
    start: Instant,
    interval_ms: u64,
    /// Milliseconds since `start` after which the next line may be printed.
    next_ms: AtomicU64,
}

impl Lines {
    /// Plain lines for `len` units of `what`, at most one per `interval_s` seconds.
    pub fn new(what: &str, len: u64, interval_s: f64) -> Lines {
        let interval_ms = (interval_s.max(0.0) * 1e3).min(1e12) as u64;
        Lines {
            what: what.to_string(),
            len,
            pos: AtomicU64::new(0),
            start: Instant::now(),
            interval_ms,
            next_ms: AtomicU64::new(interval_ms),
        }
    }

    /// Counts `n` finished units; returns the line to print, if one is due now.
    pub fn inc(&self, n: u64) -> Option<String> {
        let pos = self.pos.fetch_add(n, Ordering::Relaxed) + n;
        let now_ms = self.start.elapsed().as_millis() as u64;
        let next = self.next_ms.load(Ordering::Relaxed);
        if now_ms < next {
            return None;
        }
        // One thread wins the right to print this line.
        self.next_ms
            .compare_exchange(
                next,
                now_ms + self.interval_ms,
                Ordering::Relaxed,
                Ordering::Relaxed,
            )
            .ok()?;
        Some(self.line(pos, now_ms as f64 / 1e3))
    }

    /// The progress line for `pos` units done after `elapsed_s` seconds.
    pub fn line(&self, pos: u64, elapsed_s: f64) -> String {
        let pos = pos.min(self.len);
        let frac = if self.len > 0 {
            pos as f64 / self.len as f64
        } else {
            1.0
        };
        let eta = if pos > 0 {
            format!("{:.0} s", elapsed_s * (1.0 - frac) / frac)
        } else {
            "unknown".to_string()
        };
        format!(
            "{}: {pos}/{} ({:.1} %), {elapsed_s:.0} s elapsed, ETA {eta}",
            self.what,
            self.len,
            100.0 * frac
        )
    }
}

/// The interval of plain lines: [`INTERVAL_ENV`] if it holds a non-negative number, else
/// [`DEFAULT_INTERVAL_S`].
pub fn interval_s() -> f64 {
    std::env::var(INTERVAL_ENV)
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(DEFAULT_INTERVAL_S)
}

/// A job's progress as a front end sees it: the unit, the length and the count of the job's
/// outermost [`Progress`]. Shared between the job (which counts) and the front end (which
/// polls [`Observer::get`]).
#[derive(Debug, Default)]
pub struct Observer {
    /// Whether a progress object currently reports here (the outermost one).
    claimed: AtomicBool,
    /// (what, len) of the current job.
    job: Mutex<(String, u64)>,
    done: AtomicU64,
}

impl Observer {
    /// (units done, length, unit) of the job, or `None` before any job has started.
    pub fn get(&self) -> Option<(u64, u64, String)> {
        let job = self.job.lock().unwrap_or_else(|p| p.into_inner());
        (!job.0.is_empty()).then(|| (self.done.load(Ordering::Relaxed), job.1, job.0.clone()))
    }

    /// Claims the observer for a job of `len` units of `what`; false if one is already active.
    fn claim(&self, len: u64, what: &str) -> bool {
        if self.claimed.swap(true, Ordering::AcqRel) {
            return false;
        }
        *self.job.lock().unwrap_or_else(|p| p.into_inner()) = (what.to_string(), len);
        self.done.store(0, Ordering::Relaxed);
        true
    }
}

thread_local! {
    static OBSERVER: RefCell<Option<Arc<Observer>>> = const { RefCell::new(None) };
}

/// Runs `job` with `observer` receiving the progress of the job's outermost [`Progress`]
/// created on this thread (restoring the previous observer after).
pub fn with_observer<R>(observer: Arc<Observer>, job: impl FnOnce() -> R) -> R {
    let previous = OBSERVER.with(|o| o.borrow_mut().replace(observer));
    struct Restore(Option<Arc<Observer>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let p = self.0.take();
            OBSERVER.with(|o| *o.borrow_mut() = p);
        }
    }
    let _restore = Restore(previous);
    job()
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(o) = &self.observer {
            o.claimed.store(false, Ordering::Release);
        }
    }
}

impl Progress {
    /// Progress over `len` units of `what`: hidden unless `show`; a bar if stderr is a
    /// terminal, else plain periodic lines. Reported to the thread's [`Observer`] too (see
    /// [`with_observer`]) if it is the outermost.
    pub fn new(show: bool, len: u64, what: &str) -> Progress {
        let observer = OBSERVER
            .with(|o| o.borrow().clone())
            .filter(|o| o.claim(len, what));
        Progress {
            view: View::new(show, len, what),
            observer,
        }
    }

    /// Counts `n` finished units.
    pub fn inc(&self, n: u64) {
        if let Some(o) = &self.observer {
            o.done.fetch_add(n, Ordering::Relaxed);
        }
        match &self.view {
            View::Hidden => {}
            View::Bar(b) => b.inc(n),
            View::Lines(l) => {
                if let Some(line) = l.inc(n) {
                    eprintln!("{line}");
                }
            }
        }
    }

    /// Ends the job: clears a bar (plain lines need no end).
    pub fn finish_and_clear(&self) {
        if let View::Bar(b) = &self.view {
            b.finish_and_clear();
        }
    }
}

impl View {
    fn new(show: bool, len: u64, what: &str) -> View {
        if !show {
            return View::Hidden;
        }
        if std::io::stderr().is_terminal() {
            let style = indicatif::ProgressStyle::with_template(&format!(
                "{{spinner}} {what} {{pos}}/{{len}} [{{elapsed_precise}} < {{eta_precise}}] {{per_sec}}"
            ))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            View::Bar(indicatif::ProgressBar::new(len).with_style(style))
        } else {
            View::Lines(Lines::new(what, len, interval_s()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_wait_for_the_interval() {
        // A long interval: nothing is due, whatever the count.
        let l = Lines::new("rows", 10, 3600.0);
        assert!((0..10).all(|_| l.inc(1).is_none()));
        // Interval 0: every update is due and the line carries the numbers.
        let l = Lines::new("rows", 4, 0.0);
        let line = l.inc(1).expect("due");
        assert!(line.starts_with("rows: 1/4 (25.0 %), "), "{line}");
        assert!(line.contains("ETA"), "{line}");
        assert_eq!(
            l.line(2, 10.0),
            "rows: 2/4 (50.0 %), 10 s elapsed, ETA 10 s"
        );
        assert_eq!(
            l.line(0, 3.0),
            "rows: 0/4 (0.0 %), 3 s elapsed, ETA unknown"
        );
    }

    #[test]
    fn hidden_prints_nothing_and_counts_nothing() {
        let p = Progress::new(false, 5, "x");
        assert!(matches!(p.view, View::Hidden));
        assert!(p.observer.is_none());
        p.inc(3);
        p.finish_and_clear();
    }

    #[test]
    fn the_observer_counts_the_outermost_progress_only() {
        let o = Arc::new(Observer::default());
        assert_eq!(o.get(), None);
        with_observer(o.clone(), || {
            let outer = Progress::new(false, 10, "samples");
            outer.inc(2);
            {
                // Nested (a render inside a dataset sample): not reported.
                let inner = Progress::new(false, 99, "rows");
                inner.inc(50);
            }
            outer.inc(1);
            assert_eq!(o.get(), Some((3, 10, "samples".to_string())));
            drop(outer);
            // The next outermost progress takes over.
            let next = Progress::new(false, 4, "frames");
            next.inc(4);
            assert_eq!(o.get(), Some((4, 4, "frames".to_string())));
        });
        // Outside, nothing is observed.
        let p = Progress::new(false, 5, "x");
        assert!(p.observer.is_none());
    }
}
