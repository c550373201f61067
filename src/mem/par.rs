//! Builds on the caller's threads: sheaf never spawns a thread. A build
//! that can use several threads takes a [`Par`], the caller's way to run
//! one task on each of its workers (a thread pool's broadcast, rayon's
//! `broadcast`, or the C ABI's [`Join`], where the caller's threads join
//! one build as Embree's `rtcJoinCommitScene` lets them join a commit);
//! [`Serial`] runs everything on the calling thread.
//!
//! The phases of a joined build write disjoint parts of one pool from
//! several workers: [`Parts`] hands each part out once, and [`atomic_u32`]
//! views a `u32` pool as atomics for scattered writes. Those two and
//! [`Join`] are the unsafe pieces; the builds themselves are safe code.

use super::hg;
use core::cell::UnsafeCell;
use core::marker::PhantomData;
use core::ops::Range;
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};

/// Most workers a joined build uses.
pub const MAX_WORKERS: usize = 16;

/// Runs a task once on each of `workers()` workers and returns when every
/// run has returned. Worker 0 may be the calling thread.
pub trait Par: Sync {
    /// How many workers `run` uses (1..=`MAX_WORKERS`).
    fn workers(&self) -> usize;
    /// `task(w)` for every `w` in `0..workers()`, each exactly once, all
    /// finished on return.
    fn run(&self, task: &(dyn Fn(usize) + Sync));
}

/// `par`'s worker count, refused unless 1..=`MAX_WORKERS` (every joined
/// build checks it before it writes anything).
pub fn workers_of(par: &dyn Par) -> crate::error::Result<usize> {
    match par.workers() {
        w @ 1..=MAX_WORKERS => Ok(w),
        _ => Err(crate::error::Error::InvalidArgument(
            "a joined build takes 1 to 16 workers (Par::workers)",
        )),
    }
}

/// Everything on the calling thread.
pub struct Serial;

impl Par for Serial {
    fn workers(&self) -> usize {
        1
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        task(0)
    }
}

/// The part of `0..n` worker `w` of `workers` takes (contiguous, in order).
#[inline]
pub fn share(n: usize, w: usize, workers: usize) -> Range<usize> {
    let at = |k: usize| (n as u128 * k as u128 / workers as u128) as usize;
    at(w)..at(w + 1)
}

/// One slice cut into one part per worker at fixed bounds: each part is
/// handed out once (a second `get` of the same part panics), so workers of
/// a `Par::run` write their own parts at once without aliasing.
pub struct Parts<'a, T> {
    ptr: *mut T,
    bounds: [usize; MAX_WORKERS + 1],
    count: usize,
    taken: [AtomicBool; MAX_WORKERS],
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: `Parts` is a `&mut [T]` split among threads: parts go to one
// taker each (`taken`), and sending `T`s between threads is what
// `T: Send` allows.
unsafe impl<T: Send> Sync for Parts<'_, T> {}

impl<'a, T> Parts<'a, T> {
    /// `s` cut at `bounds` (part w is `bounds[w]..bounds[w + 1]`;
    /// nondecreasing, within `s`, at most `MAX_WORKERS` parts; panics
    /// otherwise).
    pub fn at(s: &'a mut [T], bounds: &[usize]) -> Self {
        let count = bounds.len().saturating_sub(1);
        assert!(count <= MAX_WORKERS, "Parts: too many parts");
        assert!(
            bounds.windows(2).all(|b| b[0] <= b[1]) && bounds.last().is_none_or(|&e| e <= s.len()),
            "Parts: bounds out of order or out of the slice"
        );
        let mut b = [0usize; MAX_WORKERS + 1];
        b[..bounds.len()].copy_from_slice(bounds);
        Parts {
            ptr: s.as_mut_ptr(),
            bounds: b,
            count,
            taken: [const { AtomicBool::new(false) }; MAX_WORKERS],
            _borrow: PhantomData,
        }
    }
    /// `s` in `workers` parts of (nearly) equal length (`share`).
    pub fn even(s: &'a mut [T], workers: usize) -> Self {
        let mut b = [0usize; MAX_WORKERS + 1];
        for (w, x) in b.iter_mut().enumerate().take(workers + 1) {
            *x = share(s.len(), w.min(workers), workers.max(1)).start;
        }
        b[workers] = s.len();
        Self::at(s, &b[..workers + 1])
    }
    /// Where part `w` starts in the slice.
    pub fn start(&self, w: usize) -> usize {
        self.bounds[w]
    }
    /// Part `w`, for its one taker (panics when `w` is out of range or the
    /// part was taken before).
    #[allow(clippy::mut_from_ref)]
    pub fn get(&self, w: usize) -> &mut [T] {
        assert!(w < self.count, "Parts: no part {w}");
        assert!(
            !self.taken[w].swap(true, Ordering::AcqRel),
            "Parts: part {w} taken twice"
        );
        let (a, b) = (self.bounds[w], self.bounds[w + 1]);
        // SAFETY: `a..b` lies in the borrowed slice (checked in `at`);
        // parts are disjoint (nondecreasing bounds) and each is handed out
        // once (the swap above), so this `&mut` aliases nothing.
        unsafe { core::slice::from_raw_parts_mut(self.ptr.add(a), b - a) }
    }
}

/// `s` as atomics, for scattered writes from several workers (radix sort
/// scatters, id maps): each position is written by one worker by
/// construction, and a wrong position is a wrong result, never a data race.
pub fn atomic_u32(s: &mut [u32]) -> &[AtomicU32] {
    // SAFETY: `AtomicU32` has the size and alignment of `u32` (asserted
    // below), and the `&mut` borrow guarantees no other access while the
    // returned view lives.
    const _: () =
        assert!(core::mem::size_of::<AtomicU32>() == 4 && core::mem::align_of::<AtomicU32>() == 4);
    unsafe { &*(s as *mut [u32] as *const [AtomicU32]) }
}

/// A value several workers take turns at (a spin lock): the shared work
/// item queue of a joined frame (`render::deferred::OnPar`). Held only
/// for a short step (taking the next item).
pub struct Turns<T> {
    busy: AtomicBool,
    value: UnsafeCell<T>,
}

// SAFETY: `value` is only reached inside `with`, one thread at a time
// (`busy`, acquire/release), so sharing `Turns` moves `T` between threads
// and nothing more: `T: Send` suffices.
unsafe impl<T: Send> Sync for Turns<T> {}

impl<T> Turns<T> {
    pub const fn new(value: T) -> Turns<T> {
        Turns {
            busy: AtomicBool::new(false),
            value: UnsafeCell::new(value),
        }
    }
    /// `f` on the value, alone.
    pub fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        while self
            .busy
            .compare_exchange_weak(false, true, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            // A preempted holder: give the core away rather than spin.
            backoff();
        }
        // Let go however `f` ends (a panicking item iterator unwinds).
        struct Free<'a>(&'a AtomicBool);
        impl Drop for Free<'_> {
            fn drop(&mut self) {
                // A read-modify-write, as helgrind needs (see `hg`).
                self.0.swap(false, Ordering::Release);
            }
        }
        let _free = Free(&self.busy);
        hg::acquired(self as *const Self as *const u8 as usize);
        // SAFETY: `busy` was false and is now ours until `_free` drops:
        // no other `&mut` to the value exists meanwhile.
        let r = f(unsafe { &mut *self.value.get() });
        hg::released(self as *const Self as *const u8 as usize);
        r
    }
}

/// The C ABI's joined build: thread 0 leads (it holds the context and runs
/// the build), threads 1.. call [`Join::help`] and run the tasks the
/// leader publishes until it closes the session.
///
/// Protocol: the leader takes the join (one leader at a time; a second
/// waits) and opens a session for `workers` threads. Arrival goes through
/// the door (a short lock): a helper looks at the open session, or at the
/// next one to open if none is, exactly once, and either claims its index
/// (the index is free and its thread count is the session's) or is
/// refused ([`Helped::NotAWorker`], [`Helped::Taken`]) without touching
/// the session. The leader closes the session only when every helper
/// index is claimed and every helper that was waiting when it opened has
/// looked at it, so a helper waiting beside a group it does not fit is
/// refused, never kept for a later group. Each `Par::run` publishes a task
/// (the ticket's task count goes up by one), runs it as worker 0 and waits
/// until the `workers - 1` claimed helpers have run it, even when its own
/// part panics; after the body the leader waits until every helper has
/// left (read the outcome and stopped touching the join) before it
/// returns. A helper runs every task published in its session, in order.
/// A helper's panic is caught (with `std`), counted as done and re-raised
/// on the leader. Every helper must arrive: a missing one leaves the
/// leader waiting.
pub struct Join {
    /// A leader holds the join (one joined build at a time).
    leading: AtomicBool,
    /// What the session's leader reported (the C ABI's status), for its
    /// helpers to return.
    outcome: AtomicU32,
    /// Who may join: changed only under its lock.
    door: Turns<Door>,
    /// `door`'s `open`, mirrored (written under the lock, released) for
    /// helpers between tasks to poll without taking the lock.
    live: AtomicBool,
    /// The number of the last session opened, for waiting helpers to
    /// watch without the lock.
    opened: AtomicU64,
    /// The session number (high half) and the tasks published in it (low
    /// half), in one word: a helper never runs another session's task.
    ticket: AtomicU64,
    /// Helpers that left this session: the leader returns only when all
    /// have, so its caller may reuse or free the join afterwards.
    departed: AtomicUsize,
    /// Helpers still running the current task.
    pending: AtomicUsize,
    /// A helper's task panicked in this session.
    failed: AtomicBool,
    /// The leader is inside `run` (a nested or concurrent run is refused).
    running: AtomicBool,
    /// The current task, valid while `pending > 0` or the leader is in `run`.
    task: UnsafeCell<Option<TaskPtr>>,
}

/// The join's arrival state.
struct Door {
    /// The last session opened (0: none yet).
    session: u64,
    open: bool,
    workers: usize,
    /// Bit `i`: helper index `i` of the open session is taken.
    claimed: u32,
    /// Helpers waiting for the next session to open.
    waiting: u32,
    /// Helpers that were waiting when the open session opened and have not
    /// looked at it yet: the leader does not close it before they have.
    lookers: u32,
}

/// A task trait object, as the leader's `run` borrows it.
#[derive(Clone, Copy)]
struct TaskPtr(*const (dyn Fn(usize) + Sync));

// SAFETY: the only non-atomic fields are `task` and `door`'s value;
// `door` is reached only through `Turns::with`. `task` is written by the
// leader (one leader at a time, `leading`; one run at a time, `running`)
// before the release increment of `ticket` that publishes it and read by
// helpers after their acquire load of `ticket`; the leader does not write
// it again until every helper has signalled (`pending`, release/acquire)
// that it is done with it.
unsafe impl Sync for Join {}
// SAFETY: as above; the raw task pointer is only dereferenced inside a
// session, while the leader's borrow lives.
unsafe impl Send for Join {}

impl Default for Join {
    fn default() -> Self {
        Self::new()
    }
}

/// How a `help` call ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Helped {
    /// The session ended; the leader's outcome.
    Done(u32),
    /// `me` is not a helper index of the session it looked at, or its
    /// thread count is not the session's.
    NotAWorker,
    /// Another helper of the session took `me` first.
    Taken,
}

/// Bits 1..workers: every helper index of a session of `workers`.
fn helper_bits(workers: usize) -> u32 {
    ((1u64 << workers) - 2) as u32
}

impl Join {
    pub const fn new() -> Join {
        Join {
            leading: AtomicBool::new(false),
            outcome: AtomicU32::new(0),
            door: Turns::new(Door {
                session: 0,
                open: false,
                workers: 1,
                claimed: 0,
                waiting: 0,
                lookers: 0,
            }),
            live: AtomicBool::new(false),
            opened: AtomicU64::new(0),
            ticket: AtomicU64::new(0),
            departed: AtomicUsize::new(0),
            pending: AtomicUsize::new(0),
            failed: AtomicBool::new(false),
            running: AtomicBool::new(false),
            task: UnsafeCell::new(None),
        }
    }

    /// Record the session's outcome (before `lead`'s body returns).
    pub fn set_outcome(&self, x: u32) {
        self.outcome.swap(x, Ordering::Relaxed);
    }
    /// Helgrind's name for this join's happens-before edges.
    fn tag(&self) -> usize {
        self as *const Join as usize
    }

    /// Lead a session of `workers` threads (1..=MAX_WORKERS): `body` gets
    /// the `Par` whose runs the helpers join. Waits while another leader
    /// holds the join; returns when every helper has left.
    pub fn lead<R>(&self, workers: usize, body: impl FnOnce(&dyn Par) -> R) -> R {
        while self
            .leading
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            backoff();
        }
        let workers = workers.clamp(1, MAX_WORKERS);
        // Read-modify-writes only (helgrind sees no race on them; see `hg`).
        self.departed.swap(0, Ordering::Relaxed);
        self.failed.swap(false, Ordering::Relaxed);
        let session = self.door.with(|d| {
            d.session += 1;
            d.open = true;
            d.workers = workers;
            d.claimed = 0;
            d.lookers = d.waiting;
            d.waiting = 0;
            self.live.swap(true, Ordering::Release);
            d.session
        });
        self.ticket.swap(session << 32, Ordering::Relaxed);
        hg::released(self.tag());
        // Waiting helpers go to the door once they see the number change;
        // the ticket's session is published to them through the door.
        self.opened.swap(session, Ordering::Release);
        // Close and wait for the helpers however `body` ends (a panic too).
        struct Close<'j>(&'j Join, usize);
        impl Drop for Close<'_> {
            fn drop(&mut self) {
                let (j, workers) = (self.0, self.1);
                let all = helper_bits(workers);
                // Closed only when every helper is in and every waiting
                // helper has looked (checked and closed in one turn).
                while !j.door.with(|d| {
                    let ready = d.claimed == all && d.lookers == 0;
                    if ready {
                        d.open = false;
                        j.live.swap(false, Ordering::Release);
                    }
                    ready
                }) {
                    backoff();
                }
                while j.departed.load(Ordering::Acquire) < workers - 1 {
                    backoff();
                }
                hg::acquired(j.tag());
                j.leading.swap(false, Ordering::Release);
            }
        }
        let _close = Close(self, workers);
        body(&Leader {
            join: self,
            workers,
        })
    }

    /// Help the open (or next) session as worker `me` of `workers` until
    /// it closes; refused at once if `me` is not one of its helper indices
    /// (`me` 0 or past its thread count), `workers` is not its thread
    /// count, or another helper took `me` first.
    pub fn help(&self, me: usize, workers: usize) -> Helped {
        let look = |d: &mut Door| {
            if me == 0 || me >= d.workers || workers != d.workers {
                Helped::NotAWorker
            } else if d.claimed & (1 << me) != 0 {
                Helped::Taken
            } else {
                d.claimed |= 1 << me;
                Helped::Done(0)
            }
        };
        let first = self.door.with(|d| {
            if d.open {
                Ok(look(d))
            } else {
                d.waiting += 1;
                Err(d.session)
            }
        });
        let verdict = match first {
            Ok(v) => v,
            Err(seen) => {
                while self.opened.load(Ordering::Acquire) == seen {
                    backoff();
                }
                // Still open: its leader waits for this look.
                self.door.with(|d| {
                    debug_assert!(d.open && d.session == seen + 1);
                    d.lookers -= 1;
                    look(d)
                })
            }
        };
        if verdict != Helped::Done(0) {
            return verdict;
        }
        hg::acquired(self.tag());
        // The leader cannot leave this session before this helper left.
        let session = self.ticket.load(Ordering::Acquire) >> 32;
        let mut done = 0u64;
        loop {
            let t = self.ticket.load(Ordering::Acquire);
            debug_assert_eq!(
                t >> 32,
                session,
                "the leader waits for every helper to leave"
            );
            if t & 0xffff_ffff > done {
                hg::acquired(self.tag());
                // SAFETY: published by the leader before its release
                // increment of `ticket` (acquired above) and kept until
                // every helper, this one included, has decremented `pending`.
                let task = unsafe { (*self.task.get()).expect("a published task") };
                // SAFETY: the leader's `run` waits (even while unwinding)
                // until `pending` reaches 0, which needs this helper's
                // decrement below, so the task outlives this call.
                let call = || unsafe { (*task.0)(me) };
                #[cfg(feature = "std")]
                if std::panic::catch_unwind(std::panic::AssertUnwindSafe(call)).is_err() {
                    self.failed.swap(true, Ordering::Relaxed);
                }
                #[cfg(not(feature = "std"))]
                call();
                done += 1;
                hg::released(self.tag());
                self.pending.fetch_sub(1, Ordering::Release);
                continue;
            }
            if !self.live.load(Ordering::Acquire) {
                let outcome = self.outcome.load(Ordering::Acquire);
                hg::released(self.tag());
                // The last touch of the join: the leader may return after it.
                self.departed.fetch_add(1, Ordering::AcqRel);
                return Helped::Done(outcome);
            }
            backoff();
        }
    }
}

/// The leader's side of a session.
struct Leader<'j> {
    join: &'j Join,
    workers: usize,
}

impl Par for Leader<'_> {
    fn workers(&self) -> usize {
        self.workers
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        let j = self.join;
        assert!(
            !j.running.swap(true, Ordering::Acquire),
            "Par::run called from a task or from two threads at once"
        );
        // Wait for the helpers however this run ends (a panic in task(0)
        // unwinds through here while they may still run the task).
        struct Wait<'j>(&'j Join);
        impl Drop for Wait<'_> {
            fn drop(&mut self) {
                let j = self.0;
                while j.pending.load(Ordering::Acquire) != 0 {
                    backoff();
                }
                hg::acquired(j.tag());
                j.running.swap(false, Ordering::Release);
            }
        }
        if self.workers > 1 {
            j.pending.swap(self.workers - 1, Ordering::Relaxed);
            // SAFETY: no helper reads `task` now (the previous run waited
            // for `pending` to reach 0); the release increment below
            // publishes it. The lifetime is erased: `Wait` keeps this call
            // from returning or unwinding past the caller's frame before
            // every helper is done with the task.
            unsafe {
                *j.task.get() = Some(TaskPtr(core::mem::transmute::<
                    *const (dyn Fn(usize) + Sync + '_),
                    *const (dyn Fn(usize) + Sync + 'static),
                >(task)))
            };
            hg::released(j.tag());
            j.ticket.fetch_add(1, Ordering::Release);
        }
        {
            let _wait = Wait(j);
            task(0);
        }
        assert!(
            !j.failed.load(Ordering::Relaxed),
            "a helper's part of a joined build panicked"
        );
    }
}

/// Wait a little: spin, then give the core away (with `std`).
#[inline]
fn backoff() {
    core::hint::spin_loop();
    #[cfg(feature = "std")]
    std::thread::yield_now();
}

#[cfg(all(test, feature = "std"))]
mod tests {
    use super::*;
    use core::sync::atomic::AtomicU64;

    #[test]
    fn shares_cover_in_order() {
        for n in [0usize, 1, 7, 1000] {
            for w in 1..9 {
                let mut next = 0;
                for k in 0..w {
                    let r = share(n, k, w);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, n);
            }
        }
    }

    /// A panic in any worker's part reaches the leader after every helper
    /// is done with the task; the session still closes and takes its
    /// helpers, and the join works afterwards.
    #[test]
    fn panics_wait_for_the_helpers_and_reach_the_leader() {
        let join = Join::new();
        for bad in [0usize, 1] {
            std::thread::scope(|s| {
                s.spawn(|| assert_eq!(join.help(1, 2), Helped::Done(7)));
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    join.lead(2, |par| {
                        join.set_outcome(7);
                        let v = [1u32, 2];
                        par.run(&|w| {
                            if w == bad {
                                panic!("worker {w}");
                            }
                            std::thread::sleep(std::time::Duration::from_millis(20));
                            assert_eq!(v[w], w as u32 + 1);
                        });
                    })
                }));
                assert!(r.is_err(), "worker {bad}'s panic reaches the leader");
            });
        }
        std::thread::scope(|s| {
            s.spawn(|| assert_eq!(join.help(1, 2), Helped::Done(0)));
            join.lead(2, |par| {
                join.set_outcome(0);
                par.run(&|_| {});
            });
        });
    }

    /// Until `n` helpers wait at the door for the next session.
    fn until_waiting(join: &Join, n: u32) {
        while join.door.with(|d| d.waiting) < n {
            std::thread::yield_now();
        }
    }

    /// Two helpers claiming one index, both waiting when the session
    /// opens: one joins, the other is refused at once; the build, its
    /// tasks and the next session are unharmed.
    #[test]
    fn a_taken_index_is_refused() {
        let join = Join::new();
        let sum = AtomicU64::new(0);
        std::thread::scope(|s| {
            let a = s.spawn(|| join.help(1, 2));
            let b = s.spawn(|| join.help(1, 2));
            until_waiting(&join, 2);
            join.lead(2, |par| {
                join.set_outcome(5);
                for _ in 0..20 {
                    par.run(&|w| {
                        sum.fetch_add(w as u64 + 1, Ordering::Relaxed);
                    });
                }
            });
            let mut got = [a.join().unwrap(), b.join().unwrap()];
            got.sort_by_key(|h| *h == Helped::Taken);
            assert_eq!(got, [Helped::Done(5), Helped::Taken]);
        });
        assert_eq!(
            sum.load(Ordering::Relaxed),
            20 * 3,
            "every task on both workers once"
        );
        std::thread::scope(|s| {
            s.spawn(|| assert_eq!(join.help(1, 2), Helped::Done(0)));
            join.lead(2, |par| {
                join.set_outcome(0);
                par.run(&|_| {});
            });
        });
    }

    /// A helper waiting beside a group it does not fit (index 2 of 3 by a
    /// session of 2, or index 1 of 3) is refused by that session, never
    /// kept for a later one; helpers that fit join it.
    #[test]
    fn a_waiting_helper_that_does_not_fit_is_refused() {
        for (me, count) in [(2usize, 3usize), (1, 3), (5, 16)] {
            let join = Join::new();
            std::thread::scope(|s| {
                let odd = s.spawn(|| join.help(me, count));
                until_waiting(&join, 1);
                let fits = s.spawn(|| join.help(1, 2));
                join.lead(2, |par| par.run(&|_| {}));
                assert_eq!(odd.join().unwrap(), Helped::NotAWorker, "({me}, {count})");
                assert_eq!(fits.join().unwrap(), Helped::Done(0));
            });
        }
    }

    #[test]
    fn sessions_without_tasks_take_their_helpers() {
        let join = Join::new();
        std::thread::scope(|s| {
            s.spawn(|| {
                for _ in 0..100 {
                    assert_eq!(join.help(1, 2), Helped::Done(0));
                }
            });
            for k in 0..100 {
                join.lead(2, |par| {
                    if k % 2 == 0 {
                        par.run(&|_| {});
                    }
                });
            }
        });
    }

    #[test]
    fn join_runs_every_task_on_every_worker() {
        let join = Join::new();
        for workers in [1usize, 2, 3] {
            let sum = AtomicU64::new(0);
            std::thread::scope(|s| {
                for me in 1..workers {
                    let j = &join;
                    s.spawn(move || assert_eq!(j.help(me, workers), Helped::Done(0)));
                }
                join.lead(workers, |par| {
                    assert_eq!(par.workers(), workers);
                    for round in 0..50u64 {
                        par.run(&|w| {
                            sum.fetch_add(round * 10 + w as u64 + 1, Ordering::Relaxed);
                        });
                    }
                });
            });
            let per_round: u64 = (1..=workers as u64).sum();
            let want: u64 = (0..50u64)
                .map(|r| r * 10 * workers as u64 + per_round)
                .sum();
            assert_eq!(sum.load(Ordering::Relaxed), want, "{workers} workers");
        }
    }
}
