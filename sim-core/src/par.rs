//! An ordered parallel map over indices on scoped threads (no thread-pool dependency).

/// Runs `f(0..n)` on up to one thread per core (each thread taking the next index) and returns
/// the results in index order; `done(i)` is called on the calling thread as each one finishes.
pub(crate) fn par_map<T: Send>(
    n: usize,
    f: &(dyn Fn(usize) -> T + Sync),
    done: &mut dyn FnMut(usize),
) -> Vec<T> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    par_map_on(cores, n, f, done)
}

/// [`par_map`] on up to `workers` threads.
pub(crate) fn par_map_on<T: Send>(
    workers: usize,
    n: usize,
    f: &(dyn Fn(usize) -> T + Sync),
    done: &mut dyn FnMut(usize),
) -> Vec<T> {
    let threads = workers.clamp(1, n.max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<Option<T>> = (0..n).map(|_| None).collect();
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::channel::<(usize, T)>();
        for _ in 0..threads {
            let (tx, next) = (tx.clone(), &next);
            scope.spawn(move || {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    if i >= n || tx.send((i, f(i))).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for (i, r) in rx.iter() {
            done(i);
            out[i] = Some(r);
        }
    });
    out.into_iter()
        .map(|r| r.expect("every index is taken by exactly one worker"))
        .collect()
}

/// [`par_map`] of `f` over `0..weights.len()`, the indices taken heaviest first (so the last
/// job to start is a light one and the workers finish together), results in index order.
pub(crate) fn par_map_heaviest_first<T: Send>(
    weights: &[usize],
    f: &(dyn Fn(usize) -> T + Sync),
) -> Vec<T> {
    par_map_heaviest_first_told(weights, f, &mut |_| {})
}

/// [`par_map_heaviest_first`], calling `finished(i)` on the calling thread as index `i` finishes.
pub(crate) fn par_map_heaviest_first_told<T: Send>(
    weights: &[usize],
    f: &(dyn Fn(usize) -> T + Sync),
    finished: &mut dyn FnMut(usize),
) -> Vec<T> {
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(weights[i]));
    let done = par_map(order.len(), &|k| (order[k], f(order[k])), &mut |k| {
        finished(order[k]);
    });
    let mut out: Vec<Option<T>> = (0..weights.len()).map(|_| None).collect();
    for (i, r) in done {
        out[i] = Some(r);
    }
    out.into_iter()
        .map(|r| r.expect("every index is taken once"))
        .collect()
}

/// A scoped helper thread's result, its panic passed on.
pub(crate) fn joined<T>(r: std::thread::Result<T>) -> T {
    r.unwrap_or_else(|p| std::panic::resume_unwind(p))
}
