//! taxel-msgs owns the payload types that travel through iceoryx2 shared memory and the names
//! of the services that carry them. Nothing else lives here: every process links this one crate,
//! so a payload is defined exactly once (types defined per binary are refused by iceoryx2 as
//! incompatible). Every payload is `#[repr(C)]`, `Copy`, fixed size, carries an explicit
//! versioned type name, and has its size asserted next to it. Units are in the field names.
//! Each payload's fields are listed once more, in `fields`: the table every file format
//! (record file, MCAP JSON, CSV export) is derived from, checked by the compiler against the
//! struct.

pub mod fields;

pub use fields::{Field, Message, Visitor};

use iceoryx2::prelude::ZeroCopySend;

/// Largest array the fixed-size payloads hold: 32 x 32 nodes.
pub const MAX_NODES: usize = 1024;
/// Largest number of calibration blocks a [`ForceSample`] carries (the whole array is separate).
pub const MAX_BLOCKS: usize = 8;
/// Bytes reserved for a sensor id (UTF-8, zero padded, at most `SENSOR_ID_LEN - 1` bytes used).
pub const SENSOR_ID_LEN: usize = 32;

/// A sensor id in a fixed buffer, e.g. `glove0`. Valid ids are 1..=31 bytes of
/// `[A-Za-z0-9_-]`, so they can be used verbatim in service names and file names.
pub type SensorIdBytes = [u8; SENSOR_ID_LEN];

/// Why a sensor id was refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BadSensorId(pub String);

impl std::fmt::Display for BadSensorId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "invalid sensor id {:?}: use 1 to {} characters from A-Z a-z 0-9 _ -",
            self.0,
            SENSOR_ID_LEN - 1
        )
    }
}
impl std::error::Error for BadSensorId {}

/// Checks a sensor id and packs it into its fixed buffer.
pub fn sensor_id_bytes(id: &str) -> Result<SensorIdBytes, BadSensorId> {
    let ok = !id.is_empty()
        && id.len() < SENSOR_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if !ok {
        return Err(BadSensorId(id.to_string()));
    }
    let mut out = [0u8; SENSOR_ID_LEN];
    out[..id.len()].copy_from_slice(id.as_bytes());
    Ok(out)
}

/// Reads a sensor id back from its fixed buffer (stops at the first zero byte; invalid UTF-8,
/// which a valid writer never produces, reads as `"?"`).
pub fn sensor_id_str(bytes: &SensorIdBytes) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(SENSOR_ID_LEN);
    std::str::from_utf8(&bytes[..end]).unwrap_or("?")
}

/// Where a raw frame came from (`RawFrame::source`).
pub mod source {
    /// The physics-based simulator.
    pub const SIM: u32 = 1;
    /// The readout board over a serial port.
    pub const SERIAL: u32 = 2;
    /// A recording played back.
    pub const REPLAY: u32 = 3;
    /// An external program, through the Python bindings' `taxel.Publisher`.
    pub const EXTERNAL: u32 = 4;
}

/// Bits of `RawFrame::flags`.
pub mod raw_flags {
    /// Frames were lost before this one (source hiccup, device gap, reconnect); `seq` also jumps.
    pub const GAP_BEFORE: u32 = 1 << 0;
    /// At least one node sits at the top ADC code (rail clipping).
    pub const RAIL: u32 = 1 << 1;
    /// Bits 8-11: the readout the source declares (0: not declared; 1 amplifier, 2 divider
    /// rising with force, 3 divider falling, 4 resistance in ohms, 5 inverted ADC). Calibrators
    /// and estimators refuse a declared readout their file was not made for.
    pub const READOUT_SHIFT: u32 = 8;
    pub const READOUT_MASK: u32 = 0xF << READOUT_SHIFT;

    /// The readout code in `flags`.
    pub fn readout_code(flags: u32) -> u32 {
        (flags & READOUT_MASK) >> READOUT_SHIFT
    }

    /// `flags` with the readout code set to `code` (0..=15).
    pub fn with_readout_code(flags: u32, code: u32) -> u32 {
        (flags & !READOUT_MASK) | ((code << READOUT_SHIFT) & READOUT_MASK)
    }
}

/// One scan of the array, stamped once at capture.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("taxel.RawFrame.v1")]
pub struct RawFrame {
    /// Frame sequence number, consecutive per sensor; a jump means frames were lost.
    pub seq: u64,
    /// CLOCK_MONOTONIC time (ns) at which the frame was captured, copied through every stage.
    pub t_capture_ns: u64,
    /// Sensor id (see [`sensor_id_str`]).
    pub sensor: SensorIdBytes,
    /// Array geometry; `rows * cols <= MAX_NODES`.
    pub rows: u16,
    pub cols: u16,
    /// [`raw_flags`] bits.
    pub flags: u32,
    /// One of the [`source`] codes.
    pub source: u32,
    /// Full-scale value of the readings (1023 for a 10-bit ADC; 0 when unknown, e.g. a replayed
    /// resistance in ohms). Used to detect rail clipping.
    pub full_scale: f32,
    /// Raw reading per node, row-major (`node = row * cols + col`), as the board reports it: ADC
    /// counts for the paper's board. Only the first `rows * cols` entries are meaningful.
    pub counts: [f32; MAX_NODES],
}
const _: () =
    assert!(core::mem::size_of::<RawFrame>() == 8 + 8 + 32 + 4 + 4 + 4 + 4 + 4 * MAX_NODES);

impl RawFrame {
    /// An all-zero frame (used to initialise shared-memory samples).
    pub const ZERO: RawFrame = RawFrame {
        seq: 0,
        t_capture_ns: 0,
        sensor: [0; SENSOR_ID_LEN],
        rows: 0,
        cols: 0,
        flags: 0,
        source: 0,
        full_scale: 0.0,
        counts: [0.0; MAX_NODES],
    };
    /// Number of meaningful nodes.
    pub fn n_nodes(&self) -> usize {
        (self.rows as usize * self.cols as usize).min(MAX_NODES)
    }
    /// The meaningful readings.
    pub fn nodes(&self) -> &[f32] {
        &self.counts[..self.n_nodes()]
    }
}

/// Bits of `CurvatureEstimate::flags`.
pub mod curvature_flags {
    /// The curvature is the configured value, not a learned estimate.
    pub const CONFIGURED: u32 = 1 << 0;
    /// The curvature comes from a learned model.
    pub const ESTIMATED: u32 = 1 << 1;
    /// The estimate falls outside the range the model was trained on.
    pub const OUT_OF_RANGE: u32 = 1 << 2;
    /// The curvature was predicted from the first no-load window after mounting and is held;
    /// this estimate only renews the baseline (which drifts, e.g. after presses).
    pub const HELD: u32 = 1 << 3;
}

/// The mounting curvature and the no-load baseline it was derived from.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("taxel.CurvatureEstimate.v1")]
pub struct CurvatureEstimate {
    /// `seq` of the last frame of the no-load window.
    pub seq: u64,
    /// `t_capture_ns` of that frame.
    pub t_capture_ns: u64,
    /// `t_capture_ns` of the first frame of the window.
    pub t_window_start_ns: u64,
    pub sensor: SensorIdBytes,
    pub rows: u16,
    pub cols: u16,
    /// Curvature of the mounting surface (1/m).
    pub curvature_m1: f32,
    /// One standard deviation of `curvature_m1` (1/m); 0 for a configured value.
    pub curvature_sd_m1: f32,
    /// Version of the curvature model (0 for a configured value).
    pub model_version: u32,
    /// [`curvature_flags`] bits.
    pub flags: u32,
    /// Number of frames averaged into the baseline.
    pub window_frames: u32,
    /// Counts how many baselines this estimator has published (1 for the first).
    pub estimate_index: u32,
    /// Explicit padding (always 0) so the layout has no hidden bytes.
    pub reserved: u32,
    /// Mean no-load reading per node over the window, row-major; first `rows * cols` entries used.
    pub baseline: [f32; MAX_NODES],
}
const _: () =
    assert!(core::mem::size_of::<CurvatureEstimate>() == 8 * 3 + 32 + 4 + 4 * 7 + 4 * MAX_NODES);

impl CurvatureEstimate {
    pub const ZERO: CurvatureEstimate = CurvatureEstimate {
        seq: 0,
        t_capture_ns: 0,
        t_window_start_ns: 0,
        sensor: [0; SENSOR_ID_LEN],
        rows: 0,
        cols: 0,
        curvature_m1: 0.0,
        curvature_sd_m1: 0.0,
        model_version: 0,
        flags: 0,
        window_frames: 0,
        estimate_index: 0,
        reserved: 0,
        baseline: [0.0; MAX_NODES],
    };
    pub fn n_nodes(&self) -> usize {
        (self.rows as usize * self.cols as usize).min(MAX_NODES)
    }
}

/// Bits of `ForceSample::flags`.
pub mod force_flags {
    /// A node of the frame sits at the top ADC code: the force is a lower bound.
    pub const SATURATED: u32 = 1 << 0;
    /// A reading or the curvature lies outside the calibration's declared range; the force was
    /// evaluated at the range's edge (never extrapolated).
    pub const OUT_OF_RANGE: u32 = 1 << 1;
    /// The curvature estimate is older than the configured staleness limit.
    pub const CURVATURE_STALE: u32 = 1 << 2;
    /// No curvature estimate has arrived: the calibrator's default curvature was used.
    pub const CURVATURE_DEFAULTED: u32 = 1 << 3;
    /// No no-load baseline is known yet: forces are NaN.
    pub const NO_BASELINE: u32 = 1 << 4;
    /// The raw frame followed a gap.
    pub const GAP_BEFORE: u32 = 1 << 5;
    /// No no-load baseline has been measured on this stream yet: the forces use the
    /// calibration file's `no_load_reading` (set together with `NO_BASELINE`).
    pub const BASELINE_FROM_CALIBRATION: u32 = 1 << 6;
    /// The calibration has dynamic terms whose state is not known yet: the calibrator started
    /// with the sensor loaded, or restarted with hysteresis terms, and the largest creep time
    /// constant has not passed or the force has not swept every play yet.
    pub const DYNAMICS_WARMING: u32 = 1 << 7;
}

/// Calibrated forces for one frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("taxel.ForceSample.v2")]
pub struct ForceSample {
    /// `seq` of the raw frame, copied through.
    pub seq: u64,
    /// `t_capture_ns` of the raw frame, copied through.
    pub t_capture_ns: u64,
    /// CLOCK_MONOTONIC time (ns) at which the calibrator published this sample.
    pub t_publish_ns: u64,
    pub sensor: SensorIdBytes,
    /// Force on the whole array (N).
    pub total_force_n: f32,
    /// Reading S of the whole array (baseline-subtracted sum of counts).
    pub total_reading: f32,
    /// Curvature used by the calibration (1/m).
    pub curvature_m1: f32,
    /// `version` declared in the calibration file in use.
    pub cal_version: u32,
    /// How many calibration files this calibrator has loaded successfully (1 = the first).
    pub cal_generation: u32,
    /// `model_version` of the curvature estimate used.
    pub curvature_model_version: u32,
    /// [`force_flags`] bits.
    pub flags: u32,
    /// Number of meaningful entries in `block_force_n` / `block_reading`.
    pub n_blocks: u32,
    /// Force per calibration block (N), in the order of the calibration file.
    pub block_force_n: [f32; MAX_BLOCKS],
    /// Reading S per block (baseline-subtracted sum of counts).
    pub block_reading: [f32; MAX_BLOCKS],
    /// Age of the no-load zero in use (s): this frame's capture time minus the end of the
    /// no-load window the estimator published it from (every such window re-zeroes). NaN while
    /// the zero is the calibration file's `no_load_reading` or there is none.
    pub zero_age_s: f32,
    /// Explicit padding (always 0) so the layout has no hidden bytes.
    pub reserved: u32,
}
const _: () =
    assert!(core::mem::size_of::<ForceSample>() == 8 * 3 + 32 + 4 * 8 + 4 * 2 * MAX_BLOCKS + 4 + 4);

impl ForceSample {
    pub const ZERO: ForceSample = ForceSample {
        seq: 0,
        t_capture_ns: 0,
        t_publish_ns: 0,
        sensor: [0; SENSOR_ID_LEN],
        total_force_n: 0.0,
        total_reading: 0.0,
        curvature_m1: 0.0,
        cal_version: 0,
        cal_generation: 0,
        curvature_model_version: 0,
        flags: 0,
        n_blocks: 0,
        block_force_n: [0.0; MAX_BLOCKS],
        block_reading: [0.0; MAX_BLOCKS],
        zero_age_s: f32::NAN,
        reserved: 0,
    };
    pub fn blocks(&self) -> &[f32] {
        &self.block_force_n[..(self.n_blocks as usize).min(MAX_BLOCKS)]
    }
}

/// Reference values for one frame: the simulator's ground truth, or the reference columns of a
/// replayed recording (`force_n`, `curvature_m1`, `temp_c`, `trial`), so that recordings of live
/// runs carry the reference columns of the recording CSV schema. NaN marks a value the source
/// does not know.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("taxel.Reference.v1")]
pub struct Reference {
    pub seq: u64,
    pub t_capture_ns: u64,
    pub sensor: SensorIdBytes,
    /// Source time of the frame (s): simulation time, or the recording's `t_s`.
    pub t_source_s: f64,
    /// Total applied force (N).
    pub force_n: f32,
    /// Mounting curvature (1/m).
    pub curvature_m1: f32,
    /// Ambient temperature (degC).
    pub temp_c: f32,
    /// Trial (mounting) index; -1 when unknown.
    pub trial: i32,
}
const _: () = assert!(core::mem::size_of::<Reference>() == 8 * 2 + 32 + 8 + 4 * 4);

impl Reference {
    pub const ZERO: Reference = Reference {
        seq: 0,
        t_capture_ns: 0,
        sensor: [0; SENSOR_ID_LEN],
        t_source_s: 0.0,
        force_n: 0.0,
        curvature_m1: 0.0,
        temp_c: 0.0,
        trial: 0,
    };
}

/// The streams of one sensor. Each is a publish-subscribe service paired with an event service
/// of the same name that is notified after every send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// [`RawFrame`]s from the publisher.
    Raw,
    /// [`CurvatureEstimate`]s from the estimator (history 1: late joiners get the latest).
    Curvature,
    /// [`ForceSample`]s from the calibrator (history 1).
    Force,
    /// [`Reference`] values from the sim or replay source.
    Reference,
}

impl Stream {
    pub const ALL: [Stream; 4] = [
        Stream::Raw,
        Stream::Curvature,
        Stream::Force,
        Stream::Reference,
    ];
    /// Last path component of the service name.
    pub fn suffix(self) -> &'static str {
        match self {
            Stream::Raw => "raw",
            Stream::Curvature => "curvature",
            Stream::Force => "force",
            Stream::Reference => "reference",
        }
    }
    /// How many past samples a late-joining subscriber receives.
    pub fn history(self) -> usize {
        match self {
            Stream::Raw | Stream::Reference => 0,
            Stream::Curvature | Stream::Force => 1,
        }
    }
    /// Samples each subscriber can hold before the oldest is overwritten: the time a reader may
    /// be descheduled without losing anything. Streams with one sample per frame (raw, force,
    /// and reference, which the sim and replay sources send with every frame) run at up to kHz
    /// rates and get 256 (256 ms at 1 kHz: a restarting neighbour loading its model stalls a
    /// reader for 50-60 ms on a 2-core machine); curvature estimates come at a few Hz.
    pub fn buffer(self) -> usize {
        match self {
            Stream::Raw | Stream::Force | Stream::Reference => 256,
            Stream::Curvature => 64,
        }
    }
}

/// The service name of one stream of one sensor: `taxel/<sensor>/<stream>`.
pub fn service_name(sensor: &str, stream: Stream) -> String {
    format!("taxel/{sensor}/{}", stream.suffix())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_ids_round_trip_and_bad_ones_are_refused() {
        let b = sensor_id_bytes("glove_0-a").expect("valid");
        assert_eq!(sensor_id_str(&b), "glove_0-a");
        for bad in ["", "a/b", "x y", &"z".repeat(32), "é"] {
            assert!(sensor_id_bytes(bad).is_err(), "{bad:?} accepted");
        }
        assert!(sensor_id_bytes(&"z".repeat(31)).is_ok());
    }

    #[test]
    fn streams_with_a_sample_per_frame_buffer_as_much_as_raw() {
        // The logger takes raw and reference rows side by side: a stall that raw survives must
        // not lose references.
        for s in [Stream::Force, Stream::Reference] {
            assert_eq!(s.buffer(), Stream::Raw.buffer(), "{s:?}");
        }
        assert!(Stream::Curvature.buffer() < Stream::Raw.buffer());
    }

    #[test]
    fn service_names_are_per_sensor() {
        assert_eq!(service_name("s0", Stream::Raw), "taxel/s0/raw");
        assert_eq!(service_name("s1", Stream::Force), "taxel/s1/force");
    }

    #[test]
    fn type_names_are_versioned() {
        use iceoryx2::prelude::ZeroCopySend;
        // SAFETY: type_name only returns the string given in the derive attribute.
        unsafe {
            assert_eq!(RawFrame::type_name(), "taxel.RawFrame.v1");
            assert_eq!(ForceSample::type_name(), "taxel.ForceSample.v2");
            assert_eq!(CurvatureEstimate::type_name(), "taxel.CurvatureEstimate.v1");
            assert_eq!(Reference::type_name(), "taxel.Reference.v1");
        }
    }
}
