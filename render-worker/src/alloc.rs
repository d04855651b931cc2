//! Process-wide allocator settings for the binaries that run sessions (the server with its
//! in-process worker, and the render-worker).

/// Most glibc malloc arenas. glibc gives busy threads arenas of their own (up to 8 per core),
/// and memory freed in an arena mostly stays with the process: every session thread that
/// rendered a frame kept its peak. Measured with the capacity bench (quick rows, default phantom,
/// 2 cores, two runs each): server RSS with 1 / 4 / 8 live sessions 1,062 / 1,256 / 1,498 and
/// 1,057 / 1,216 / 1,515 MiB with glibc's default, 968 / 1,080 / 1,283 and 937 / 1,065 / 1,278
/// MiB with 2 arenas (about 63 -> 47 MB per added session), latencies alike. A worker process
/// runs the same session threads.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MALLOC_ARENAS: i32 = 2;

/// Caps glibc's malloc arenas at [`MALLOC_ARENAS`], unless `MALLOC_ARENA_MAX` says otherwise
/// (glibc has applied that already). Call it first thing in `main`, before other threads.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[expect(unsafe_code, reason = "mallopt(3) has no safe wrapper; it only sets a malloc tunable")]
pub fn limit_malloc_arenas() {
    if std::env::var_os("MALLOC_ARENA_MAX").is_none() {
        // SAFETY: mallopt takes two integers and changes a tunable of the process's allocator;
        // callers call it first thing in main, before any other thread exists.
        unsafe {
            libc::mallopt(libc::M_ARENA_MAX, MALLOC_ARENAS);
        }
    }
}

/// Nothing to cap outside glibc.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn limit_malloc_arenas() {}
