//! A cache-line prefetch hint for walks whose next reads are known a step
//! ahead (the 4-wide collapse reads each binary node's children one pop
//! later). A hint only: it never faults and changes no value.

/// Ask the CPU to bring the cache line holding `x` closer (x86-64:
/// `prefetcht0`; elsewhere nothing).
#[inline(always)]
pub(crate) fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `prefetcht0` needs SSE, which every x86-64 CPU has (it is in
    // the target's baseline), and it reads nothing architecturally: a
    // prefetch of any address never faults. `x` is a live reference anyway.
    unsafe {
        use core::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<{ _MM_HINT_T0 }>((x as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}
