//! taxel-publisher owns the sources of raw frames: the physics-based simulator (`sim`), a
//! recording played back (`replay`), and (with the serial issue) the readout board. Each source
//! produces frames; the publish loop paces them, stamps `t_capture_ns` once, assigns the
//! per-sensor `seq`, and sends `RawFrame`s (plus `Reference` values when the source knows them)
//! on `taxel/<sensor>/raw` and `taxel/<sensor>/reference`.

pub mod cli;
pub mod run;
pub mod serial;
pub mod source;
