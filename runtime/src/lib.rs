//! taxel-runtime owns what every taxel process shares: the process skeleton (one signal owner
//! setting a shutdown flag, tracing set-up, exit codes: 0 on requested shutdown, 2 for bad
//! configuration, 1 for runtime failures), the monotonic capture clock, and the iceoryx2
//! plumbing (a node per process with a configurable service prefix, and "streams": a
//! publish-subscribe service paired with an event service of the same name, notified after
//! every send so consumers wake on data through a WaitSet), the sensor lists of processes that
//! serve several sensors (`sensors`), and real-time scheduling (`priority`).

pub mod clock;
pub mod filewatch;
pub mod ipc;
pub mod priority;
pub mod process;
pub mod progress;
pub mod sensors;
pub mod signals;
pub mod stats;
pub mod wake;

pub use clock::now_ns;
pub use ipc::{Ipc, StreamPublisher, StreamSubscriber};
pub use process::{CommonArgs, Failure, Shutdown};
