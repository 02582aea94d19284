//! Cooperative cancellation of long jobs (renders, matrices, datasets, sweeps), for front ends
//! that must stop on request, e.g. the Python module on Ctrl-C.
//!
//! Model: a front end runs a job inside [`with_flag`], which installs a shared flag as the
//! calling thread's cancellation token. A long loop reads the token once with [`current`] on
//! the thread that starts it (before it fans out over worker threads) and checks
//! [`Token::is_cancelled`] once per row, sample or grid point: one relaxed atomic load. Once
//! the flag is set, the loop skips the rest of its work and the job's result is meaningless; the
//! front end discards it. Jobs that write files ([`crate::dataset::generate`]) check the token
//! before every write and return an error instead, so nothing half-made is written. The token is
//! thread-local, so a job started without a flag (the CLI, tests) can never be cancelled and
//! concurrent jobs do not cancel each other.

use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

thread_local! {
    static FLAG: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
}

/// The cancellation token of the job running on this thread (none outside [`with_flag`]).
#[derive(Clone, Debug, Default)]
pub struct Token(Option<Arc<AtomicBool>>);

impl Token {
    /// Whether the job was asked to stop.
    #[inline]
    pub fn is_cancelled(&self) -> bool {
        self.0.as_ref().is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

/// The token of the current thread: read it before a loop goes parallel.
pub fn current() -> Token {
    Token(FLAG.with(|f| f.borrow().clone()))
}

/// Runs `job` with `flag` as this thread's cancellation token (restoring the previous one after).
pub fn with_flag<R>(flag: Arc<AtomicBool>, job: impl FnOnce() -> R) -> R {
    let previous = FLAG.with(|f| f.borrow_mut().replace(flag));
    struct Restore(Option<Arc<AtomicBool>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let p = self.0.take();
            FLAG.with(|f| *f.borrow_mut() = p);
        }
    }
    let _restore = Restore(previous);
    job()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn token_follows_the_flag_only_inside_with_flag() {
        assert!(!current().is_cancelled());
        let flag = Arc::new(AtomicBool::new(false));
        let t = with_flag(flag.clone(), current);
        assert!(!t.is_cancelled());
        flag.store(true, Ordering::Relaxed);
        assert!(t.is_cancelled());
        // Outside, no token: never cancelled.
        assert!(!current().is_cancelled());
    }
}
