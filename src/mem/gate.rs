//! Misuse detection across threads for bindings that share one context
//! between threads without Rust's borrow rules (the C ABI: a `const
//! sheaf_context *` on many threads): a context's call gate and a lock for
//! a small value (its last error), both plain atomics, so they work
//! without std. Rust callers get the same guarantees from `&`/`&mut`.
//!
//! The state word counts the shared calls inside the context (trace,
//! occluded, the `_slot` calls, render_rows, stats, deferred_pixel...) and
//! has one bit for an exclusive call (set_geometry, clear_geometry, the
//! builds, the renders that record stats, destroy) and one for a context
//! poisoned by a caught panic. Entering costs one atomic read-modify-write
//! per call (never per ray); a call that finds the context held the other
//! way leaves at once with `Error::ContextBusy` and changes nothing.
//!
//! Helgrind (valgrind) does not see synchronisation through atomics, only
//! through pthread calls and its client requests; on x86-64 every acquire
//! and release below also tells helgrind about the happens-before edge it
//! makes (`hg`), so `ffi-tests/test_threads.c` runs under helgrind with no
//! suppressions for sheaf. Outside valgrind a client request is a few
//! register rotations that change nothing.

use super::hg;
use crate::error::{Error, Result};
use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

/// The state word's exclusive bit; the low bits count shared calls.
const EXCLUSIVE: u32 = 1 << 31;
/// Set by a caught panic: every later call but last_error and destroy
/// returns `Error::Poisoned`.
const POISONED: u32 = 1 << 30;
/// Set by destroy, forever: no call enters any more ("not a live context").
const DYING: u32 = 1 << 29;
/// The bits of calls inside: the exclusive bit and the shared count.
const INSIDE: u32 = EXCLUSIVE | (DYING - 1);

/// One context's state word (`CallGate::enter_shared`, `enter_exclusive`,
/// `enter_destroy`, `poison`).
pub struct CallGate(AtomicU32);

impl Default for CallGate {
    fn default() -> CallGate {
        CallGate::new()
    }
}

impl CallGate {
    /// A gate with no call inside.
    pub const fn new() -> CallGate {
        CallGate(AtomicU32::new(0))
    }

    /// Register a shared call: `Err(ContextBusy)` while an exclusive call
    /// runs, `Err(Poisoned)` after a panic. The guard leaves on drop.
    pub fn enter_shared(&self) -> Result<SharedGuard<'_>> {
        let prev = self.0.fetch_add(1, Ordering::Acquire);
        if prev & (EXCLUSIVE | POISONED | DYING) != 0 {
            self.0.fetch_sub(1, Ordering::Relaxed);
            return Err(refusal(prev));
        }
        hg::acquired(self.tag());
        Ok(SharedGuard(self))
    }

    /// Take the context exclusively: `Err(ContextBusy)` while any other
    /// call is inside, `Err(Poisoned)` after a panic.
    pub fn enter_exclusive(&self) -> Result<ExclusiveGuard<'_>> {
        match self
            .0
            .compare_exchange(0, EXCLUSIVE, Ordering::Acquire, Ordering::Relaxed)
        {
            Ok(_) => {
                hg::acquired(self.tag());
                Ok(ExclusiveGuard(self))
            }
            Err(now) => Err(refusal(now)),
        }
    }

    /// Take the context for destroy: from now on every call is refused (as
    /// on a destroyed context); then wait for the calls already inside to
    /// return.
    /// False when another destroy got here first (it does the work). The
    /// word is never released: the memory is freed or handed back.
    pub fn enter_destroy(&self) -> bool {
        if self.0.fetch_or(DYING, Ordering::Acquire) & DYING != 0 {
            return false;
        }
        while self.0.load(Ordering::Acquire) & INSIDE != 0 {
            core::hint::spin_loop();
            #[cfg(feature = "std")]
            std::thread::yield_now();
        }
        hg::acquired(self.tag());
        true
    }

    /// Whether destroy has started (a locked read: helgrind sees every
    /// access to the word as atomic).
    pub fn dead(&self) -> bool {
        self.0.fetch_or(0, Ordering::Acquire) & DYING != 0
    }

    /// Poison the context (a panic was caught inside a call).
    pub fn poison(&self) {
        self.0.fetch_or(POISONED, Ordering::Relaxed);
    }

    fn tag(&self) -> usize {
        core::ptr::from_ref(self) as usize
    }
}

fn refusal(state: u32) -> Error {
    if state & DYING != 0 {
        Error::InvalidArgument("not a live sheaf_context (destroyed?)")
    } else if state & POISONED != 0 {
        Error::Poisoned
    } else {
        Error::ContextBusy
    }
}

/// A registered shared call; leaves on drop.
pub struct SharedGuard<'s>(&'s CallGate);

impl Drop for SharedGuard<'_> {
    fn drop(&mut self) {
        hg::released(self.0.tag());
        self.0.0.fetch_sub(1, Ordering::Release);
    }
}

/// An exclusive call; releases on drop.
pub struct ExclusiveGuard<'s>(&'s CallGate);

impl Drop for ExclusiveGuard<'_> {
    fn drop(&mut self) {
        hg::released(self.0.tag());
        self.0.0.fetch_and(!EXCLUSIVE, Ordering::Release);
    }
}

/// A lock for a small `Copy` value (the last error), held for a copy only.
pub struct Locked<T: Copy> {
    locked: AtomicBool,
    value: UnsafeCell<T>,
}

// SAFETY: `value` is only accessed between a successful swap of `locked`
// to true (Acquire) and its store back to false (Release), so by one
// thread at a time; T is Copy + Send, copied in and out.
unsafe impl<T: Copy + Send> Sync for Locked<T> {}

impl<T: Copy> Locked<T> {
    pub const fn new(v: T) -> Locked<T> {
        Locked {
            locked: AtomicBool::new(false),
            value: UnsafeCell::new(v),
        }
    }

    fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        while self.locked.swap(true, Ordering::Acquire) {
            core::hint::spin_loop();
        }
        let tag = core::ptr::from_ref(self) as usize;
        hg::acquired(tag);
        // SAFETY: the lock is held (see the Sync impl); `f` cannot reach
        // the slot again (it is private to this module's callers' closures,
        // which only copy a value).
        let r = f(unsafe { &mut *self.value.get() });
        hg::released(tag);
        // A locked swap, not a plain store: helgrind sees every access to
        // the flag as atomic (a plain store would look like a race).
        self.locked.swap(false, Ordering::Release);
        r
    }

    pub fn set(&self, v: T) {
        self.with(|x| *x = v);
    }

    pub fn get(&self) -> T {
        self.with(|x| *x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_calls_share_and_exclusive_calls_wait_for_none() {
        let s = CallGate::new();
        let a = s.enter_shared().unwrap();
        let b = s.enter_shared().unwrap();
        assert_eq!(s.enter_exclusive().err(), Some(Error::ContextBusy));
        drop(a);
        assert_eq!(s.enter_exclusive().err(), Some(Error::ContextBusy));
        drop(b);
        let x = s.enter_exclusive().unwrap();
        assert_eq!(s.enter_shared().err(), Some(Error::ContextBusy));
        assert_eq!(s.enter_exclusive().err(), Some(Error::ContextBusy));
        drop(x);
        // A refused shared call left no count behind.
        assert_eq!(s.0.load(Ordering::Relaxed), 0);
        assert!(s.enter_exclusive().is_ok());
    }

    #[test]
    fn a_poisoned_context_refuses_everything_but_destroy() {
        let s = CallGate::new();
        s.poison();
        assert_eq!(s.enter_shared().err(), Some(Error::Poisoned));
        assert_eq!(s.enter_exclusive().err(), Some(Error::Poisoned));
        assert!(s.enter_destroy());
        // Destroyed: nothing enters again.
        assert!(s.enter_shared().is_err());
        assert!(!s.enter_destroy());
    }

    #[test]
    fn destroy_waits_for_the_calls_inside_and_refuses_new_ones() {
        let s = CallGate::new();
        let inside = s.enter_shared().unwrap();
        std::thread::scope(|sc| {
            let d = sc.spawn(|| s.enter_destroy());
            while s.0.load(Ordering::Relaxed) & DYING == 0 {
                std::thread::yield_now();
            }
            let gone = Some(Error::InvalidArgument(
                "not a live sheaf_context (destroyed?)",
            ));
            assert_eq!(s.enter_shared().err(), gone);
            assert_eq!(s.enter_exclusive().err(), gone);
            assert!(!d.is_finished());
            drop(inside);
            assert!(d.join().unwrap());
        });
    }

    #[test]
    fn the_last_error_slot_copies_in_and_out() {
        let slot = Locked::new(None);
        assert_eq!(slot.get(), None);
        slot.set(Some(Error::NotBuilt));
        assert_eq!(slot.get(), Some(Error::NotBuilt));
    }
}
