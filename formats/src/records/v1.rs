//! Record files of format version 1 (written until the field tables of taxel-msgs existed):
//! each payload is a bincode 2 (serde, standard config) value of the frozen enum below. They
//! are read into the same [`Record`] as version 2 files. What version 1 did not store reads as
//! zero (a force sample's `curvature_model_version`, an estimate's `estimate_index`); an
//! estimate's array shape, which version 1 did not store either, is taken as square when its
//! baseline has a square number of nodes, else as one row.

use serde::Deserialize;
use taxel_msgs::{
    CurvatureEstimate, ForceSample, RawFrame, Reference, SensorIdBytes, MAX_BLOCKS, MAX_NODES,
    SENSOR_ID_LEN,
};

use super::Record;

/// The record of format version 1, field for field (do not change: files hold it).
#[derive(Deserialize)]
enum RecordV1 {
    Raw {
        sensor: String,
        seq: u64,
        t_capture_ns: u64,
        rows: u16,
        cols: u16,
        flags: u32,
        source: u32,
        full_scale: f32,
        counts: Vec<f32>,
    },
    Curvature {
        sensor: String,
        seq: u64,
        t_capture_ns: u64,
        t_window_start_ns: u64,
        curvature_m1: f32,
        curvature_sd_m1: f32,
        model_version: u32,
        flags: u32,
        window_frames: u32,
        baseline: Vec<f32>,
    },
    Force {
        sensor: String,
        seq: u64,
        t_capture_ns: u64,
        t_publish_ns: u64,
        total_force_n: f32,
        total_reading: f32,
        curvature_m1: f32,
        cal_version: u32,
        cal_generation: u32,
        flags: u32,
        block_force_n: Vec<f32>,
        block_reading: Vec<f32>,
    },
    Reference {
        sensor: String,
        seq: u64,
        t_capture_ns: u64,
        t_source_s: f64,
        force_n: f32,
        curvature_m1: f32,
        temp_c: f32,
        trial: i32,
    },
}

/// The sensor id bytes of a stored id (at most `SENSOR_ID_LEN - 1` bytes).
pub(super) fn sensor_bytes(s: &[u8]) -> Result<SensorIdBytes, String> {
    if s.len() >= SENSOR_ID_LEN {
        return Err(format!(
            "sensor id of {} bytes (at most {})",
            s.len(),
            SENSOR_ID_LEN - 1
        ));
    }
    let mut out = [0u8; SENSOR_ID_LEN];
    out[..s.len()].copy_from_slice(s);
    Ok(out)
}

/// Copies `from` into the start of `to` when it fits.
fn fill(to: &mut [f32], from: &[f32], what: &str) -> Result<(), String> {
    if from.len() > to.len() {
        return Err(format!(
            "{what} has {} entries (at most {})",
            from.len(),
            to.len()
        ));
    }
    to[..from.len()].copy_from_slice(from);
    Ok(())
}

/// The shape of an array of `n` nodes whose rows and columns were not stored: square when `n`
/// is a square number, else one row.
pub(crate) fn shape_of(n: usize) -> (u16, u16) {
    let s = (n as f64).sqrt().round() as usize;
    if s * s == n {
        (s as u16, s as u16)
    } else {
        (1, n.min(MAX_NODES) as u16)
    }
}

/// Decodes one version-1 payload.
pub(super) fn decode(payload: &[u8]) -> Result<Record, String> {
    let (rec, used) =
        bincode::serde::decode_from_slice::<RecordV1, _>(payload, bincode::config::standard())
            .map_err(|e| e.to_string())?;
    if used != payload.len() {
        return Err(super::TRAILING.into());
    }
    Ok(match rec {
        RecordV1::Raw {
            sensor,
            seq,
            t_capture_ns,
            rows,
            cols,
            flags,
            source,
            full_scale,
            counts,
        } => {
            let mut f = RawFrame::ZERO;
            f.sensor = sensor_bytes(sensor.as_bytes())?;
            (f.seq, f.t_capture_ns, f.rows, f.cols) = (seq, t_capture_ns, rows, cols);
            (f.flags, f.source, f.full_scale) = (flags, source, full_scale);
            if counts.len() != f.n_nodes() {
                return Err(format!(
                    "counts has {} entries for a {rows} x {cols} array",
                    counts.len()
                ));
            }
            fill(&mut f.counts, &counts, "counts")?;
            Record::Raw(Box::new(f))
        }
        RecordV1::Curvature {
            sensor,
            seq,
            t_capture_ns,
            t_window_start_ns,
            curvature_m1,
            curvature_sd_m1,
            model_version,
            flags,
            window_frames,
            baseline,
        } => {
            let mut e = CurvatureEstimate::ZERO;
            e.sensor = sensor_bytes(sensor.as_bytes())?;
            (e.seq, e.t_capture_ns, e.t_window_start_ns) = (seq, t_capture_ns, t_window_start_ns);
            (e.curvature_m1, e.curvature_sd_m1) = (curvature_m1, curvature_sd_m1);
            (e.model_version, e.flags, e.window_frames) = (model_version, flags, window_frames);
            fill(&mut e.baseline, &baseline, "baseline")?;
            (e.rows, e.cols) = shape_of(baseline.len());
            Record::Curvature(Box::new(e))
        }
        RecordV1::Force {
            sensor,
            seq,
            t_capture_ns,
            t_publish_ns,
            total_force_n,
            total_reading,
            curvature_m1,
            cal_version,
            cal_generation,
            flags,
            block_force_n,
            block_reading,
        } => {
            let mut f = ForceSample::ZERO;
            f.sensor = sensor_bytes(sensor.as_bytes())?;
            (f.seq, f.t_capture_ns, f.t_publish_ns) = (seq, t_capture_ns, t_publish_ns);
            (f.total_force_n, f.total_reading) = (total_force_n, total_reading);
            (f.curvature_m1, f.cal_version) = (curvature_m1, cal_version);
            (f.cal_generation, f.flags) = (cal_generation, flags);
            if block_reading.len() != block_force_n.len() || block_force_n.len() > MAX_BLOCKS {
                return Err(format!(
                    "{} block forces and {} block readings",
                    block_force_n.len(),
                    block_reading.len()
                ));
            }
            fill(&mut f.block_force_n, &block_force_n, "block_force_n")?;
            fill(&mut f.block_reading, &block_reading, "block_reading")?;
            f.n_blocks = block_force_n.len() as u32;
            Record::Force(f)
        }
        RecordV1::Reference {
            sensor,
            seq,
            t_capture_ns,
            t_source_s,
            force_n,
            curvature_m1,
            temp_c,
            trial,
        } => Record::Reference(Reference {
            seq,
            t_capture_ns,
            sensor: sensor_bytes(sensor.as_bytes())?,
            t_source_s,
            force_n,
            curvature_m1,
            temp_c,
            trial,
        }),
    })
}
