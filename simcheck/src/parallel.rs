//! Two-way parallelism without nesting: the cross-validation runs its two folds side by side,
//! and an evaluation outside a fold splits its nodes (or rows) between two threads. A thread
//! that is already one of two never splits again, so the machine's cores are not
//! oversubscribed. Results never depend on whether work was split: each item is computed on
//! its own and the callers reduce them in item order.

use std::cell::Cell;
use std::sync::OnceLock;

thread_local! {
    static INSIDE: Cell<bool> = const { Cell::new(false) };
}

fn cores() -> usize {
    static CORES: OnceLock<usize> = OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Runs `f` with this thread marked as one of a parallel pair (restored afterwards).
fn marked<T>(f: impl FnOnce() -> T) -> T {
    let was = INSIDE.with(|c| c.replace(true));
    let out = f();
    INSIDE.with(|c| c.set(was));
    out
}

/// Whether work started on this thread may be split over two threads.
fn may_split() -> bool {
    cores() >= 2 && !INSIDE.with(Cell::get)
}

/// `a` and `b`, side by side when the machine has two cores and this thread is not already one
/// of a pair; one after the other otherwise.
pub fn join<A: Send, B: Send>(
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    if !may_split() {
        return (a(), b());
    }
    std::thread::scope(|sc| {
        let h = sc.spawn(|| marked(a));
        let rb = marked(b);
        let ra = h.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
        (ra, rb)
    })
}

/// `f(0), f(1), ..., f(items - 1)`, in that order; the first half computed on a second thread
/// when [`join`] would split.
pub fn map<T: Send>(items: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    if items < 2 || !may_split() {
        return (0..items).map(f).collect();
    }
    let half = items / 2;
    let (mut first, second) = join(
        || (0..half).map(&f).collect::<Vec<T>>(),
        || (half..items).map(&f).collect::<Vec<T>>(),
    );
    first.extend(second);
    first
}

#[cfg(test)]
mod tests {
    #[test]
    fn map_keeps_the_order_and_does_not_nest() {
        let v = super::map(9, |i| {
            // Inside a split, a nested map runs sequentially and still in order.
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
}
