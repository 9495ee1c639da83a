//! What the monitor knows about each sensor and process, updated from the samples it receives
//! and from iceoryx2's node listing; pure data, no terminal or IPC (unit-tested here).

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use taxel_msgs::{force_flags, CurvatureEstimate, ForceSample, RawFrame, MAX_NODES};

use crate::age::AgeHistogram;

/// Samples of force history kept for the sparklines.
pub const HISTORY: usize = 240;
/// A stream with no sample for this long is stale.
pub const STALE_AFTER: Duration = Duration::from_secs(1);
/// A process whose node was replaced this recently is shown as restarting.
pub const RESTART_SHOWN: Duration = Duration::from_secs(5);
/// Age percentiles are computed over windows of this length.
const AGE_WINDOW: Duration = Duration::from_secs(2);

/// What the heatmap shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// Raw readings as the board sent them.
    Raw,
    /// Raw readings minus the no-load baseline of the latest curvature estimate.
    Baseline,
    /// The array's total force split over the nodes by their share of the reading.
    Force,
}

impl View {
    pub fn next(self) -> View {
        match self {
            View::Raw => View::Baseline,
            View::Baseline => View::Force,
            View::Force => View::Raw,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            View::Raw => "raw counts",
            View::Baseline => "baseline-subtracted counts",
            View::Force => "force (N, by reading share)",
        }
    }
}

/// Everything shown for one sensor.
pub struct SensorState {
    pub id: String,
    pub raw: Option<RawFrame>,
    pub curvature: Option<CurvatureEstimate>,
    pub force: Option<ForceSample>,
    pub last_raw: Option<Instant>,
    pub last_force: Option<Instant>,
    pub last_curvature: Option<Instant>,
    /// Raw frames received in total.
    pub frames: u64,
    /// Frames missing from the raw stream (sequence gaps seen by the monitor).
    pub dropped: u64,
    /// Force samples flagged GAP_BEFORE (the calibrator saw a gap).
    pub gaps_flagged: u64,
    /// Raw frames per second over the last second.
    pub rate_hz: f64,
    rate_count: u64,
    rate_since: Instant,
    /// Total force history (N), oldest first.
    pub total_history: VecDeque<f32>,
    /// Per-block force history (N), oldest first.
    pub block_history: Vec<VecDeque<f32>>,
    /// (calibration generation, when the monitor saw it change).
    pub cal_seen: Option<(u32, Option<Instant>)>,
    ages: AgeHistogram,
    ages_since: Instant,
    /// Sample age capture -> force published: p50, p90, p99, max of the last complete window
    /// (us), and its sample count.
    pub age_us: Option<([f64; 4], u64)>,
}

impl SensorState {
    pub fn new(id: &str, now: Instant) -> SensorState {
        SensorState {
            id: id.to_string(),
            raw: None,
            curvature: None,
            force: None,
            last_raw: None,
            last_force: None,
            last_curvature: None,
            frames: 0,
            dropped: 0,
            gaps_flagged: 0,
            rate_hz: 0.0,
            rate_count: 0,
            rate_since: now,
            total_history: VecDeque::with_capacity(HISTORY),
            block_history: Vec::new(),
            cal_seen: None,
            ages: AgeHistogram::new(),
            ages_since: now,
            age_us: None,
        }
    }

    pub fn on_raw(&mut self, f: &RawFrame, now: Instant) {
        if let Some(prev) = &self.raw {
            if f.seq > prev.seq + 1 {
                self.dropped += f.seq - prev.seq - 1;
            }
        }
        self.raw = Some(*f);
        self.last_raw = Some(now);
        self.frames += 1;
        self.rate_count += 1;
    }

    pub fn on_curvature(&mut self, e: &CurvatureEstimate, now: Instant) {
        self.curvature = Some(*e);
        self.last_curvature = Some(now);
    }

    /// A force sample. Its age is the pipeline's (capture -> calibrator publish, both stamped
    /// by the pipeline), so the monitor's own polling does not inflate it.
    pub fn on_force(&mut self, f: &ForceSample, now: Instant) {
        self.ages
            .record_ns(f.t_publish_ns.saturating_sub(f.t_capture_ns));
        if f.flags & force_flags::GAP_BEFORE != 0 {
            self.gaps_flagged += 1;
        }
        match self.cal_seen {
            None => self.cal_seen = Some((f.cal_generation, None)),
            Some((g, _)) if g != f.cal_generation => {
                self.cal_seen = Some((f.cal_generation, Some(now)))
            }
            _ => {}
        }
        push(&mut self.total_history, f.total_force_n);
        let blocks = f.blocks();
        self.block_history
            .resize_with(blocks.len(), || VecDeque::with_capacity(HISTORY));
        for (h, v) in self.block_history.iter_mut().zip(blocks) {
            push(h, *v);
        }
        self.force = Some(*f);
        self.last_force = Some(now);
    }

    /// Rolls the rate and age windows; call at every redraw.
    pub fn tick(&mut self, now: Instant) {
        let dt = now.duration_since(self.rate_since);
        if dt >= Duration::from_secs(1) {
            self.rate_hz = self.rate_count as f64 / dt.as_secs_f64();
            self.rate_count = 0;
            self.rate_since = now;
        }
        if now.duration_since(self.ages_since) >= AGE_WINDOW {
            if !self.ages.is_empty() {
                let h = &self.ages;
                self.age_us = Some((
                    [
                        h.percentile_us(50.0),
                        h.percentile_us(90.0),
                        h.percentile_us(99.0),
                        h.max_us(),
                    ],
                    h.len(),
                ));
            } else {
                self.age_us = None;
            }
            self.ages.reset();
            self.ages_since = now;
        }
    }

    /// The heatmap values (row-major) and the array's shape for `view`.
    pub fn heatmap(&self, view: View) -> Option<(usize, usize, Vec<f32>)> {
        let f = self.raw.as_ref()?;
        let (rows, cols) = (f.rows as usize, f.cols as usize);
        let n = f.n_nodes();
        let counts = &f.counts[..n];
        let baseline = self
            .curvature
            .as_ref()
            .filter(|c| c.rows == f.rows && c.cols == f.cols)
            .map(|c| &c.baseline[..n.min(MAX_NODES)]);
        let sub: Vec<f32> = match baseline {
            Some(b) => counts.iter().zip(b).map(|(c, b)| c - b).collect(),
            None => vec![f32::NAN; n],
        };
        let values = match view {
            View::Raw => counts.to_vec(),
            View::Baseline => sub,
            View::Force => {
                let total = self.force.as_ref().map_or(f32::NAN, |f| f.total_force_n);
                let sum: f32 = sub.iter().map(|v| v.max(0.0)).sum();
                sub.iter()
                    .map(|v| {
                        if sum > 0.0 {
                            total * v.max(0.0) / sum
                        } else {
                            0.0 * total
                        }
                    })
                    .collect()
            }
        };
        Some((rows, cols, values))
    }
}

fn push(h: &mut VecDeque<f32>, v: f32) {
    if h.len() == HISTORY {
        h.pop_front();
    }
    h.push_back(v);
}

/// Health of one process, from the node listing and its stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Health {
    /// Node alive and its stream (if it has one) delivered within [`STALE_AFTER`].
    Alive,
    /// Node alive but its stream is silent.
    Stale,
    /// A new node replaced the previous one of the same name within [`RESTART_SHOWN`], or the
    /// node is gone after having been seen (a supervisor may bring it back).
    Restarting,
    /// The node's process died without cleaning up.
    Dead,
}

impl Health {
    pub fn label(&self) -> &'static str {
        match self {
            Health::Alive => "alive",
            Health::Stale => "stale",
            Health::Restarting => "restarting",
            Health::Dead => "dead",
        }
    }
}

/// One process as seen in the node listing.
#[derive(Debug, Clone)]
pub struct ProcState {
    pub name: String,
    pub pid: u32,
    pub node_id: String,
    pub alive: bool,
    pub present: bool,
    pub restarts: u32,
    pub replaced_at: Option<Instant>,
    pub gone_since: Option<Instant>,
}

/// A node listing entry: name, pid, unique id, alive.
pub struct NodeSeen {
    pub name: String,
    pub pid: u32,
    pub id: String,
    pub alive: bool,
}

/// Processes by node name, updated from successive node listings.
#[derive(Default)]
pub struct Procs {
    pub by_name: BTreeMap<String, ProcState>,
}

impl Procs {
    pub fn update(&mut self, nodes: &[NodeSeen], now: Instant) {
        for p in self.by_name.values_mut() {
            p.present = false;
        }
        for n in nodes {
            // A dead node next to a live one of the same name is the old incarnation.
            if !n.alive && nodes.iter().any(|o| o.alive && o.name == n.name) {
                continue;
            }
            match self.by_name.get_mut(&n.name) {
                Some(p) => {
                    if p.node_id != n.id && n.alive {
                        p.restarts += 1;
                        p.replaced_at = Some(now);
                    }
                    p.node_id = n.id.clone();
                    p.pid = n.pid;
                    p.alive = n.alive;
                    p.present = true;
                    p.gone_since = None;
                }
                None => {
                    self.by_name.insert(
                        n.name.clone(),
                        ProcState {
                            name: n.name.clone(),
                            pid: n.pid,
                            node_id: n.id.clone(),
                            alive: n.alive,
                            present: true,
                            restarts: 0,
                            replaced_at: None,
                            gone_since: None,
                        },
                    );
                }
            }
        }
        for p in self.by_name.values_mut() {
            if !p.present && p.gone_since.is_none() {
                p.gone_since = Some(now);
            }
        }
    }

    /// The health of `p`, given when its stream last delivered (None: it has no stream the
    /// monitor follows).
    pub fn health(p: &ProcState, last_data: Option<Option<Instant>>, now: Instant) -> Health {
        if !p.present {
            return Health::Restarting;
        }
        if !p.alive {
            return Health::Dead;
        }
        if p.replaced_at
            .is_some_and(|t| now.duration_since(t) < RESTART_SHOWN)
        {
            return Health::Restarting;
        }
        match last_data {
            Some(Some(t)) if now.duration_since(t) <= STALE_AFTER => Health::Alive,
            Some(_) => Health::Stale,
            None => Health::Alive,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(seq: u64, counts: &[f32]) -> RawFrame {
        let mut f = RawFrame::ZERO;
        f.seq = seq;
        f.rows = 2;
        f.cols = 2;
        f.counts[..4].copy_from_slice(counts);
        f
    }

    #[test]
    fn drops_rate_and_views() {
        let t0 = Instant::now();
        let mut s = SensorState::new("s0", t0);
        s.on_raw(&raw(1, &[10.0, 20.0, 30.0, 40.0]), t0);
        s.on_raw(&raw(4, &[10.0, 20.0, 30.0, 40.0]), t0);
        assert_eq!((s.frames, s.dropped), (2, 2));
        s.tick(t0 + Duration::from_secs(2));
        assert_eq!(s.rate_hz, 1.0);
        let (r, c, v) = s.heatmap(View::Raw).expect("frame");
        assert_eq!((r, c, v), (2, 2, vec![10.0, 20.0, 30.0, 40.0]));
        // No baseline yet: subtracted view is unknown.
        assert!(s.heatmap(View::Baseline).expect("frame").2[0].is_nan());
        let mut e = CurvatureEstimate::ZERO;
        e.rows = 2;
        e.cols = 2;
        e.baseline[..4].copy_from_slice(&[10.0, 10.0, 10.0, 10.0]);
        s.on_curvature(&e, t0);
        assert_eq!(
            s.heatmap(View::Baseline).expect("frame").2,
            vec![0.0, 10.0, 20.0, 30.0]
        );
        let mut f = ForceSample::ZERO;
        f.total_force_n = 6.0;
        f.n_blocks = 2;
        f.block_force_n[..2].copy_from_slice(&[1.0, 5.0]);
        f.cal_generation = 1;
        f.t_capture_ns = 1_000;
        f.t_publish_ns = 51_000;
        s.on_force(&f, t0);
        assert_eq!(
            s.heatmap(View::Force).expect("frame").2,
            vec![0.0, 1.0, 2.0, 3.0]
        );
        assert_eq!(s.block_history.len(), 2);
        assert_eq!(s.cal_seen, Some((1, None)));
        f.cal_generation = 2;
        let t1 = t0 + Duration::from_secs(3);
        s.on_force(&f, t1);
        assert_eq!(s.cal_seen, Some((2, Some(t1))));
        s.tick(t1 + AGE_WINDOW);
        let (p, n) = s.age_us.expect("ages");
        assert_eq!(n, 2);
        assert!((p[0] - 50.0).abs() < 0.1, "{p:?}");
        assert_eq!(View::Force.next(), View::Raw);
    }

    #[test]
    fn process_health_follows_nodes_and_streams() {
        let t0 = Instant::now();
        let mut p = Procs::default();
        let node = |id: &str, alive| NodeSeen {
            name: "publisher-s0".into(),
            pid: 7,
            id: id.into(),
            alive,
        };
        p.update(&[node("a", true)], t0);
        let s = &p.by_name["publisher-s0"];
        assert_eq!(Procs::health(s, Some(Some(t0)), t0), Health::Alive);
        let later = t0 + Duration::from_secs(3);
        assert_eq!(Procs::health(s, Some(Some(t0)), later), Health::Stale);
        assert_eq!(Procs::health(s, None, later), Health::Alive);
        p.update(&[node("a", false)], later);
        let s = &p.by_name["publisher-s0"];
        assert_eq!(Procs::health(s, Some(Some(t0)), later), Health::Dead);
        p.update(&[node("a", false), node("b", true)], later);
        let s = &p.by_name["publisher-s0"];
        assert_eq!(s.restarts, 1);
        assert_eq!(
            Procs::health(s, Some(Some(later)), later),
            Health::Restarting
        );
        let much_later = later + RESTART_SHOWN;
        assert_eq!(
            Procs::health(s, Some(Some(much_later)), much_later),
            Health::Alive
        );
        p.update(&[], much_later);
        let s = &p.by_name["publisher-s0"];
        assert_eq!(Procs::health(s, None, much_later), Health::Restarting);
    }
}
