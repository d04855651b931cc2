//! Which work yields the cores: the full frame that refines a draft already on a learner's
//! screen is the one render nobody waits on, so its helper threads run at a lower CPU priority
//! than every other session's first frames (drafts, shots, needle steps, live pulses).
//!
//! A session's thread marks such a render with [`refining`]; code that spreads a render over
//! helper threads takes [`Priority::of_this_thread`] before spawning them and calls
//! [`Priority::enter`] first thing in each. Only helper threads are lowered: they end with their
//! render, so no thread ever needs its priority raised again (which an unprivileged process may
//! not do). Alone on the machine a lowered thread runs as fast as before (the scheduler only
//! weighs threads that compete).

use std::cell::Cell;

/// How much a refining render's helper threads add to their nice value (at most 19). Simulator
/// choice: under Linux's fair scheduler a thread 10 nice steps lower weighs 110 against 1024,
/// so a draft that competes with a refinement gets about nine tenths of a core.
pub const REFINING_NICE_STEP: i32 = 10;

thread_local! {
    static REFINING: Cell<bool> = const { Cell::new(false) };
}

/// Marks this thread's renders as refinements until the guard drops.
#[must_use = "the mark lasts while the guard lives"]
pub struct Refining {
    before: bool,
}

/// Marks the renders this thread starts from now on, until the guard drops, as refinements of
/// a frame already shown.
pub fn refining() -> Refining {
    Refining {
        before: REFINING.with(|r| r.replace(true)),
    }
}

impl Drop for Refining {
    fn drop(&mut self) {
        REFINING.with(|r| r.set(self.before));
    }
}

/// The priority a render's helper threads take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Priority {
    /// As the process runs.
    Normal,
    /// Lowered by [`REFINING_NICE_STEP`]: a refinement.
    Refining,
}

impl Priority {
    /// The priority of the render this thread is doing now.
    pub fn of_this_thread() -> Priority {
        if REFINING.with(Cell::get) {
            Priority::Refining
        } else {
            Priority::Normal
        }
    }

    /// Takes this priority on the calling thread, a helper thread that ends with the render.
    /// Nothing on platforms without per-thread nice values, or where the call fails.
    pub fn enter(self) {
        if self == Priority::Refining {
            lower_this_thread(REFINING_NICE_STEP);
        }
    }
}

/// Adds `step` to the calling thread's nice value, up to 19 (Linux keeps one per thread).
#[cfg(target_os = "linux")]
#[expect(
    unsafe_code,
    reason = "setpriority(2) has no safe wrapper; it changes only the calling thread's nice value"
)]
fn lower_this_thread(step: i32) {
    let nice = (nice_of_this_thread() + step).min(19);
    // SAFETY: PRIO_PROCESS with `who` 0 names the calling thread on Linux; the call reads and
    // writes no memory of ours.
    let r = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) };
    if r != 0 {
        tracing::debug!(
            "lowering a refinement thread: {}",
            std::io::Error::last_os_error()
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn lower_this_thread(_step: i32) {}

/// The calling thread's nice value (Linux).
#[cfg(target_os = "linux")]
#[expect(
    unsafe_code,
    reason = "getpriority(2) has no safe wrapper; it only reads the calling thread's nice value"
)]
pub fn nice_of_this_thread() -> i32 {
    // SAFETY: as above, a read of the calling thread's nice value.
    unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn helpers_of_a_refining_render_run_lowered_and_the_session_thread_does_not() {
        let mine = nice_of_this_thread();
        let helper = |p: Priority| {
            std::thread::scope(|s| {
                s.spawn(move || {
                    p.enter();
                    nice_of_this_thread()
                })
                .join()
                .unwrap()
            })
        };
        assert_eq!(Priority::of_this_thread(), Priority::Normal);
        assert_eq!(helper(Priority::of_this_thread()), mine);
        {
            let _r = refining();
            assert_eq!(Priority::of_this_thread(), Priority::Refining);
            {
                let _nested = refining();
            }
            assert_eq!(
                Priority::of_this_thread(),
                Priority::Refining,
                "nested guard"
            );
            assert_eq!(
                helper(Priority::of_this_thread()),
                (mine + REFINING_NICE_STEP).min(19),
                "a helper of a refinement"
            );
        }
        assert_eq!(Priority::of_this_thread(), Priority::Normal);
        assert_eq!(helper(Priority::of_this_thread()), mine);
        assert_eq!(
            nice_of_this_thread(),
            mine,
            "the calling thread keeps its priority"
        );
    }
}
