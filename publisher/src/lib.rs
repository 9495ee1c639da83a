//! taxel-publisher owns the sources of raw frames (`source`): the physics-based simulator
//! (`sim`), a recording played back (`replay`: recording CSV or MCAP), and the readout board
//! over a serial port (`serial`: wire-format detection, framing, stalls and replugs). Each
//! source produces frames; the publish loop (`run`) paces them, stamps `t_capture_ns` once,
//! assigns the per-sensor `seq`, flags gaps, and sends `RawFrame`s (plus `Reference` values
//! when the source knows them) on `taxel/<sensor>/raw` and `taxel/<sensor>/reference`; offline
//! it writes a source into a recording CSV (`--to-csv`).

pub mod cli;
pub mod run;
pub mod serial;
pub mod source;
