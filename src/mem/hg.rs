//! Helgrind's user-defined synchronisation objects (valgrind's
//! `helgrind.h`: `ANNOTATE_HAPPENS_BEFORE` / `_AFTER`).
//!
//! Helgrind sees synchronisation through pthread calls and its client
//! requests, not through atomics. sheaf's own locks (the C ABI's state word
//! and last-error lock, the thread slots' claim flags) tell it about the
//! happens-before edges they make, so the C tests run under helgrind with
//! no suppressions for sheaf; every access to those atomics is a locked
//! instruction (no plain stores), which helgrind does not report as a race.
//! Outside valgrind a client request is a few register rotations that
//! change nothing.

/// `VG_USERREQ_TOOL_BASE('H', 'G') + 256 + 33` and `+ 34`:
/// `_VG_USERREQ__HG_USERSO_SEND_PRE` and `_RECV_POST`.
const BASE: usize = ((b'H' as usize) << 24) | ((b'G' as usize) << 16);
const SEND_PRE: usize = BASE + 256 + 33;
const RECV_POST: usize = BASE + 256 + 34;

/// After an acquire of the object `tag`.
#[inline(always)]
pub fn acquired(tag: usize) {
    request(RECV_POST, tag);
}

/// Before a release of the object `tag`.
#[inline(always)]
pub fn released(tag: usize) {
    request(SEND_PRE, tag);
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn request(code: usize, arg: usize) {
    let args: [usize; 6] = [code, arg, 0, 0, 0, 0];
    let _result: usize;
    // SAFETY: valgrind's client-request preamble for amd64
    // (valgrind.h, VALGRIND_DO_CLIENT_REQUEST_EXPR): rdi is rotated by
    // 3 + 13 + 61 + 51 = 128 bits, i.e. left unchanged, and `xchg rbx,
    // rbx` is a no-op, so natively the block only sets flags and
    // returns the default (0) in rdx; under valgrind it reads the six
    // words at rax (alive on this stack frame) and writes rdx.
    unsafe {
        core::arch::asm!(
            "rol rdi, 3",
            "rol rdi, 13",
            "rol rdi, 61",
            "rol rdi, 51",
            "xchg rbx, rbx",
            inout("rdx") 0usize => _result,
            in("rax") args.as_ptr(),
            options(nostack),
        );
    }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn request(_code: usize, _arg: usize) {}
