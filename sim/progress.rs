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

use std::io::IsTerminal;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Seconds between two plain progress lines when stderr is not a terminal.
pub const DEFAULT_INTERVAL_S: f64 = 10.0;

/// Environment variable overriding [`DEFAULT_INTERVAL_S`].
pub const INTERVAL_ENV: &str = "STSCAM_PROGRESS_INTERVAL_S";

/// Progress of one job (shareable between threads).
#[derive(Debug)]
pub enum Progress {
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

impl Progress {
    /// Progress over `len` units of `what`: hidden unless `show`; a bar if stderr is a
    /// terminal, else plain periodic lines.
    pub fn new(show: bool, len: u64, what: &str) -> Progress {
        if !show {
            return Progress::Hidden;
        }
        if std::io::stderr().is_terminal() {
            let style = indicatif::ProgressStyle::with_template(&format!(
                "{{spinner}} {what} {{pos}}/{{len}} [{{elapsed_precise}} < {{eta_precise}}] {{per_sec}}"
            ))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            Progress::Bar(indicatif::ProgressBar::new(len).with_style(style))
        } else {
            Progress::Lines(Lines::new(what, len, interval_s()))
        }
    }

    /// Counts `n` finished units.
    pub fn inc(&self, n: u64) {
        match self {
            Progress::Hidden => {}
            Progress::Bar(b) => b.inc(n),
            Progress::Lines(l) => {
                if let Some(line) = l.inc(n) {
                    eprintln!("{line}");
                }
            }
        }
    }

    /// Ends the job: clears a bar (plain lines need no end).
    pub fn finish_and_clear(&self) {
        if let Progress::Bar(b) = self {
            b.finish_and_clear();
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
        assert!(matches!(p, Progress::Hidden));
        p.inc(3);
        p.finish_and_clear();
    }
}
