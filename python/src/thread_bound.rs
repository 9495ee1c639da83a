//! Values that must stay on the thread that made them (iceoryx2 ports and nodes are not
//! thread-safe), inside Python objects that any thread can reach. Every use checks the thread
//! and raises `taxel.TaxelError` elsewhere, instead of PyO3's panic for `unsendable` classes.

use std::mem::ManuallyDrop;
use std::thread::ThreadId;

use pyo3::PyResult;

use crate::bad;

/// A value reachable only on the thread that made it.
pub(crate) struct ThreadBound<T> {
    owner: ThreadId,
    value: ManuallyDrop<T>,
}

// SAFETY: the value is reached only through `get`, which takes `&mut self` and checks that the
// caller runs on the owner thread, and it is dropped only on that thread (elsewhere it is
// leaked). So the value is only ever used, and dropped, where it was made; a shared reference
// gives no access to it.
unsafe impl<T> Send for ThreadBound<T> {}
unsafe impl<T> Sync for ThreadBound<T> {}

impl<T> ThreadBound<T> {
    pub(crate) fn new(value: T) -> ThreadBound<T> {
        ThreadBound {
            owner: std::thread::current().id(),
            value: ManuallyDrop::new(value),
        }
    }

    /// The value, on its own thread; on any other, a `TaxelError` naming `what`.
    pub(crate) fn get(&mut self, what: impl FnOnce() -> String) -> PyResult<&mut T> {
        if std::thread::current().id() == self.owner {
            Ok(&mut self.value)
        } else {
            Err(bad(format!(
                "{}: used from a thread other than the one that made it; iceoryx2 ports are not \
                 thread-safe, so use it on that thread (or open another on this one)",
                what()
            )))
        }
    }
}

impl<T> Drop for ThreadBound<T> {
    fn drop(&mut self) {
        if std::thread::current().id() == self.owner {
            // SAFETY: dropped once, here, and never used again.
            unsafe { ManuallyDrop::drop(&mut self.value) }
        }
        // Collected on another thread: leaked (its node is removed when the process ends),
        // since dropping iceoryx2 ports elsewhere is not allowed.
    }
}
