//! The one table of every payload's fields, from which every file format is derived: the
//! logger's record file, the MCAP JSON messages and their JSON Schemas, and the recording CSV
//! export (taxel-formats) all walk a payload with [`Message::visit`] instead of naming its
//! fields again. Each `visit` destructures its payload without `..`, so a field added to a
//! payload does not compile until it is added to the table; once it is, it reaches every
//! format.
//!
//! The order of a table is the order of the fields in the record file and in the JSON
//! messages. Add a field at the end of its table (the record file stores the fields in this
//! order and reads a field missing from an older file as zero).

use crate::{
    CurvatureEstimate, ForceSample, RawFrame, Reference, SensorIdBytes, Stream, MAX_BLOCKS,
    MAX_NODES,
};

/// One field of a payload: its name (units in the name, as in the payload) and its meaning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    pub name: &'static str,
    pub doc: &'static str,
}

const fn field(name: &'static str, doc: &'static str) -> Field {
    Field { name, doc }
}

/// What the formats do with each field. Encoders read the values; decoders write them. The
/// visit of a payload calls one method per field, in the table's order.
pub trait Visitor {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes);
    fn u64(&mut self, f: &Field, v: &mut u64);
    fn u32(&mut self, f: &Field, v: &mut u32);
    fn u16(&mut self, f: &Field, v: &mut u16);
    fn i32(&mut self, f: &Field, v: &mut i32);
    fn f32(&mut self, f: &Field, v: &mut f32);
    fn f64(&mut self, f: &Field, v: &mut f64);
    /// An array whose first `*len` entries are meaningful. Encoders use `v[..*len]`; decoders
    /// fill the start of `v` and set `*len` to the number of entries they read (never more
    /// than `v.len()`).
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize);
    /// The visit found the decoded fields inconsistent (an array's length against the sizes
    /// that govern it). Decoders report it; encoders never see it.
    fn invalid(&mut self, _why: String) {}
}

/// A payload the formats can walk.
pub trait Message: Copy + std::fmt::Debug + 'static {
    /// The schema name of the payload in files (its type name without the version suffix).
    const NAME: &'static str;
    /// The stream that carries it.
    const STREAM: Stream;
    /// An all-zero value (decoders start from it; a field an older file lacks stays zero).
    fn zero() -> Self;
    /// Visits every field in the table's order.
    fn visit<V: Visitor>(&mut self, v: &mut V);
}

/// The names of a payload's fields, in its table's order.
pub fn names<M: Message>() -> Vec<&'static str> {
    struct Names(Vec<&'static str>);
    impl Visitor for Names {
        fn sensor(&mut self, f: &Field, _: &mut SensorIdBytes) {
            self.0.push(f.name)
        }
        fn u64(&mut self, f: &Field, _: &mut u64) {
            self.0.push(f.name)
        }
        fn u32(&mut self, f: &Field, _: &mut u32) {
            self.0.push(f.name)
        }
        fn u16(&mut self, f: &Field, _: &mut u16) {
            self.0.push(f.name)
        }
        fn i32(&mut self, f: &Field, _: &mut i32) {
            self.0.push(f.name)
        }
        fn f32(&mut self, f: &Field, _: &mut f32) {
            self.0.push(f.name)
        }
        fn f64(&mut self, f: &Field, _: &mut f64) {
            self.0.push(f.name)
        }
        fn f32s(&mut self, f: &Field, _: &mut [f32], _: &mut usize) {
            self.0.push(f.name)
        }
    }
    let mut n = Names(Vec::new());
    M::zero().visit(&mut n);
    n.0
}

/// Number of meaningful nodes of a `rows x cols` array.
fn nodes(rows: u16, cols: u16) -> usize {
    (rows as usize * cols as usize).min(MAX_NODES)
}

/// Checks an array's decoded length against the sizes that govern it.
fn check_len<V: Visitor>(v: &mut V, f: &Field, got: usize, want: usize, of: &str) {
    if got != want {
        v.invalid(format!("{} has {got} entries for {of} {want}", f.name));
    }
}

pub const SENSOR: Field = field("sensor", "sensor id");
pub const SEQ: Field = field("seq", "frame sequence number from the publisher");
pub const T_CAPTURE_NS: Field = field(
    "t_capture_ns",
    "capture time of the raw frame, CLOCK_MONOTONIC ns",
);

impl Message for RawFrame {
    const NAME: &'static str = "taxel.RawFrame";
    const STREAM: Stream = Stream::Raw;
    fn zero() -> Self {
        RawFrame::ZERO
    }
    fn visit<V: Visitor>(&mut self, v: &mut V) {
        let RawFrame {
            seq,
            t_capture_ns,
            sensor,
            rows,
            cols,
            flags,
            source,
            full_scale,
            counts,
        } = self;
        v.sensor(&SENSOR, sensor);
        v.u64(&SEQ, seq);
        v.u64(&T_CAPTURE_NS, t_capture_ns);
        v.u16(&field("rows", "rows of the array"), rows);
        v.u16(&field("cols", "columns of the array"), cols);
        v.u32(
            &field("flags", "RawFrame flags bits (docs/messages.md)"),
            flags,
        );
        v.u32(
            &field(
                "source",
                "source kind: 1 sim, 2 serial, 3 replay, 4 external (Python)",
            ),
            source,
        );
        v.f32(
            &field(
                "full_scale",
                "largest valid reading (counts; 0 when unknown)",
            ),
            full_scale,
        );
        let want = nodes(*rows, *cols);
        let mut n = want;
        let counts_field = field("counts", "raw reading per node, row-major (ADC counts)");
        v.f32s(&counts_field, counts, &mut n);
        check_len(v, &counts_field, n, want, "rows x cols");
    }
}

impl Message for CurvatureEstimate {
    const NAME: &'static str = "taxel.CurvatureEstimate";
    const STREAM: Stream = Stream::Curvature;
    fn zero() -> Self {
        CurvatureEstimate::ZERO
    }
    fn visit<V: Visitor>(&mut self, v: &mut V) {
        let CurvatureEstimate {
            seq,
            t_capture_ns,
            t_window_start_ns,
            sensor,
            rows,
            cols,
            curvature_m1,
            curvature_sd_m1,
            model_version,
            flags,
            window_frames,
            estimate_index,
            // Explicit padding, always 0: not a value.
            reserved: _,
            baseline,
        } = self;
        v.sensor(&SENSOR, sensor);
        v.u64(&SEQ, seq);
        v.u64(&T_CAPTURE_NS, t_capture_ns);
        v.u64(
            &field(
                "t_window_start_ns",
                "capture time of the first frame of the baseline window, ns",
            ),
            t_window_start_ns,
        );
        v.f32(
            &field("curvature_m1", "estimated curvature (1/m)"),
            curvature_m1,
        );
        v.f32(
            &field(
                "curvature_sd_m1",
                "standard deviation of the estimate (1/m)",
            ),
            curvature_sd_m1,
        );
        v.u32(
            &field(
                "model_version",
                "curvature model version (0: a configured curvature)",
            ),
            model_version,
        );
        v.u32(
            &field("flags", "CurvatureEstimate flags bits (docs/messages.md)"),
            flags,
        );
        v.u32(
            &field("window_frames", "frames in the baseline window"),
            window_frames,
        );
        let baseline_field = field("baseline", "no-load baseline per node (ADC counts)");
        let mut n = nodes(*rows, *cols);
        v.f32s(&baseline_field, baseline, &mut n);
        v.u16(&field("rows", "rows of the array"), rows);
        v.u16(&field("cols", "columns of the array"), cols);
        check_len(v, &baseline_field, n, nodes(*rows, *cols), "rows x cols");
        v.u32(
            &field(
                "estimate_index",
                "baselines this estimator has published (1 = the first)",
            ),
            estimate_index,
        );
    }
}

impl Message for ForceSample {
    const NAME: &'static str = "taxel.ForceSample";
    const STREAM: Stream = Stream::Force;
    fn zero() -> Self {
        ForceSample::ZERO
    }
    fn visit<V: Visitor>(&mut self, v: &mut V) {
        let ForceSample {
            seq,
            t_capture_ns,
            t_publish_ns,
            sensor,
            total_force_n,
            total_reading,
            curvature_m1,
            cal_version,
            cal_generation,
            curvature_model_version,
            flags,
            n_blocks,
            block_force_n,
            block_reading,
            zero_age_s,
            reserved: _,
        } = self;
        v.sensor(&SENSOR, sensor);
        v.u64(&SEQ, seq);
        v.u64(&T_CAPTURE_NS, t_capture_ns);
        v.u64(
            &field(
                "t_publish_ns",
                "time the calibrator published, CLOCK_MONOTONIC ns",
            ),
            t_publish_ns,
        );
        v.f32(
            &field("total_force_n", "force on the whole array (N)"),
            total_force_n,
        );
        v.f32(
            &field(
                "total_reading",
                "baseline-subtracted sum of counts of the array",
            ),
            total_reading,
        );
        v.f32(
            &field("curvature_m1", "curvature used by the calibration (1/m)"),
            curvature_m1,
        );
        v.u32(
            &field("cal_version", "version declared in the calibration file"),
            cal_version,
        );
        v.u32(
            &field(
                "cal_generation",
                "calibration files loaded by the calibrator (1 = first)",
            ),
            cal_generation,
        );
        v.u32(
            &field("flags", "ForceSample flags bits (docs/messages.md)"),
            flags,
        );
        // The number of blocks is the length of the two block arrays (in files as in memory).
        let mut nb = (*n_blocks as usize).min(MAX_BLOCKS);
        v.f32s(
            &field("block_force_n", "force per calibration block (N)"),
            block_force_n,
            &mut nb,
        );
        let reading_field = field(
            "block_reading",
            "baseline-subtracted sum of counts per block",
        );
        let mut nr = nb;
        v.f32s(&reading_field, block_reading, &mut nr);
        check_len(v, &reading_field, nr, nb, "block_force_n's");
        *n_blocks = nb as u32;
        v.u32(
            &field(
                "curvature_model_version",
                "model_version of the curvature estimate used (0: configured or none)",
            ),
            curvature_model_version,
        );
        v.f32(
            &field(
                "zero_age_s",
                "age of the no-load zero in use (s); NaN while it is the calibration file's",
            ),
            zero_age_s,
        );
    }
}

impl Message for Reference {
    const NAME: &'static str = "taxel.Reference";
    const STREAM: Stream = Stream::Reference;
    fn zero() -> Self {
        Reference::ZERO
    }
    fn visit<V: Visitor>(&mut self, v: &mut V) {
        let Reference {
            seq,
            t_capture_ns,
            sensor,
            t_source_s,
            force_n,
            curvature_m1,
            temp_c,
            trial,
        } = self;
        v.sensor(&SENSOR, sensor);
        v.u64(&SEQ, seq);
        v.u64(&T_CAPTURE_NS, t_capture_ns);
        v.f64(
            &field(
                "t_source_s",
                "source time (s): simulation time or the recording's t_s",
            ),
            t_source_s,
        );
        v.f32(
            &field("force_n", "reference total force (N); null = unknown"),
            force_n,
        );
        v.f32(
            &field(
                "curvature_m1",
                "reference mounting curvature (1/m); null = unknown",
            ),
            curvature_m1,
        );
        v.f32(
            &field("temp_c", "ambient temperature (degC); null = unknown"),
            temp_c,
        );
        v.i32(
            &field("trial", "trial (mounting) index; -1 = unknown"),
            trial,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_table_starts_with_the_fields_of_version_one_files_in_their_order() {
        // The record file stores fields in table order and the JSON messages list them so:
        // the fields the first file version had come first, in its order; new ones follow.
        let v1: [(&str, &[&str]); 4] = [
            (
                RawFrame::NAME,
                &[
                    "sensor",
                    "seq",
                    "t_capture_ns",
                    "rows",
                    "cols",
                    "flags",
                    "source",
                    "full_scale",
                    "counts",
                ],
            ),
            (
                CurvatureEstimate::NAME,
                &[
                    "sensor",
                    "seq",
                    "t_capture_ns",
                    "t_window_start_ns",
                    "curvature_m1",
                    "curvature_sd_m1",
                    "model_version",
                    "flags",
                    "window_frames",
                    "baseline",
                ],
            ),
            (
                ForceSample::NAME,
                &[
                    "sensor",
                    "seq",
                    "t_capture_ns",
                    "t_publish_ns",
                    "total_force_n",
                    "total_reading",
                    "curvature_m1",
                    "cal_version",
                    "cal_generation",
                    "flags",
                    "block_force_n",
                    "block_reading",
                ],
            ),
            (
                Reference::NAME,
                &[
                    "sensor",
                    "seq",
                    "t_capture_ns",
                    "t_source_s",
                    "force_n",
                    "curvature_m1",
                    "temp_c",
                    "trial",
                ],
            ),
        ];
        let tables = [
            (RawFrame::NAME, names::<RawFrame>()),
            (CurvatureEstimate::NAME, names::<CurvatureEstimate>()),
            (ForceSample::NAME, names::<ForceSample>()),
            (Reference::NAME, names::<Reference>()),
        ];
        for ((name, old), (_, now)) in v1.iter().zip(&tables) {
            assert_eq!(&now[..old.len()], *old, "{name}");
            let mut unique = now.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(unique.len(), now.len(), "{name}: a field twice");
        }
        assert!(names::<ForceSample>().contains(&"curvature_model_version"));
    }
}
