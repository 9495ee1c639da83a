//! taxel-formats owns every file format taxel reads or writes: the recording CSV schema that all
//! offline tools share (`csv`), the logger's crash-tolerant record file (`records`), its
//! export to the recording CSV schema (`export`) and to MCAP for Foxglove, and MCAP import
//! (`mcap`); the one bincode envelope (magic + format version, trailing bytes rejected) that
//! model files use (`envelope`); and what a board's reading is (`readout`: amplifier, divider,
//! resistance, inverted, and the signal rising with conductance that calibrations and
//! curvature models work on). The record file, the MCAP messages and the CSV export are derived
//! from the field tables of taxel-msgs, so every payload field reaches them. Readers never
//! panic on bad input: errors name the file and the line or byte offset. Documented in
//! docs/formats.md.

pub mod crc;
pub mod csv;
pub mod envelope;
pub mod export;
pub mod mcap;
pub mod readout;
pub mod records;

pub use csv::{Geometry, Recording, RecordingWriter};
pub use export::CsvExport;
pub use readout::{Readout, ReadoutKind};
pub use records::{Record, RecordFileReader, RecordFileWriter};
