//! The calibrator process loop, for one sensor or many: wakes on raw frames (WaitSet; one
//! listener per sensor), applies each sensor's calibration to every frame (the per-frame
//! computation is [`Calibrator`]), publishes a `ForceSample` per frame on that sensor's stream,
//! and swaps in a reloaded calibration between two frames for every sensor its file serves.
//! One sensor waits in any wake mode; several wait event-driven in one WaitSet.

use std::path::PathBuf;
use std::sync::Arc;

use taxel_formats::{Readout, ReadoutKind};
use taxel_msgs::{
    force_flags, raw_flags, CurvatureEstimate, ForceSample, RawFrame, Stream, MAX_BLOCKS, MAX_NODES,
};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::ipc::{GroupListener, GroupNotifier};
use taxel_runtime::wake::{receive_group, receive_loop, receive_many, LoopOptions, WakeMode};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::calibration::Calibration;
use crate::dynamics::State;
use crate::lane::{Lane, Streams};
use crate::reload::{Loaded, Watched, Watcher};

/// One sensor of a calibrator: its id and the index of its calibration file in
/// [`Config::files`].
#[derive(Debug, Clone)]
pub struct SensorConfig {
    pub sensor: String,
    pub file: usize,
}

/// Calibrator settings.
#[derive(Debug, Clone)]
pub struct Config {
    pub sensors: Vec<SensorConfig>,
    /// The distinct calibration files (each watched once, reloaded for all its sensors).
    pub files: Vec<PathBuf>,
    /// A curvature estimate (baseline) older than this is flagged stale (s).
    pub curvature_stale_s: f64,
    /// How to wait for raw frames.
    pub wake: WakeMode,
    /// Several sensors: wait on this wake-up group and poll their streams (`--wake-group`).
    pub group: Option<String>,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub frames: u64,
    pub dropped: u64,
    pub reloads: u32,
    pub geometry_mismatches: u64,
    /// Frames skipped because the stream's readings move the other way with force than the
    /// calibration's readout (see `Readout::check_stream`).
    pub readout_mismatches: u64,
    /// What the adaptive wake-up did (zero in other modes).
    pub wake: taxel_runtime::wake::AdaptiveStats,
}

/// The pure per-frame computation (shared with offline evaluation).
#[derive(Debug, Clone)]
pub struct Calibrator {
    loaded: Arc<Loaded>,
    /// The stream's no-load baseline (stream units), once an estimate brought one.
    baseline: Option<Box<[f32; MAX_NODES]>>,
    /// The signal of the baseline in use (the stream's, else the file's `no_load_reading`).
    base_signal: Box<[f64; MAX_NODES]>,
    has_base: bool,
    curvature: Option<(f32, u64, u32)>,
    stale_ns: u64,
    /// Dynamic states of the whole array (0) and of each block (1..), and the capture time of
    /// the last frame they were advanced at.
    states: [State; 1 + MAX_BLOCKS],
    last_t_ns: Option<u64>,
    /// Apply the file's dynamic terms (off: the static calibration alone, for comparison).
    dynamics: bool,
    /// Whether the dynamic states are known (see `DYNAMICS_WARMING`).
    warm: Warm,
    /// Capture time of the end of the no-load window the zero in use came from.
    zero_t_ns: Option<u64>,
}

/// What the calibrator knows of its dynamic states.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Warm {
    /// No frame with a baseline yet.
    Unchecked,
    /// Started under load or restarted: not known until this capture time and until every
    /// play has been swept.
    Until(u64),
    /// Known (started at rest, or long enough ago, or no dynamic terms).
    Known,
}

impl Calibrator {
    pub fn new(loaded: Arc<Loaded>, curvature_stale_s: f64) -> Calibrator {
        let mut c = Calibrator {
            loaded,
            baseline: None,
            base_signal: Box::new([0.0; MAX_NODES]),
            has_base: false,
            curvature: None,
            stale_ns: (curvature_stale_s.max(0.0) * 1e9) as u64,
            states: [State::REST; 1 + MAX_BLOCKS],
            last_t_ns: None,
            dynamics: true,
            warm: Warm::Unchecked,
            zero_t_ns: None,
        };
        c.refresh_base();
        c
    }

    /// A calibrator for a calibration loaded outside the watcher (generation 1): offline
    /// evaluation, tests, benchmarks.
    pub fn for_calibration(calibration: Calibration, curvature_stale_s: f64) -> Calibrator {
        Calibrator::new(
            Arc::new(Loaded {
                calibration,
                generation: 1,
            }),
            curvature_stale_s,
        )
    }

    /// Recomputes the baseline's signal (after a new baseline or a new calibration, whose
    /// readout may differ).
    fn refresh_base(&mut self) {
        let cal = &self.loaded.calibration;
        let ro = cal.readout;
        match &self.baseline {
            Some(b) => {
                for (d, v) in self.base_signal.iter_mut().zip(b.iter()) {
                    *d = ro.signal(*v as f64);
                }
                self.has_base = true;
            }
            None => {
                for (d, v) in self.base_signal.iter_mut().zip(&cal.no_load_reading) {
                    *d = ro.signal(*v);
                }
                self.has_base = !cal.no_load_reading.is_empty();
            }
        }
    }

    /// Takes a new baseline (the zero of every block's reading) and curvature. With dynamic
    /// terms, each block keeps as a credit what its terms predict the no-load window holds
    /// (`dynamics::State::rezero`), so only the drift they do not explain is taken out.
    pub fn set_curvature(&mut self, est: &CurvatureEstimate) {
        let b = self
            .baseline
            .get_or_insert_with(|| Box::new([0.0; MAX_NODES]));
        b.copy_from_slice(&est.baseline);
        self.curvature = Some((est.curvature_m1, est.t_capture_ns, est.model_version));
        self.zero_t_ns = Some(est.t_capture_ns);
        self.refresh_base();
        if self.dynamics {
            let cal = &self.loaded.calibration;
            let c = est.curvature_m1 as f64;
            for (st, b) in self.states.iter_mut().zip(cal.all_blocks()) {
                st.rezero(b, c);
            }
        }
    }

    /// Uses a given curvature (1/m) until an estimate brings another; the baseline stays the
    /// stream's or, until one arrives, the file's.
    pub fn set_known_curvature(&mut self, c: f64) {
        self.curvature = Some((c as f32, 0, 0));
    }

    /// Applies the file's dynamic terms (the default) or only its static model.
    pub fn set_dynamics(&mut self, on: bool) {
        self.dynamics = on;
    }

    /// Serves a (re)loaded calibration from the next frame on; the baseline carries over, and
    /// each block's dynamic state continues from what its old terms added at the last frame
    /// (`dynamics::State::carry_over`), so the force does not jump. New terms on a loaded
    /// sensor are flagged `DYNAMICS_WARMING` as at a start.
    pub fn set_loaded(&mut self, loaded: Arc<Loaded>) {
        let old = std::mem::replace(&mut self.loaded, loaded);
        let cal = &self.loaded.calibration;
        for ((st, o), n) in self
            .states
            .iter_mut()
            .zip(old.calibration.all_blocks())
            .zip(cal.all_blocks())
        {
            st.carry_over(o, n);
        }
        let had = old
            .calibration
            .all_blocks()
            .any(|b| !b.dynamics.is_static());
        if !had && self.warm == Warm::Known {
            self.warm = Warm::Unchecked;
        }
        self.refresh_base();
    }

    /// What is known of the dynamic states at the first frame with a baseline (whole-array
    /// reading `s`): the states start at rest, which is right for a sensor at rest, unless the
    /// process was restarted (a remanence it cannot know) or the sensor is loaded (creep under
    /// way). Then they are flagged until the longest creep time constant has passed and every
    /// play has been swept (`dynamics::State::plays_known`).
    fn start_warm(&self, s: f64, t_ns: u64) -> Warm {
        let cal = &self.loaded.calibration;
        if !self.dynamics || cal.all_blocks().all(|b| b.dynamics.is_static()) {
            return Warm::Known;
        }
        let longest = cal
            .all_blocks()
            .map(|b| b.dynamics.longest_tau_s())
            .fold(0.0, f64::max);
        let hysteresis = cal.all_blocks().any(|b| b.dynamics.hysteresis.is_some());
        let (range, _) = cal.array.ranges();
        let loaded = s > range[0] + UNLOADED_SHARE * (range[1] - range[0]);
        let restarted = taxel_runtime::process::restarted();
        if loaded {
            Warm::Until(t_ns + (longest * 1e9) as u64)
        } else if restarted && hysteresis {
            Warm::Until(t_ns)
        } else {
            Warm::Known
        }
    }

    pub fn calibration(&self) -> &Calibration {
        &self.loaded.calibration
    }

    /// Computes the forces of `frame` into `out` (all fields but `t_publish_ns`).
    pub fn apply(&mut self, frame: &RawFrame, now_ns: u64, out: &mut ForceSample) {
        let dt_s = self
            .last_t_ns
            .map_or(0.0, |t| frame.t_capture_ns.saturating_sub(t) as f64 * 1e-9);
        self.last_t_ns = Some(frame.t_capture_ns);
        let cal = &self.loaded.calibration;
        out.seq = frame.seq;
        out.t_capture_ns = frame.t_capture_ns;
        out.sensor = frame.sensor;
        out.cal_version = cal.version;
        out.cal_generation = self.loaded.generation;
        out.n_blocks = cal.blocks.len().min(MAX_BLOCKS) as u32;
        let mut flags = 0;
        if frame.flags & raw_flags::RAIL != 0 {
            flags |= force_flags::SATURATED;
        }
        if frame.flags & raw_flags::GAP_BEFORE != 0 {
            flags |= force_flags::GAP_BEFORE;
        }
        let c = match self.curvature {
            Some((c, t, version)) => {
                if now_ns.saturating_sub(t) > self.stale_ns {
                    flags |= force_flags::CURVATURE_STALE;
                }
                out.curvature_model_version = version;
                c as f64
            }
            None => {
                flags |= force_flags::CURVATURE_DEFAULTED;
                out.curvature_model_version = 0;
                cal.default_curvature_m1
            }
        };
        out.curvature_m1 = c as f32;
        out.zero_age_s = self.zero_t_ns.map_or(f32::NAN, |t| {
            (frame.t_capture_ns.saturating_sub(t) as f64 * 1e-9) as f32
        });
        let n = frame.n_nodes();
        if self.baseline.is_none() {
            flags |= force_flags::NO_BASELINE;
        }
        if !self.has_base {
            out.total_force_n = f32::NAN;
            out.total_reading = f32::NAN;
            out.block_force_n = [f32::NAN; MAX_BLOCKS];
            out.block_reading = [f32::NAN; MAX_BLOCKS];
            out.flags = flags;
            return;
        }
        if self.baseline.is_none() {
            flags |= force_flags::BASELINE_FROM_CALIBRATION;
        }
        let ro = cal.readout;
        let (counts, base) = (&frame.counts[..n], &self.base_signal[..n]);
        let reading = |nodes: &[usize]| block_reading(&ro, counts, base, nodes);
        let offset = cal.no_load_force_n;
        let dynamics = self.dynamics;
        let s = reading(&cal.array.nodes);
        if self.warm == Warm::Unchecked {
            self.warm = self.start_warm(s, frame.t_capture_ns);
        }
        if self.warm != Warm::Known {
            let states_known = cal
                .all_blocks()
                .zip(&self.states)
                .all(|(b, st)| st.plays_known(b));
            match self.warm {
                Warm::Until(until) if frame.t_capture_ns >= until && states_known => {
                    self.warm = Warm::Known
                }
                _ => flags |= force_flags::DYNAMICS_WARMING,
            }
        }
        let mut force = |k: usize, b: &crate::calibration::Block, s: f64| {
            if dynamics {
                self.states[k].step(b, s, c, dt_s)
            } else {
                b.evaluate(s, c)
            }
        };
        let e = force(0, &cal.array, s);
        out.total_reading = s as f32;
        out.total_force_n = (offset + e.force_n) as f32;
        if e.out_of_range {
            flags |= force_flags::OUT_OF_RANGE;
        }
        for (i, b) in cal.blocks.iter().take(MAX_BLOCKS).enumerate() {
            let s = reading(&b.nodes);
            let e = force(i + 1, b, s);
            out.block_reading[i] = s as f32;
            out.block_force_n[i] = (offset + e.force_n) as f32;
            if e.out_of_range {
                flags |= force_flags::OUT_OF_RANGE;
            }
        }
        out.flags = flags;
    }
}

/// The whole array's reading counts as unloaded (dynamic states known to be at rest) below this
/// share of its declared range.
const UNLOADED_SHARE: f64 = 0.02;

/// S of a block (`nodes` empty: every node): the sum of `signal(raw) - signal(baseline)`. The
/// amplifier's identity signal gets its own loop, so the hot path stays a plain sum.
#[inline]
fn block_reading(ro: &Readout, counts: &[f32], base: &[f64], nodes: &[usize]) -> f64 {
    if ro.kind == ReadoutKind::Amplifier {
        sum_signal(counts, base, nodes, |r| r)
    } else {
        sum_signal(counts, base, nodes, |r| ro.signal(r))
    }
}

#[inline(always)]
fn sum_signal(counts: &[f32], base: &[f64], nodes: &[usize], signal: impl Fn(f64) -> f64) -> f64 {
    let node = |k: usize| signal(counts[k] as f64) - base[k];
    if nodes.is_empty() {
        (0..counts.len()).map(node).sum()
    } else {
        nodes
            .iter()
            .filter(|&&k| k < counts.len())
            .map(|&k| node(k))
            .sum()
    }
}

/// Runs the calibrator until shutdown. The initial calibrations (one per file of
/// `cfg.files`) were validated by the caller.
pub fn run(
    ipc: &Ipc,
    cfg: &Config,
    initial: Vec<Calibration>,
    shutdown: &Shutdown,
) -> anyhow::Result<Summary> {
    anyhow::ensure!(
        !cfg.sensors.is_empty() && initial.len() == cfg.files.len(),
        "need sensors and one calibration per file"
    );
    let mut watched: Vec<Watched> = initial
        .iter()
        .zip(&cfg.files)
        .map(|(c, p)| Watched {
            path: p.clone(),
            rows: c.rows,
            cols: c.cols,
            sensors: Vec::new(),
        })
        .collect();
    let loaded: Vec<Arc<Loaded>> = initial
        .into_iter()
        .map(|calibration| {
            Arc::new(Loaded {
                calibration,
                generation: 1,
            })
        })
        .collect();
    let mut lanes = Vec::with_capacity(cfg.sensors.len());
    let mut streams = Streams::default();
    let group = match &cfg.group {
        Some(g) if cfg.sensors.len() > 1 => Some((
            ipc.group_listener(g, Stream::Raw)?,
            ipc.group_notifier(g, Stream::Force)?,
        )),
        _ => None,
    };
    let polled = group.is_some();
    for s in &cfg.sensors {
        let f = s.file;
        anyhow::ensure!(
            f < loaded.len(),
            "sensor {}: no calibration file {f}",
            s.sensor
        );
        if cfg.sensors.len() > 1 {
            watched[f].sensors.push(s.sensor.clone());
        }
        let cal = Calibrator::new(loaded[f].clone(), cfg.curvature_stale_s);
        let shown = cfg.files[f].display().to_string();
        streams.open(ipc, &s.sensor, polled)?;
        lanes.push(Lane::new(&s.sensor, f, shown, cal));
    }
    // Ready once every sensor's streams are open.
    for (lane, curv) in lanes.iter_mut().zip(&streams.curv) {
        info!(
            sensor = %lane.sensor,
            file = %cfg.files[lane.file].display(),
            id = %lane.cal.calibration().id,
            version = lane.cal.calibration().version,
            "calibrator ready"
        );
        // A late start still gets the latest estimate through the stream's history.
        if let Some(est) = curv.latest()? {
            lane.cal.set_curvature(&est);
        }
    }
    let watcher = Watcher::spawn_many(watched)?;
    let wake = if let [lane] = lanes.as_mut_slice() {
        one(lane, &streams, &watcher, cfg.wake, shutdown)?
    } else {
        anyhow::ensure!(
            cfg.wake == WakeMode::Event,
            "several sensors wait event-driven only"
        );
        many(&mut lanes, &streams, &watcher, group.as_ref(), shutdown)?;
        info!(sensors = lanes.len(), "calibrator stopped serving");
        Default::default()
    };
    let mut summary = Summary {
        wake,
        ..Summary::default()
    };
    for l in &lanes {
        summary.frames += l.frames;
        summary.dropped += l.seq.dropped;
        summary.reloads += l.reloads;
        summary.geometry_mismatches += l.geometry_mismatches;
        summary.readout_mismatches += l.readout_mismatches;
    }
    Ok(summary)
}

/// One sensor, in any wake mode, handing over to a polling consumer.
fn one(
    lane: &mut Lane,
    st: &Streams,
    watcher: &Watcher,
    wake: WakeMode,
    shutdown: &Shutdown,
) -> anyhow::Result<taxel_runtime::wake::AdaptiveStats> {
    let stats = receive_loop(
        &st.raw[0],
        LoopOptions::new(wake),
        shutdown,
        |f| (f.seq, f.t_capture_ns),
        |frame, _| {
            lane.poll_curvature(&st.curv[0])?;
            if let Some(l) = watcher.try_next() {
                lane.reloaded(l);
            }
            lane.on_frame(frame, &st.force[0], true)
        },
        || {
            let _ = st.curv[0].clear_wakeups();
        },
    )?;
    Ok(stats)
}

/// Several sensors in one WaitSet: every raw listener attached, or the wake-up group's alone
/// (the raw streams polled when it fires, and the group's force stream notified as forces go
/// out). A reloaded file goes to every sensor it serves, between two frames.
fn many(
    lanes: &mut [Lane],
    st: &Streams,
    watcher: &Watcher,
    group: Option<&(GroupListener, GroupNotifier)>,
    shutdown: &Shutdown,
) -> anyhow::Result<()> {
    let forces = group.map(|(_, n)| n);
    let on_frame = |lanes: &mut [Lane], i: usize, frame: &RawFrame, _: u64| -> anyhow::Result<()> {
        watcher.try_each(|f, l| {
            for lane in lanes.iter_mut().filter(|x| x.file == f) {
                lane.reloaded(l.clone());
            }
        });
        let lane = &mut lanes[i];
        lane.poll_curvature(&st.curv[i])?;
        lane.on_frame(frame, &st.force[i], false)?;
        if let Some(n) = forces {
            n.sent()?;
        }
        Ok(())
    };
    let on_tick = |_: &mut [Lane]| -> anyhow::Result<()> {
        for c in &st.curv {
            let _ = c.clear_wakeups();
        }
        Ok(())
    };
    let tick = taxel_runtime::ipc::TICK;
    match group {
        Some((g, n)) => {
            let flush = |_: &mut [Lane]| -> anyhow::Result<()> { Ok(n.flush()?) };
            receive_group(
                &st.raw, g, None, tick, shutdown, lanes, on_frame, flush, on_tick,
            )?;
            Ok(())
        }
        None => receive_many(&st.raw, None, tick, shutdown, lanes, on_frame, on_tick),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calibrator(creep: &str) -> Calibrator {
        let text = format!(
            "id = \"c\"\nversion = 1\nrows = 1\ncols = 1\n[array]\nname = \"array\"\nmodel = {{ form = \"poly\", terms = [{{ s = 1, c = 0, coef = 0.01 }}] }}\nrange = {{ s = [0, 1000], curvature_m1 = [0, 80] }}\n{creep}\n"
        );
        let cal = Calibration::from_toml_str("c.toml", &text).expect("valid");
        let mut c = Calibrator::for_calibration(cal, 60.0);
        let mut est = CurvatureEstimate::ZERO;
        est.rows = 1;
        est.cols = 1;
        est.baseline[0] = 100.0;
        c.set_curvature(&est);
        c
    }

    /// Flags of a stream held at `reading` for `seconds` at 100 Hz, from t = 1 s.
    fn flags(c: &mut Calibrator, reading: f32, seconds: f64) -> Vec<u32> {
        let mut frame = RawFrame::ZERO;
        frame.rows = 1;
        frame.cols = 1;
        frame.counts[0] = reading;
        let mut out = ForceSample::ZERO;
        (0..(seconds * 100.0) as u64)
            .map(|i| {
                frame.t_capture_ns = 1_000_000_000 + i * 10_000_000;
                c.apply(&frame, frame.t_capture_ns, &mut out);
                out.flags & force_flags::DYNAMICS_WARMING
            })
            .collect()
    }

    #[test]
    fn every_sample_says_how_old_its_zero_is() {
        let text = "id = \"c\"\nversion = 1\nrows = 1\ncols = 1\nno_load_reading = [100]\n[array]\nname = \"array\"\nmodel = { form = \"poly\", terms = [{ s = 1, c = 0, coef = 0.01 }] }\nrange = { s = [0, 1000], curvature_m1 = [0, 80] }\n";
        let cal = Calibration::from_toml_str("c.toml", text).expect("valid");
        let mut c = Calibrator::for_calibration(cal, 60.0);
        let mut frame = RawFrame::ZERO;
        (frame.rows, frame.cols, frame.counts[0]) = (1, 1, 150.0);
        let mut out = ForceSample::ZERO;
        frame.t_capture_ns = 2_000_000_000;
        c.apply(&frame, frame.t_capture_ns, &mut out);
        // Counted from the file's no-load reading: no measured zero, no age.
        assert!(
            out.total_force_n.is_finite() && out.zero_age_s.is_nan(),
            "{out:?}"
        );
        let mut est = CurvatureEstimate::ZERO;
        (est.rows, est.cols, est.baseline[0]) = (1, 1, 101.0);
        est.t_capture_ns = 2_500_000_000;
        c.set_curvature(&est);
        frame.t_capture_ns = 4_000_000_000;
        c.apply(&frame, frame.t_capture_ns, &mut out);
        assert!((out.zero_age_s - 1.5).abs() < 1e-6, "{}", out.zero_age_s);
    }

    #[test]
    fn a_calibrator_started_under_load_flags_its_dynamic_state_until_it_is_known() {
        let creep = "creep = { tau_s = [1, 4], share = [0.1, 0.1] }";
        // Started loaded: warming for the longest time constant (4 s), then not.
        let f = flags(&mut calibrator(creep), 600.0, 6.0);
        assert!(f[..399].iter().all(|&x| x != 0) && f[401..].iter().all(|&x| x == 0));
        // Started at rest: the zero states are right from the first frame.
        assert!(flags(&mut calibrator(creep), 101.0, 2.0)
            .iter()
            .all(|&x| x == 0));
        // Without dynamic terms there is nothing to warm up.
        assert!(flags(&mut calibrator(""), 600.0, 2.0)
            .iter()
            .all(|&x| x == 0));
    }
}
