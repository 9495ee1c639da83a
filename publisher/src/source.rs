//! Frame sources. A source fills the readings of the next frame and says when it is due
//! relative to the start of the stream; the publish loop does the pacing and stamping.

use std::path::Path;

use taxel_formats::Recording;
use taxel_msgs::source;
use taxel_sim::{Scenario, SensorModel, Simulator};

/// Reference values that go with a frame (NaN / -1 when unknown).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefValues {
    pub t_source_s: f64,
    pub force_n: f64,
    pub curvature_m1: f64,
    pub temp_c: f64,
    pub trial: i32,
}

/// One produced frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Produced {
    /// When the frame is due, in seconds since the stream started (already divided by any
    /// replay speed).
    pub due_s: f64,
    pub reference: Option<RefValues>,
}

/// A source of frames.
pub trait Source {
    fn rows(&self) -> usize;
    fn cols(&self) -> usize;
    /// `source` code of `RawFrame`.
    fn kind(&self) -> u32;
    /// Full-scale reading (0 if unknown).
    fn full_scale(&self) -> f32;
    /// The readout it declares in every frame's flags (`Readout::code`; 0: undeclared).
    fn readout_code(&self) -> u32 {
        0
    }
    /// Writes the next frame's `rows * cols` readings; `None` at the end of the source.
    fn next_frame(&mut self, out: &mut [f32]) -> Option<Produced>;
}

/// The readout code a simulated board declares.
pub fn sim_readout_code(r: &taxel_sim::model::Readout) -> u32 {
    use taxel_formats::{Readout, ReadoutKind as K};
    let (kind, rises) = match r.kind {
        taxel_sim::ReadoutKind::Amplifier if r.inverted => (K::Inverted, false),
        taxel_sim::ReadoutKind::Amplifier => (K::Amplifier, true),
        taxel_sim::ReadoutKind::Resistance => (K::Resistance, false),
        taxel_sim::ReadoutKind::Divider => (K::Divider, r.divider_rises),
    };
    Readout {
        kind,
        full_scale: r.max_code(),
        rises,
    }
    .code()
}

/// The simulator as a source.
pub struct SimSource {
    sim: Simulator,
    remaining: Option<u64>,
}

impl SimSource {
    /// `frames`: stop after this many frames (None: the scenario's length, or forever when it
    /// repeats).
    pub fn new(
        model: &SensorModel,
        scenario: &Scenario,
        frames: Option<u64>,
    ) -> anyhow::Result<SimSource> {
        let sim = Simulator::new(model, scenario)?;
        let remaining = frames.or(sim.frames_in_scenario());
        Ok(SimSource { sim, remaining })
    }

    /// Frames left (None: endless).
    pub fn frames_hint(&self) -> Option<u64> {
        self.remaining
    }
}

impl Source for SimSource {
    fn rows(&self) -> usize {
        self.sim.rows()
    }
    fn cols(&self) -> usize {
        self.sim.cols()
    }
    fn kind(&self) -> u32 {
        source::SIM
    }
    fn full_scale(&self) -> f32 {
        self.sim.full_scale() as f32
    }
    fn readout_code(&self) -> u32 {
        sim_readout_code(&self.sim.model().readout)
    }
    fn next_frame(&mut self, out: &mut [f32]) -> Option<Produced> {
        if let Some(r) = self.remaining.as_mut() {
            if *r == 0 {
                return None;
            }
            *r -= 1;
        }
        let t = self.sim.step(out);
        Some(Produced {
            due_s: t.t_s,
            reference: Some(RefValues {
                t_source_s: t.t_s,
                force_n: t.force_n,
                curvature_m1: t.curvature_m1,
                temp_c: t.temp_c,
                trial: t.trial as i32,
            }),
        })
    }
}

/// A recording CSV played back at `speed` times real time (timing from its `t_s`).
pub struct ReplaySource {
    rec: Recording,
    rows: usize,
    cols: usize,
    speed: f64,
    full_scale: f32,
    next: usize,
    repeat: bool,
    pass: u64,
    offset_s: f64,
    readout_code: u32,
}

impl ReplaySource {
    /// Declares the recording's readout in every frame (`Readout::code`; 0: undeclared).
    pub fn with_readout_code(mut self, code: u32) -> ReplaySource {
        self.readout_code = code;
        self
    }

    pub fn open(
        path: &Path,
        rows: Option<usize>,
        cols: Option<usize>,
        speed: f64,
        full_scale: f32,
        repeat: bool,
    ) -> anyhow::Result<ReplaySource> {
        let rec = Recording::read(path)?;
        Self::from_recording(rec, path, rows, cols, speed, full_scale, repeat)
    }

    /// Plays the raw channel of one sensor of an MCAP file written by `taxel logger export
    /// --mcap` (`from_sensor`: which one, needed when the file holds several). The array's
    /// shape and full scale come from the frames unless given.
    pub fn open_mcap(
        path: &Path,
        from_sensor: Option<&str>,
        rows: Option<usize>,
        cols: Option<usize>,
        speed: f64,
        full_scale: f32,
        repeat: bool,
    ) -> anyhow::Result<ReplaySource> {
        let m = taxel_formats::mcap::read_recording(path, from_sensor)?;
        let full_scale = if full_scale > 0.0 {
            full_scale
        } else {
            m.full_scale
        };
        Self::from_recording(
            m.recording,
            path,
            rows.or(Some(m.rows)),
            cols.or(Some(m.cols)),
            speed,
            full_scale,
            repeat,
        )
    }

    fn from_recording(
        rec: Recording,
        path: &Path,
        rows: Option<usize>,
        cols: Option<usize>,
        speed: f64,
        full_scale: f32,
        repeat: bool,
    ) -> anyhow::Result<ReplaySource> {
        let g = rec.geometry(rows, cols)?;
        anyhow::ensure!(
            speed.is_finite() && speed > 0.0,
            "--speed must be a positive number, got {speed}"
        );
        for i in 1..rec.len() {
            anyhow::ensure!(
                rec.t_s[i] >= rec.t_s[i - 1],
                "{}: t_s goes backwards at data row {} ({} after {})",
                path.display(),
                i + 1,
                rec.t_s[i],
                rec.t_s[i - 1]
            );
        }
        Ok(ReplaySource {
            rows: g.rows,
            cols: g.cols,
            speed,
            full_scale,
            next: 0,
            repeat,
            pass: 0,
            offset_s: 0.0,
            readout_code: 0,
            rec,
        })
    }
}

impl Source for ReplaySource {
    fn rows(&self) -> usize {
        self.rows
    }
    fn cols(&self) -> usize {
        self.cols
    }
    fn kind(&self) -> u32 {
        source::REPLAY
    }
    fn readout_code(&self) -> u32 {
        self.readout_code
    }
    fn full_scale(&self) -> f32 {
        self.full_scale
    }
    fn next_frame(&mut self, out: &mut [f32]) -> Option<Produced> {
        if self.next >= self.rec.len() {
            if !self.repeat {
                return None;
            }
            let t = &self.rec.t_s;
            let span = t[t.len() - 1] - t[0];
            let step = if t.len() > 1 {
                span / (t.len() - 1) as f64
            } else {
                0.01
            };
            self.offset_s += span + step;
            self.next = 0;
            self.pass += 1;
        }
        let i = self.next;
        self.next += 1;
        for (o, v) in out.iter_mut().zip(self.rec.sample(i)) {
            *o = *v as f32;
        }
        let t = self.rec.t_s[i] - self.rec.t_s[0] + self.offset_s;
        let pick = |c: &Option<Vec<f64>>| c.as_ref().map_or(f64::NAN, |v| v[i]);
        let has_ref = self.rec.force_n.is_some()
            || self.rec.curvature_m1.is_some()
            || self.rec.temp_c.is_some()
            || self.rec.trial.is_some();
        Some(Produced {
            due_s: t / self.speed,
            reference: has_ref.then(|| RefValues {
                t_source_s: self.rec.t_s[i],
                force_n: pick(&self.rec.force_n),
                curvature_m1: pick(&self.rec.curvature_m1),
                temp_c: pick(&self.rec.temp_c),
                trial: self
                    .rec
                    .trial
                    .as_ref()
                    .map_or(-1, |v| v[i].clamp(i32::MIN as i64, i32::MAX as i64) as i32),
            }),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_simulated_board_declares_its_readout() {
        let code = |name: &str| {
            let m = taxel_sim::presets::preset(name).expect("preset");
            taxel_formats::Readout::kind_of_code(sim_readout_code(&m.readout))
        };
        use taxel_formats::ReadoutKind as K;
        assert_eq!(code("default"), Some((K::Amplifier, true)));
        assert_eq!(code("zoo-sat"), Some((K::Amplifier, true)));
        assert_eq!(code("zoo-pow"), Some((K::Inverted, false)));
        assert_eq!(code("zoo-log"), Some((K::Divider, false)));
        let mut m = taxel_sim::presets::preset("zoo-log").expect("preset");
        m.readout.divider_rises = true;
        assert_eq!(
            taxel_formats::Readout::kind_of_code(sim_readout_code(&m.readout)),
            Some((K::Divider, true))
        );
    }

    #[test]
    fn replay_follows_the_file_and_repeats() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("r.csv");
        std::fs::write(&p, "t_s,n0,force_n\n10,500,0\n10.5,400,1\n11,300,2\n").expect("write");
        let mut s = ReplaySource::open(&p, None, None, 2.0, 0.0, true).expect("open");
        let mut out = [0f32; 1];
        let a = s.next_frame(&mut out).expect("frame");
        assert_eq!((a.due_s, out[0]), (0.0, 500.0));
        let b = s.next_frame(&mut out).expect("frame");
        assert_eq!(b.due_s, 0.25);
        assert_eq!(b.reference.map(|r| r.force_n), Some(1.0));
        s.next_frame(&mut out);
        let d = s.next_frame(&mut out).expect("repeats");
        assert_eq!((d.due_s, out[0]), (0.75, 500.0));
        std::fs::write(&p, "t_s,n0\n1,5\n0,5\n").expect("write");
        let e = ReplaySource::open(&p, None, None, 1.0, 0.0, false)
            .err()
            .expect("backwards");
        assert!(format!("{e:#}").contains("backwards"), "{e:#}");
    }

    #[test]
    fn replay_plays_an_mcap_raw_channel() {
        use taxel_formats::mcap::McapRecordWriter;
        use taxel_formats::Record;
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("r.mcap");
        let mut w = McapRecordWriter::create(&p).expect("create");
        for (i, sensor) in [(0u64, "a"), (0, "b"), (1, "a"), (2, "a")] {
            let mut f = taxel_msgs::RawFrame::ZERO;
            f.sensor = taxel_msgs::sensor_id_bytes(sensor).expect("id");
            (f.seq, f.t_capture_ns) = (i, 1_000_000_000 + i * 10_000_000);
            (f.rows, f.cols, f.full_scale) = (1, 2, 1023.0);
            f.counts[..2].copy_from_slice(&[i as f32, 100.0 + i as f32]);
            w.write(&Record::from(f)).expect("write");
        }
        w.finish().expect("finish");
        let e = ReplaySource::open_mcap(&p, None, None, None, 1.0, 0.0, false)
            .err()
            .expect("two sensors");
        assert!(format!("{e:#}").contains("choose"), "{e:#}");
        let mut s =
            ReplaySource::open_mcap(&p, Some("a"), None, None, 1.0, 0.0, false).expect("open");
        assert_eq!((s.rows(), s.cols(), s.full_scale()), (1, 2, 1023.0));
        let mut out = [0f32; 2];
        let mut got = Vec::new();
        while let Some(f) = s.next_frame(&mut out) {
            got.push((f.due_s, out));
        }
        assert_eq!(got.len(), 3);
        assert_eq!(got[2].1, [2.0, 102.0]);
        assert!((got[2].0 - 0.02).abs() < 1e-9, "{}", got[2].0);
    }
}
