//! Which renders newer input stops: a full frame that refines a draft already on a learner's
//! screen is obsolete once the learner has moved the view again (the probe slid on), and a
//! session then draws the new view's draft instead of finishing the old frame.
//!
//! A session's thread watches a flag with [`watching`] around such a render; the host raises
//! the flag when a command that moves a view arrives (`CommandSpec::supersedes`). A renderer
//! that can stop part-way takes [`Interrupt::of_this_thread`] (before it spawns helpers, which
//! do not share the thread-local) and asks [`Interrupt::is_raised`] between pieces of its work;
//! a render it gives up ends with the modality's `Interrupted` error and leaves its view dirty,
//! so nothing half-done is shown or kept. Renders nobody has seen a draft of (a shot, a needle
//! step, a draft itself) are never watched.
//!
//! A second flag, watched with [`watching_input`], says that any command waits for the
//! session: work not begun yet (a refinement or prefetch still waiting for its turn at the GPU
//! targets) then gives up its low place in line, and the session takes the command first
//! and renders what it needs at the priority of a frame someone waits on. Work under way is
//! not stopped by it: the command needs that work anyway.

use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

thread_local! {
    static WATCHED: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
    static INPUT: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
}

/// Makes `flag` stop the renders this thread starts from now on, until the guard drops.
pub fn watching(flag: &Arc<AtomicBool>) -> Watching {
    Watching {
        watched: Some(WATCHED.with(|w| w.replace(Some(Arc::clone(flag))))),
        input: None,
    }
}

/// Makes `flag` say, until the guard drops, that a command waits for the session while this
/// thread's renders wait for their turn (see [`Interrupt::input_waits`]).
pub fn watching_input(flag: &Arc<AtomicBool>) -> Watching {
    Watching {
        watched: None,
        input: Some(INPUT.with(|w| w.replace(Some(Arc::clone(flag))))),
    }
}

/// Lets nothing stop the renders this thread starts from now on, until the guard drops: for a
/// render the watched input does not make obsolete (a modality knows which of its own).
pub fn unwatched() -> Watching {
    Watching {
        watched: Some(WATCHED.with(|w| w.replace(None))),
        input: Some(INPUT.with(|w| w.replace(None))),
    }
}

/// A thread's watch of its flags (see [`watching`], [`watching_input`]); the flags it replaced
/// come back on drop.
#[must_use = "the watch lasts while the guard lives"]
pub struct Watching {
    watched: Option<Option<Arc<AtomicBool>>>,
    input: Option<Option<Arc<AtomicBool>>>,
}

impl Drop for Watching {
    fn drop(&mut self) {
        if let Some(before) = self.watched.take() {
            WATCHED.with(|w| *w.borrow_mut() = before);
        }
        if let Some(before) = self.input.take() {
            INPUT.with(|w| *w.borrow_mut() = before);
        }
    }
}

/// What may stop the render this thread is doing now: a flag, or nothing.
#[derive(Debug, Clone, Default)]
pub struct Interrupt {
    flag: Option<Arc<AtomicBool>>,
    input: Option<Arc<AtomicBool>>,
}

impl Interrupt {
    /// The flag this thread watches now (none outside [`watching`]).
    pub fn of_this_thread() -> Interrupt {
        Interrupt {
            flag: WATCHED.with(|w| w.borrow().clone()),
            input: INPUT.with(|w| w.borrow().clone()),
        }
    }

    /// Whether the render should stop: newer input has made it obsolete.
    pub fn is_raised(&self) -> bool {
        self.flag
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    }

    /// Whether any command waits for the session (see [`watching_input`]).
    pub fn input_waits(&self) -> bool {
        self.input
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_watch_lasts_while_its_guard_lives_reaches_helpers_and_is_suspended_by_unwatched() {
        let flag = Arc::new(AtomicBool::new(false));
        assert!(!Interrupt::of_this_thread().is_raised());
        {
            let _w = watching(&flag);
            let i = Interrupt::of_this_thread();
            assert!(!i.is_raised());
            flag.store(true, Ordering::Relaxed);
            // A helper thread sees the flag through the handle taken before it was spawned,
            // and nothing of its own.
            let seen = std::thread::scope(|s| {
                s.spawn(|| (i.is_raised(), Interrupt::of_this_thread().is_raised()))
                    .join()
                    .unwrap()
            });
            assert_eq!(seen, (true, false));
            let other = Arc::new(AtomicBool::new(false));
            {
                let _nested = watching(&other);
                assert!(!Interrupt::of_this_thread().is_raised(), "nested watch");
            }
            {
                let _none = unwatched();
                assert!(!Interrupt::of_this_thread().is_raised(), "unwatched");
            }
            assert!(
                Interrupt::of_this_thread().is_raised(),
                "the outer watch is back"
            );
        }
        assert!(
            !Interrupt::of_this_thread().is_raised(),
            "no watch after the guard"
        );
    }

    #[test]
    fn the_input_flag_reaches_the_handle_and_unwatched_clears_both_flags() {
        let input = Arc::new(AtomicBool::new(true));
        let flag = Arc::new(AtomicBool::new(true));
        assert!(!Interrupt::of_this_thread().input_waits());
        {
            let _w = watching(&flag);
            let _i = watching_input(&input);
            let i = Interrupt::of_this_thread();
            assert!(i.is_raised() && i.input_waits());
            {
                let _none = unwatched();
                let i = Interrupt::of_this_thread();
                assert!(!i.is_raised() && !i.input_waits(), "unwatched");
            }
            let i = Interrupt::of_this_thread();
            assert!(i.is_raised() && i.input_waits(), "both back");
            input.store(false, Ordering::Relaxed);
            assert!(!Interrupt::of_this_thread().input_waits());
        }
        let i = Interrupt::of_this_thread();
        assert!(!i.is_raised() && !i.input_waits(), "both dropped");
    }
}
