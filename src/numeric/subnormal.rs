//! Subnormal numbers flushed to zero while a simulation runs.
//!
//! A diffusing signal leaves most of a long ladder's far nodes, their
//! Newton corrections and the LU's intermediate products below
//! `f64::MIN_POSITIVE` (2.2e-308) for much of a run. On Intel cores every
//! operation on a subnormal takes a microcode assist of about a hundred
//! cycles: a 10^4-section RC ladder ran 2.5× slower (the error norm's
//! divisions and the sparse substitution were half the run), a 10^5 one
//! 3.2×. No tolerance reaches down there (the smallest absolute tolerance
//! is 1e-12 of a volt or ampere), so the run treats them as zero, as the
//! hardware can: flush results to zero (FTZ) and read subnormal inputs as
//! zero (DAZ). The mode is the calling thread's and is restored by the
//! guard's drop.

/// The thread's floating-point mode as it was, restored on drop.
pub struct FlushSubnormals {
    #[cfg_attr(
        not(any(target_arch = "x86_64", target_arch = "aarch64")),
        allow(dead_code)
    )]
    saved: u64,
}

/// Flush subnormals to zero on this thread until the guard is dropped; a
/// no-op where the architecture has no such mode here.
pub fn flush_subnormals() -> FlushSubnormals {
    let saved = read_mode();
    write_mode(saved | FLUSH_BITS);
    FlushSubnormals { saved }
}

impl Drop for FlushSubnormals {
    fn drop(&mut self) {
        write_mode(self.saved);
    }
}

/// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6).
#[cfg(target_arch = "x86_64")]
const FLUSH_BITS: u64 = 0x8040;

/// FPCR's flush-to-zero (bit 24), which on AArch64 covers inputs as well.
#[cfg(target_arch = "aarch64")]
const FLUSH_BITS: u64 = 1 << 24;

#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
const FLUSH_BITS: u64 = 0;

#[cfg(target_arch = "x86_64")]
fn read_mode() -> u64 {
    let mut csr: u32 = 0;
    // SAFETY: stmxcsr stores the 32-bit control register at the pointer,
    // which points at a live u32.
    unsafe {
        std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack, preserves_flags));
    }
    u64::from(csr)
}

#[cfg(target_arch = "x86_64")]
fn write_mode(mode: u64) {
    let csr = mode as u32;
    // SAFETY: ldmxcsr loads the control register from a live u32; the bits
    // written are those read by `read_mode` with at most FTZ and DAZ added,
    // which change rounding of subnormals only, never raise a trap.
    unsafe {
        std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, preserves_flags, readonly));
    }
}

#[cfg(target_arch = "aarch64")]
fn read_mode() -> u64 {
    let fpcr: u64;
    // SAFETY: reading FPCR has no effect but the read.
    unsafe {
        std::arch::asm!("mrs {}, fpcr", out(reg) fpcr, options(nomem, nostack, preserves_flags));
    }
    fpcr
}

#[cfg(target_arch = "aarch64")]
fn write_mode(mode: u64) {
    // SAFETY: the value written is FPCR as read with at most FZ added,
    // which changes the treatment of subnormals only.
    unsafe {
        std::arch::asm!("msr fpcr, {}", in(reg) mode, options(nomem, nostack, preserves_flags));
    }
}

#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
fn read_mode() -> u64 {
    0
}

#[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
fn write_mode(_: u64) {}

#[cfg(test)]
mod tests {
    use super::*;

    /// Under the guard a product below the normal range is zero, and after
    /// it the thread computes subnormals again.
    #[test]
    fn subnormals_are_flushed_under_the_guard_only() {
        let tiny = std::hint::black_box(1e-300_f64);
        let below = std::hint::black_box(1e-10_f64);
        assert!(tiny * below > 0.0, "subnormal before the guard");
        {
            let _guard = flush_subnormals();
            let p = std::hint::black_box(tiny) * std::hint::black_box(below);
            if FLUSH_BITS != 0 {
                assert_eq!(p, 0.0);
            }
        }
        let p = std::hint::black_box(tiny) * std::hint::black_box(below);
        assert!(p > 0.0 && p < f64::MIN_POSITIVE, "restored after: {p:e}");
    }
}
