//! taxel-consumers owns the processes that use the streams: `control`, an example grip-force
//! controller that measures every sample's age and goes to a safe state on stale or invalid
//! data; `logger`, which records the raw, curvature, force and reference streams of one or more
//! sensors into a crash-tolerant record file and exports it to the recording CSV schema or
//! MCAP; `latency`, a probe that reports sample-age percentiles and drops; and `monitor`, a live
//! terminal UI of the sensors and processes under a prefix.

pub mod age;
pub mod control;
pub mod latency;
pub mod logger;
pub mod monitor;
