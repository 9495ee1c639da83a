//! The allocator's settings for the command: a diagnosis allocates and frees arrays of every
//! node and sample (7.7 MB on a 10-minute 4 x 4 recording at 100 Hz) thousands of times, on
//! several threads. With glibc's defaults each array comes fresh from the kernel or is handed
//! back to it when freed, and every page is faulted in and zeroed again. [`keep_freed_memory`]
//! keeps freed memory in the process for the next array instead.

/// glibc only: arrays up to 32 MiB (the largest it allows) come from the heap, not from their
/// own mapping, and up to 1 GiB of free memory at the heap's top is kept, not returned. On the
/// 10-minute recording: about half the system time and 4 % of the wall time, the same report.
/// Elsewhere: nothing.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt takes no pointers and may be called at any time (glibc takes its
        // arenas' locks); it only changes two thresholds, and a refused value leaves the default.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
            libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        }
    }
}
