//! Worker threads shared by the calls of one `Recognizer`.
//!
//! A recognizer owns `threads` worker threads' worth of cores. Each call first takes a lease
//! of some of them, waiting in a first-come, first-served queue while none is free, then
//! runs on a rayon pool of exactly that many threads that no other call uses at the same
//! time. A call alone gets every thread (lowest latency); when calls queue, each takes its
//! share of the free threads (`ceil(free / waiting)`), so under load several calls run side
//! by side on one or a few threads each (highest throughput: a call on one thread wastes
//! nothing on synchronisation) and cores are never oversubscribed.
//!
//! Why not one pool for all calls: rayon runs a call injected into a busy pool inside
//! whichever worker waits for work, including one blocked in another call's join, so calls
//! nest, each waits for the ones started inside it, and eight callers of a 0.64 s call saw
//! a median latency of 6.4 s. Leases keep calls apart; results do not depend on the thread
//! count, so the share a call gets never changes its answer.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

use crate::deadline::CancelToken;
use crate::error::{Error, Result};

/// The worker threads of one recognizer.
pub(crate) struct Workers {
    threads: usize,
    /// The pool a call that leases every thread runs on (also model preparation).
    full: rayon::ThreadPool,
    state: Mutex<State>,
    changed: Condvar,
}

#[derive(Default)]
struct State {
    /// Threads not leased.
    free: usize,
    /// Tickets of the calls waiting, first come first.
    queue: VecDeque<u64>,
    next_ticket: u64,
    /// Pools of fewer threads than `threads`, idle, for reuse.
    idle: Vec<rayon::ThreadPool>,
}

/// Threads leased by one call; returned on drop.
pub(crate) struct Lease<'a> {
    workers: &'a Workers,
    threads: usize,
    /// `None`: the full pool.
    pool: Option<rayon::ThreadPool>,
}

/// How often a waiting call looks at its cancel token.
const CANCEL_POLL: Duration = Duration::from_millis(5);

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("binpick-{i}"))
        .build()
        .map_err(|e| Error::Threads(e.to_string()))
}

impl Workers {
    pub(crate) fn new(threads: usize) -> Result<Self> {
        Ok(Self {
            threads,
            full: pool(threads)?,
            state: Mutex::new(State {
                free: threads,
                ..State::default()
            }),
            changed: Condvar::new(),
        })
    }

    pub(crate) fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `f` on every thread, outside any lease (model preparation, before any call).
    pub(crate) fn install_full<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.full.install(f)
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A poisoned lock only means a thread panicked while holding it; the counts it
        // guards are updated in single statements, so they are still consistent.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits for this call's turn and a share of the free threads. `Ok(None)` when `cancel`
    /// fires while waiting.
    pub(crate) fn lease(&self, cancel: Option<&CancelToken>) -> Result<Option<Lease<'_>>> {
        let mut s = self.lock();
        let ticket = s.next_ticket;
        s.next_ticket += 1;
        s.queue.push_back(ticket);
        loop {
            if cancel.is_some_and(CancelToken::is_cancelled) {
                s.queue.retain(|&t| t != ticket);
                drop(s);
                self.changed.notify_all();
                return Ok(None);
            }
            if s.queue.front() == Some(&ticket) && s.free > 0 {
                break;
            }
            s = match self.changed.wait_timeout(s, CANCEL_POLL) {
                Ok((s, _)) => s,
                Err(e) => e.into_inner().0,
            };
        }
        let waiting = s.queue.len();
        let threads = s.free.div_ceil(waiting);
        s.free -= threads;
        s.queue.pop_front();
        // The full pool for a lease of every thread; else an idle pool of that size, or a
        // new one (built outside the lock).
        let idle = (threads < self.threads)
            .then(|| {
                s.idle
                    .iter()
                    .position(|p| p.current_num_threads() == threads)
            })
            .flatten()
            .map(|i| s.idle.swap_remove(i));
        drop(s);
        self.changed.notify_all();
        let pool = match idle {
            Some(p) => Some(p),
            None if threads == self.threads => None,
            None => match self::pool(threads) {
                Ok(p) => Some(p),
                Err(e) => {
                    self.give_back(threads, None);
                    return Err(e);
                }
            },
        };
        Ok(Some(Lease {
            workers: self,
            threads,
            pool,
        }))
    }

    fn give_back(&self, threads: usize, pool: Option<rayon::ThreadPool>) {
        let mut s = self.lock();
        s.free += threads;
        if let Some(p) = pool {
            s.idle.push(p);
        }
        drop(s);
        self.changed.notify_all();
    }
}

impl Lease<'_> {
    /// Threads of this lease.
    pub(crate) fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `f` on the leased pool, with `interrupt` installed for the bridge's long calls on
    /// every thread of it for the duration.
    pub(crate) fn run<R: Send>(
        &self,
        interrupt: binpick_pcl::Interrupt,
        f: impl FnOnce() -> R + Send,
    ) -> R {
        let pool = self.pool.as_ref().unwrap_or(&self.workers.full);
        pool.install(|| {
            rayon::broadcast(|_| binpick_pcl::set_interrupt(Some(interrupt.clone())));
            let out = f();
            rayon::broadcast(|_| binpick_pcl::set_interrupt(None));
            out
        })
    }
}

impl Drop for Lease<'_> {
    fn drop(&mut self) {
        self.workers.give_back(self.threads, self.pool.take());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_lone_call_gets_every_thread_and_queued_calls_share() {
        let w = Workers::new(4).unwrap();
        let a = w.lease(None).unwrap().unwrap();
        assert_eq!(a.threads(), 4);
        drop(a);
        // Three calls queue behind a full lease; released, they share the four threads.
        std::thread::scope(|s| {
            let first = w.lease(None).unwrap().unwrap();
            assert_eq!(first.threads(), 4);
            let all_leased = Arc::new(std::sync::Barrier::new(3));
            let handles: Vec<_> = (0..3)
                .map(|_| {
                    let (w, all_leased) = (&w, all_leased.clone());
                    s.spawn(move || {
                        let l = w.lease(None).unwrap().unwrap();
                        // The leased pool has exactly that many threads.
                        let pool_threads = l.run(Arc::new(|| false), rayon::current_num_threads);
                        all_leased.wait(); // all three hold their lease at once
                        (l.threads(), pool_threads)
                    })
                })
                .collect();
            while w.lock().queue.len() < 3 {
                std::thread::sleep(Duration::from_millis(1));
            }
            drop(first);
            let mut got: Vec<(usize, usize)> =
                handles.into_iter().map(|h| h.join().unwrap()).collect();
            got.sort_unstable();
            // ceil(4 free / 3 waiting) = 2, then ceil(2 / 2) = 1, then 1.
            assert_eq!(got, vec![(1, 1), (1, 1), (2, 2)]);
        });
        assert_eq!(w.lock().free, 4);
    }

    #[test]
    fn a_cancelled_waiter_leaves_the_queue() {
        let w = Workers::new(1).unwrap();
        let held = w.lease(None).unwrap().unwrap();
        let token = CancelToken::new();
        std::thread::scope(|s| {
            let h = s.spawn(|| w.lease(Some(&token)).unwrap().is_none());
            while w.lock().queue.is_empty() {
                std::thread::sleep(Duration::from_millis(1));
            }
            token.cancel();
            assert!(h.join().unwrap());
        });
        assert!(w.lock().queue.is_empty());
        drop(held);
        assert_eq!(w.lease(None).unwrap().unwrap().threads(), 1);
    }
}
