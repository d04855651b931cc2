//! Splitting a frame's independent rows over the two threads of a scan.

/// Runs `f(part, first)` on the two halves of `data` (whole chunks of `chunk` items; `first` is
/// the index of the part's first chunk), the second half on another thread. Each item is
/// computed the same way whichever thread does it, so the result does not depend on the split.
pub(crate) fn in_two<T: Send>(data: &mut [T], chunk: usize, f: impl Fn(&mut [T], usize) + Sync) {
    let half = data.len() / chunk / 2;
    let (a, b) = data.split_at_mut(half * chunk);
    std::thread::scope(|s| {
        s.spawn(|| f(b, half));
        f(a, 0);
    });
}
