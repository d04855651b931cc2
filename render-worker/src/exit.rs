//! Ending a process that has used the graphics driver.
//!
//! A process that returns from `main` runs the C library's exit handlers, and with them the
//! static destructors of the graphics driver and of the LLVM inside Mesa's lavapipe. Threads
//! that `main` does not join keep running meanwhile: the start-up calibration (a frame of the
//! heaviest station takes a quarter of a second on 2 cores, and it times many), a replay or an
//! anatomy build that a request started and that the runtime's shutdown left behind. One of them
//! building a shader while LLVM's globals are destroyed aborts the process: a CI run of the
//! server's SIGTERM test ended in SIGABRT after "LLVM ERROR: Do not know how to split the result
//! of this operator!", after every session thread had been joined and the database stopped
//! (`server/tests/session_sigkill.rs`, once in a CI run of 2026-11-30). Other drivers' exit
//! handlers have been seen to hang.
//!
//! So the binaries that host sessions stop what must be stopped themselves (sessions joined,
//! records stored, the database shut down) and then leave with [`after_shutdown`], which
//! flushes the standard streams and ends the process without the exit handlers. The kernel
//! releases its memory, files and sockets; nothing of the driver's state outlives the process.

use std::io::Write;

/// Flushes stdout and stderr, then ends the process with `code` without running the C library's
/// exit handlers or Rust's end-of-`main` clean-up (see the module docs). Call it only once
/// everything that must be kept is stored: it does not return, and no destructor runs after it.
#[expect(
    unsafe_code,
    reason = "_exit(2) (the process ends without its exit handlers) has no safe wrapper in std"
)]
pub fn after_shutdown(code: u8) -> ! {
    // A closed stream (a parent that stopped reading) must not keep the process alive.
    let _ = std::io::stdout().lock().flush();
    let _ = std::io::stderr().lock().flush();
    // SAFETY: _exit takes an integer and never returns; the kernel ends every thread of the
    // process at once, so no thread of it can observe a half-torn-down state.
    unsafe { libc::_exit(i32::from(code)) }
}
