//! Parallelism on a pool of worker threads, one per core (rayon's): the cross-validation runs
//! its two folds side by side, and an evaluation splits its nodes (or rows) between the
//! workers. Work split inside a fold is split again, and an idle worker steals it, so a fold
//! that finishes first helps the other. Results never depend on whether or how work was
//! split: each item is computed on its own and the callers reduce them in item order.

use std::sync::OnceLock;

/// Runs `f` on one of the pool's workers (one per core), the calling thread waiting. The work
/// between parallel sections then runs on a worker too, so the process has as many busy
/// threads as cores: an idle worker looking for work never competes with the thread doing
/// it. Without a pool (it could not be built) `f` runs here.
pub fn install<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    let pool = POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads(cores)
            .thread_name(|i| format!("simcheck-{i}"))
            .build()
            .ok()
    });
    match pool {
        Some(p) => p.install(|| crate::timing::top(f)),
        None => crate::timing::top(f),
    }
}

/// `a` and `b`, side by side when a worker is free; one after the other otherwise.
pub fn join<A: Send, B: Send>(
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    crate::timing::parallel_section(|| rayon::join(a, b))
}

/// Calls `f(c, chunk)` on each `size`-long chunk `c` of `out` (the last may be shorter), the
/// chunks spread over the workers: for filling a large array element by element.
pub fn chunks_mut<T: Send>(out: &mut [T], size: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    use rayon::prelude::*;
    crate::timing::parallel_section(|| {
        out.par_chunks_mut(size.max(1))
            .enumerate()
            .for_each(|(c, chunk)| f(c, chunk))
    });
}

/// [`chunks_mut`] over two arrays of the same length at once.
pub fn chunks_mut2<T: Send, U: Send>(
    a: &mut [T],
    b: &mut [U],
    size: usize,
    f: impl Fn(usize, &mut [T], &mut [U]) + Sync,
) {
    use rayon::prelude::*;
    let size = size.max(1);
    crate::timing::parallel_section(|| {
        a.par_chunks_mut(size)
            .zip(b.par_chunks_mut(size))
            .enumerate()
            .for_each(|(c, (ca, cb))| f(c, ca, cb))
    });
}

/// Sorts `v` by `cmp`, stably (equal items keep their order: the same order as
/// `slice::sort_by`), the work spread over the workers.
pub fn sort_by<T: Send>(v: &mut [T], cmp: impl Fn(&T, &T) -> std::cmp::Ordering + Sync) {
    use rayon::prelude::*;
    crate::timing::parallel_section(|| v.par_sort_by(cmp));
}

/// `f(0), f(1), ..., f(items - 1)`, in that order; the items spread over the workers.
pub fn map<T: Send>(items: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    use rayon::prelude::*;
    crate::timing::parallel_section(|| (0..items).into_par_iter().map(&f).collect())
}

#[cfg(test)]
mod tests {
    #[test]
    fn map_keeps_the_order_nested_too() {
        let v = super::map(9, |i| {
            // Inside a split, a nested map may split again and is still in order.
            let inner = super::map(3, |j| i * 10 + j);
            (i, inner)
        });
        for (i, (got, inner)) in v.iter().enumerate() {
            assert_eq!(*got, i);
            assert_eq!(inner, &vec![i * 10, i * 10 + 1, i * 10 + 2]);
        }
        let (a, b) = super::join(|| 1, || 2);
        assert_eq!((a, b), (1, 2));
    }

    #[test]
    fn chunks_are_filled_where_they_lie() {
        let mut a = vec![0usize; 1000];
        let mut b = vec![0usize; 1000];
        super::chunks_mut(&mut a, 64, |c, out| {
            for (j, v) in out.iter_mut().enumerate() {
                *v = c * 64 + j;
            }
        });
        assert!(a.iter().enumerate().all(|(i, v)| *v == i));
        super::chunks_mut2(&mut a, &mut b, 100, |c, x, y| {
            for (u, v) in x.iter_mut().zip(y.iter_mut()) {
                *v = *u + c;
                *u = c;
            }
        });
        assert!(a.iter().enumerate().all(|(i, v)| *v == i / 100));
        assert!(b.iter().enumerate().all(|(i, v)| *v == i + i / 100));
    }

    #[test]
    fn the_parallel_sort_keeps_equal_items_in_order() {
        // Keys with many ties; the second field records the original position.
        let mut v: Vec<(u64, usize)> = (0..100_000)
            .map(|i| ((i as u64).wrapping_mul(2_654_435_761) % 97, i))
            .collect();
        let mut want = v.clone();
        want.sort_by_key(|p| std::cmp::Reverse(p.0));
        super::sort_by(&mut v, |a, b| b.0.cmp(&a.0));
        assert_eq!(v, want);
    }
}
