//! taxel-supervisor owns running a pipeline as separate OS processes: the pipeline file of
//! `taxel up` (`pipeline`: TOML, parsed with `deny_unknown_fields`, validated into the list of
//! processes; `layout`: the shared layout, one process per role for many sensors), the supervisor (`supervise`: starts every role as a child `taxel <role> ...`,
//! restarts the dead with backoff inside a restart budget, cleans their iceoryx2 resources,
//! stops everything stage by stage; `children`: process groups, exit reasons, peak memory),
//! and the three commands built on it: `taxel up PIPELINE.toml` (`up`), the simulated demo
//! (`demo`) and the fault-injecting soak test (`soak`). Children are started from the running
//! executable, so this library only works inside the `taxel` launcher.

pub mod children;
pub mod demo;
pub mod layout;
pub mod pipeline;
pub mod soak;
pub mod supervise;
pub mod up;
