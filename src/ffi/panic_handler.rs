//! The opt-in `#[panic_handler]` of the no_std library (feature
//! `panic-handler`), for C programs that link the no_std staticlib or
//! cdylib. Without std nothing can unwind, so a panic (a bug in sheaf:
//! caller input is validated so that none reaches one, and fuzzed) cannot
//! become `SHEAF_STATUS_PANIC`: it traps, stopping the program where a
//! debugger shows it, instead of spinning forever.

#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    trap()
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
fn trap() -> ! {
    // SAFETY: `ud2` raises an invalid-opcode exception (SIGILL on Unix); it
    // touches no memory and never returns.
    unsafe { core::arch::asm!("ud2", options(noreturn, nomem, nostack)) }
}

#[cfg(target_arch = "aarch64")]
fn trap() -> ! {
    // SAFETY: `brk` raises a breakpoint exception (SIGTRAP on Unix); it
    // touches no memory and never returns.
    unsafe { core::arch::asm!("brk #0x1", options(noreturn, nomem, nostack)) }
}

#[cfg(not(any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64")))]
fn trap() -> ! {
    // No trap instruction known here: stop without burning a core.
    loop {
        core::hint::spin_loop();
    }
}

/// The precompiled `core` the no_std library links was built to unwind and
/// refers to this symbol from its unwind tables; with `panic = "abort"`
/// (the `release-nostd` profile) nothing ever unwinds, so it is never
/// called. Defined here so the staticlib links into C programs without a
/// Rust std (the usual no_std workaround; the real one needs a nightly
/// `-Z build-std`).
#[unsafe(no_mangle)]
extern "C" fn rust_eh_personality() {}
