//! The time budget and cancellation of one recognition.
//!
//! A [`Deadline`] is created when a call's work starts (after any wait for worker threads) and
//! is checked at every step of every long stage: `deadline.check("stage")?` returns
//! [`Error::Interrupted`] once the budget is spent or the caller's [`CancelToken`] fired, and
//! every later check fails too, so all workers stop at their next check. The same test is
//! installed in the bridge (`binpick_pcl::set_interrupt`), which polls it between the chunks
//! of long PCL calls (ICP iterations, RANSAC iterations, blocks of the neighbourhood search,
//! voxel-grid tiles); those chunks are cut where the answer does not change.
//!
//! Stages only unwind; the level that keeps partial results (the recognizer for the whole
//! scene, an engine per cluster) turns the interruption into a value with
//! [`Deadline::partial`], and the recognizer reports it at return as an
//! [`Interruption`] in `Recognition::interrupted`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::result::{Interruption, StopCause};

/// Cancels recognitions from another thread: clone it into
/// [`RecognizeOptions`](crate::RecognizeOptions), call [`cancel`](Self::cancel) from anywhere.
/// All clones share one flag; once cancelled it stays cancelled (use a new token per call or
/// per batch of calls).
#[derive(Clone, Debug, Default)]
pub struct CancelToken(Arc<AtomicBool>);

impl CancelToken {
    /// A token nobody has cancelled yet; clone it to hand it to another thread.
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks every call holding this token to stop: a running call returns at its next check
    /// with what it verified so far, a call not yet started returns at once.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether `cancel` was called on this token or a clone of it.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// When one recognition must stop. Cheap to clone (shared state).
#[derive(Clone, Debug)]
pub(crate) struct Deadline {
    inner: Arc<Shared>,
}

#[derive(Debug)]
struct Shared {
    start: Instant,
    budget: Option<Duration>,
    cancel: Option<CancelToken>,
    /// Set once, by the first check that fails: why and where.
    stopped: OnceLock<(StopCause, &'static str)>,
}

impl Deadline {
    /// Starts the clock now.
    pub(crate) fn new(budget: Option<Duration>, cancel: Option<CancelToken>) -> Self {
        Self {
            inner: Arc::new(Shared {
                start: Instant::now(),
                budget,
                cancel,
                stopped: OnceLock::new(),
            }),
        }
    }

    /// No budget, no token: checks never fail (model preparation, the reference engine's
    /// cleaning, tests).
    pub(crate) fn unlimited() -> Self {
        Self::new(None, None)
    }

    pub(crate) fn elapsed(&self) -> Duration {
        self.inner.start.elapsed()
    }

    /// Why the call must stop now, if it must (a cancellation wins over the budget).
    fn due(&self) -> Option<StopCause> {
        let s = &self.inner;
        if let Some((cause, _)) = s.stopped.get() {
            return Some(*cause);
        }
        if s.cancel.as_ref().is_some_and(CancelToken::is_cancelled) {
            return Some(StopCause::Cancelled);
        }
        match s.budget {
            Some(b) if s.start.elapsed() >= b => Some(StopCause::TimeBudget),
            _ => None,
        }
    }

    /// `Err(Error::Interrupted)` once the budget is spent or the call is cancelled; the first
    /// failing check records `stage` (what was running when the call was stopped).
    pub(crate) fn check(&self, stage: &'static str) -> Result<()> {
        match self.due() {
            None => Ok(()),
            Some(cause) => {
                self.record(cause, stage);
                Err(Error::Interrupted { stage })
            }
        }
    }

    fn record(&self, cause: StopCause, stage: &'static str) {
        let _ = self.inner.stopped.set((cause, stage));
    }

    /// Splits an interruption off a stage's result: `Ok(Some(v))` when it finished,
    /// `Ok(None)` when it was interrupted (what it computed is dropped, the caller keeps what
    /// it had), `Err` for any other error.
    pub(crate) fn partial<T>(&self, result: Result<T>) -> Result<Option<T>> {
        match result {
            Ok(v) => Ok(Some(v)),
            Err(Error::Interrupted { stage }) => {
                // Noticed inside PCL: no Rust check has recorded it yet.
                let cause = self.due().unwrap_or(StopCause::TimeBudget);
                self.record(cause, stage);
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    /// The same test for the bridge's long calls (`binpick_pcl::set_interrupt`).
    pub(crate) fn interrupt(&self) -> binpick_pcl::Interrupt {
        let d = self.clone();
        Arc::new(move || d.due().is_some())
    }

    /// What stopped the call, as reported at return, `elapsed` after its start: `None` when
    /// nothing did and the budget (if any) still holds at `elapsed`. A call that finished
    /// every stage but returns after its budget reports the budget with stage "return" (its
    /// detections are then complete).
    pub(crate) fn report(&self, elapsed: Duration) -> Option<Interruption> {
        let s = &self.inner;
        let (cause, stage) = match s.stopped.get() {
            Some(&(cause, stage)) => (cause, stage),
            None if s.cancel.as_ref().is_some_and(CancelToken::is_cancelled) => {
                (StopCause::Cancelled, "return")
            }
            None if s.budget.is_some_and(|b| elapsed >= b) => (StopCause::TimeBudget, "return"),
            None => return None,
        };
        Some(Interruption {
            cause,
            budget_ms: s.budget.map(|b| b.as_secs_f64() * 1000.0),
            stage: stage.to_owned(),
            elapsed_ms: ms(elapsed),
        })
    }

    /// [`report`](Self::report) now.
    pub(crate) fn report_now(&self) -> Option<Interruption> {
        self.report(self.elapsed())
    }
}

/// A duration in milliseconds (the unit of every timing report).
pub(crate) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checks_fail_after_the_budget_and_record_the_first_stage() {
        let d = Deadline::new(Some(Duration::from_millis(20)), None);
        assert!(d.check("a").is_ok());
        assert!(d.report_now().is_none());
        std::thread::sleep(Duration::from_millis(25));
        assert!(matches!(
            d.check("b"),
            Err(Error::Interrupted { stage: "b" })
        ));
        assert!(d.check("c").is_err());
        let r = d.report_now().unwrap();
        assert_eq!((r.cause, r.stage.as_str()), (StopCause::TimeBudget, "b"));
        assert_eq!(r.budget_ms, Some(20.0));
        assert!(r.elapsed_ms >= 25.0);
        assert!((d.interrupt())());
    }

    #[test]
    fn cancellation_stops_every_check_and_wins_over_the_budget() {
        let token = CancelToken::new();
        let d = Deadline::new(Some(Duration::from_secs(3600)), Some(token.clone()));
        assert!(d.check("a").is_ok());
        assert!(!(d.interrupt())());
        token.clone().cancel();
        assert!(token.is_cancelled());
        assert!(d.check("b").is_err());
        assert_eq!(d.report_now().unwrap().cause, StopCause::Cancelled);
    }

    #[test]
    fn partial_keeps_values_drops_interruptions_and_passes_errors() {
        let d = Deadline::unlimited();
        assert_eq!(d.partial(Ok(3)).unwrap(), Some(3));
        assert_eq!(
            d.partial::<u8>(Err(Error::Interrupted { stage: "ICP" }))
                .unwrap(),
            None
        );
        assert_eq!(d.report_now().unwrap().stage, "ICP");
        let e = d.partial::<u8>(Err(crate::error::input("scene", "bad")));
        assert!(e.is_err());
        // A deadline without budget or token never stops by itself.
        assert!(Deadline::unlimited().check("x").is_ok());
        assert!(Deadline::unlimited().report_now().is_none());
    }
}
