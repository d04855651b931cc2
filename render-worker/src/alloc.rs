//! Process-wide allocator settings for the binaries that run sessions (the server with its
//! in-process worker, and the render-worker), and handing free memory back when they are quiet.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

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
#[expect(
    unsafe_code,
    reason = "mallopt(3) has no safe wrapper; it only sets a malloc tunable"
)]
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

/// Frames being rendered and published now, in the whole process (see [`busy`]).
static BUSY: AtomicUsize = AtomicUsize::new(0);

/// When the last frame in flight ended, ms after [`epoch`] (0: none yet).
static LAST_FRAME_END_MS: AtomicU64 = AtomicU64::new(0);

/// How long the process must have had no frame in flight before its free memory is handed back,
/// ms. A hand-back walks every arena's free chunks with the arena locked (3 to 35 ms with the
/// default lumbar station's sessions, 2 cores), and the pages it returns are faulted in again
/// by the next frames that use them. Done after every busy period, it made the capacity bench's
/// p95 at 8 learners 1,145 and 1,227 ms against 893 and 940 ms without it (two runs each,
/// quick rows); learners pause one to two seconds, so a server in use rarely idles this long.
const QUIET_MS: u64 = 1_000;

fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

fn now_ms() -> u64 {
    epoch().elapsed().as_millis() as u64 + 1
}

/// A frame in flight: hold it while a session renders and publishes. Once the process has had no
/// frame in flight for `QUIET_MS` (1 s), a background thread hands the allocator's free memory back
/// to the system (once per quiet period). glibc keeps memory freed inside its heaps: every
/// session's frames free megabytes of transient buffers between longer-lived allocations, and
/// that memory stayed resident (sessions bench, memory section, default lumbar station: about
/// 23 MB of resident memory per added session, of which the allocator counted about 9 MB in
/// use).
pub fn busy() -> Busy {
    static JANITOR: OnceLock<()> = OnceLock::new();
    JANITOR.get_or_init(|| {
        let spawned = std::thread::Builder::new()
            .name("memory-release".into())
            .spawn(release_when_quiet);
        if let Err(e) = spawned {
            tracing::warn!("no memory-release thread: {e}");
        }
    });
    BUSY.fetch_add(1, Ordering::SeqCst);
    Busy(())
}

/// See [`busy`].
#[must_use = "the frame is in flight while this is held"]
pub struct Busy(());

impl Drop for Busy {
    fn drop(&mut self) {
        // The latest end wins when frames end at once on several threads.
        LAST_FRAME_END_MS.fetch_max(now_ms(), Ordering::SeqCst);
        BUSY.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The memory-release thread: hands free memory back once after each busy period (see [`busy`]).
fn release_when_quiet() {
    let mut released_after_ms = 0;
    loop {
        std::thread::sleep(Duration::from_millis(QUIET_MS / 4));
        let last_end = LAST_FRAME_END_MS.load(Ordering::SeqCst);
        if release_due(
            now_ms(),
            last_end,
            released_after_ms,
            BUSY.load(Ordering::SeqCst),
        ) {
            release_free_memory();
            released_after_ms = last_end;
        }
    }
}

/// Whether to hand memory back at `now_ms`: no frame in flight (`busy`), none ended within
/// [`QUIET_MS`], and frames have ended since the last hand-back (which followed the frame that
/// ended at `released_after_ms`).
fn release_due(now_ms: u64, last_end_ms: u64, released_after_ms: u64, busy: usize) -> bool {
    busy == 0 && last_end_ms > released_after_ms && now_ms.saturating_sub(last_end_ms) >= QUIET_MS
}

/// Hands the free memory of every malloc arena back to the system (malloc_trim(3)).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[expect(
    unsafe_code,
    reason = "malloc_trim(3) has no safe wrapper; it only returns free pages"
)]
fn release_free_memory() {
    // SAFETY: malloc_trim takes an integer (the padding to keep) and only releases memory the
    // allocator holds free; it is thread-safe (it locks each arena in turn).
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Other allocators hand memory back themselves.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn release_free_memory() {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_goes_back_once_after_a_quiet_period() {
        let q = QUIET_MS;
        // Frames ended at 100 ms; nothing released yet.
        assert!(
            !release_due(100 + q - 1, 100, 0, 0),
            "not quiet long enough"
        );
        assert!(release_due(100 + q, 100, 0, 0));
        assert!(!release_due(100 + q, 100, 0, 1), "a frame in flight");
        // Released after the frame of 100 ms: not again until another frame ends.
        assert!(!release_due(100 + 5 * q, 100, 100, 0));
        assert!(!release_due(900 + q - 1, 900, 100, 0));
        assert!(release_due(900 + q, 900, 100, 0));
        // No frame ever: nothing to release.
        assert!(!release_due(10 * q, 0, 0, 0));
    }
}
