//! Process-wide signal dispositions other than shutdown (which `process::Shutdown` owns).
//!
//! A writer that exceeds the file-size limit (`ulimit -f`, RLIMIT_FSIZE) is killed by SIGXFSZ
//! unless the signal is ignored; ignored, the write fails with EFBIG instead, which a process
//! that must keep running (the logger) handles like a full disk.

/// Makes a write beyond the file-size limit fail with EFBIG instead of killing the process.
pub fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to SIG_IGN installs no handler code and is
    // async-signal-safe; it only changes how the kernel treats SIGXFSZ for this process.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}
