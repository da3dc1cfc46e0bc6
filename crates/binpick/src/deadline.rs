//! Time budget for one recognition, checked between work items (a PCL call itself is never
//! interrupted, so the overshoot is at most one stage of one cluster).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};

#[derive(Debug)]
pub(crate) struct Deadline {
    start: Instant,
    budget: Option<Duration>,
    expired: AtomicBool,
}

impl Deadline {
    pub(crate) fn new(budget: Option<Duration>) -> Self {
        Self {
            start: Instant::now(),
            budget,
            expired: AtomicBool::new(false),
        }
    }

    pub(crate) fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    /// Errors once the budget is spent; once one worker sees it, all others stop at their
    /// next check.
    pub(crate) fn check(&self, stage: &'static str) -> Result<()> {
        let Some(budget) = self.budget else {
            return Ok(());
        };
        let elapsed = self.start.elapsed();
        if self.expired.load(Ordering::Relaxed) || elapsed > budget {
            self.expired.store(true, Ordering::Relaxed);
            return Err(Error::TimeBudget {
                budget_ms: budget.as_millis() as u64,
                elapsed_ms: elapsed.as_millis() as u64,
                stage,
            });
        }
        Ok(())
    }
}

/// A duration in milliseconds (the unit of every timing report).
pub(crate) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}
