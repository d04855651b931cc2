//! Row-parallel loops over an image on scoped threads, in contiguous blocks of rows.

/// Runs `f(row, row_slice)` over all rows on `threads` workers (contiguous blocks of rows).
pub(crate) fn par_rows<T: Send>(
    out: &mut [T],
    width: usize,
    threads: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    if out.is_empty() || width == 0 {
        return;
    }
    let height = out.len() / width.max(1);
    let threads = threads.clamp(1, height.max(1));
    let rows_per = height.div_ceil(threads);
    std::thread::scope(|s| {
        for (block, chunk) in out.chunks_mut(rows_per * width).enumerate() {
            let f = &f;
            s.spawn(move || {
                for (k, row) in chunk.chunks_mut(width).enumerate() {
                    f(block * rows_per + k, row);
                }
            });
        }
    });
}

pub(crate) fn thread_count(requested: usize) -> usize {
    if requested > 0 {
        requested
    } else {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

/// Runs `f(row, row_a, row_b)` over the rows of two images of the same shape on `threads`
/// workers (contiguous blocks of rows).
pub(crate) fn par_rows_pair<A: Send, B: Send>(
    a: &mut [A],
    b: &mut [B],
    width: usize,
    threads: usize,
    f: impl Fn(usize, &mut [A], &mut [B]) + Sync,
) {
    assert_eq!(a.len(), b.len(), "images of one shape");
    if a.is_empty() || width == 0 {
        return;
    }
    let height = a.len() / width.max(1);
    let threads = threads.clamp(1, height.max(1));
    let rows_per = height.div_ceil(threads);
    std::thread::scope(|s| {
        let blocks = a
            .chunks_mut(rows_per * width)
            .zip(b.chunks_mut(rows_per * width));
        for (block, (ca, cb)) in blocks.enumerate() {
            let f = &f;
            s.spawn(move || {
                for (k, (ra, rb)) in ca.chunks_mut(width).zip(cb.chunks_mut(width)).enumerate() {
                    f(block * rows_per + k, ra, rb);
                }
            });
        }
    });
}
