//! No-load baseline detection with every threshold in units of a noise level measured from the
//! stream itself, so the same defaults work for a 10-bit board with 0.3 counts of noise, a
//! 12-bit divider with 5 counts, and a board that logs ohms.
//!
//! Frames are grouped into consecutive windows of `window_frames`. For each node and window the
//! detector measures, robustly (so rare spikes do not count):
//! - the *level*: a trimmed mean (the 5 % highest and lowest values dropped);
//! - the *spread*: the standard deviation of the same central 90 %, scaled to a normal's (rare
//!   spikes are dropped, but a press filling part of the window is not);
//! - the *noise*: the frame-to-frame noise from first differences (a trimmed mean of their
//!   absolute values, scaled to a standard deviation), floored at half the reading's resolution
//!   (the smallest step seen);
//! - the *reference noise*: the lower quartile of the noise of the last 64 windows, i.e. of the
//!   quietest windows seen so far (from the first window on, its own noise).
//!
//! A window is *steady* when every node's spread is at most `steady_ratio` x its noise (white
//! noise gives about 1; a ramp, a hand's tremor or a drift within the window give more) and its
//! noise at most `noise_ratio` x the reference noise (vibration under load). A steady window is
//! *no load* when no node's level is more than `contact_sigmas` reference noises from the
//! baseline in use (slow drift and wander are followed window by window). The first steady window
//! gives the first baseline (the stream must start unloaded, as the paper's protocol does). A
//! steady level away from the baseline by less than `max_rebaseline_sigmas` on every node that
//! stays for `rebaseline_s` becomes the new baseline: the sensor was remounted (a held press
//! moves the loaded nodes much further, and a hand's tremor keeps it from being steady); when
//! the direction of a load is known and the level lies toward load, it must stay for
//! `rebaseline_load_s` (30 s), longer than a light press is held still (15 s holds in the
//! dynamic protocol were taken for remounts at 5 s). When
//! the direction of the readings with force is known, a steady level on the unloaded side of
//! the baseline is no load whatever its distance (a load only raises conductance): beyond the
//! contact limit it replaces the baseline at once as a new level (flagged like a remount, so the
//! curvature is predicted anew): a remount to a lower-reading curvature, Velostat relaxed to a
//! new unloaded level after its first presses, or a stream cut from the middle of a session
//! that started loaded.
//!
//! Readings of a resistance (ohm) are judged in the log domain, where their noise is even. The
//! published baseline is the level in the stream's own units.

/// Windows whose noise is remembered for the reference noise.
const NOISE_HISTORY: usize = 64;
/// Share of values dropped at each end for the trimmed level and spread.
const TRIM: f64 = 0.05;
/// Standard deviation of the central 90 % of a standard normal: turns the trimmed standard
/// deviation into a standard deviation.
const TRIMMED_SD_NORMAL: f64 = 0.789;

/// Detector settings; thresholds are in units of the stream's own noise.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorConfig {
    /// Frames per window (the paper averages 100 no-load samples).
    pub window_frames: usize,
    /// Steady: each node's spread within the window at most this many times its noise.
    pub steady_ratio: f64,
    /// Steady: each node's noise at most this many times the quietest noise seen.
    pub noise_ratio: f64,
    /// No load: each node's level within this many reference noises of the baseline.
    pub contact_sigmas: f64,
    /// Least time between two published baselines (s).
    pub min_interval_s: f64,
    /// How long a new steady level must last to replace the baseline (s).
    pub rebaseline_s: f64,
    /// The same for a level on the loaded side of the baseline when the direction of a load is
    /// known (`rises`): a light press held still looks like a remount there, so it must last
    /// longer than a hand or a protocol holds a level (s).
    pub rebaseline_load_s: f64,
    /// Largest per-node move from the baseline that can still be a remount (reference noises).
    pub max_rebaseline_sigmas: f64,
    /// Judge the readings in the log domain (a resistance readout).
    pub log_domain: bool,
    /// Whether the readings rise with force (None: not known). When known, a steady level on
    /// the unloaded side of the baseline (no node more than the contact limit toward load)
    /// cannot be a press: it replaces the baseline at once as a new level, however far it moved
    /// (a remount, a sensor relaxing after its first press, a stream that started in one).
    pub rises: Option<bool>,
    /// Fixed overrides, for those who want them: the largest spread of a steady node, and the
    /// largest level move still counted as no load, in the judging domain's units (reading
    /// units; natural-log units for a resistance). None: adaptive.
    pub max_node_sd: Option<f64>,
    pub contact_threshold: Option<f64>,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            window_frames: 100,
            steady_ratio: 2.0,
            noise_ratio: 3.0,
            contact_sigmas: 8.0,
            min_interval_s: 1.0,
            rebaseline_s: 5.0,
            rebaseline_load_s: 30.0,
            max_rebaseline_sigmas: 60.0,
            log_domain: false,
            rises: None,
            max_node_sd: None,
            contact_threshold: None,
        }
    }
}

impl DetectorConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.window_frames < 4 || self.window_frames > 1_000_000 {
            return Err(format!(
                "window_frames must be 4..=1000000, got {}",
                self.window_frames
            ));
        }
        for (v, name) in [
            (self.steady_ratio, "steady_ratio"),
            (self.noise_ratio, "noise_ratio"),
            (self.contact_sigmas, "contact_sigmas"),
            (self.max_rebaseline_sigmas, "max_rebaseline_sigmas"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be a finite number > 0, got {v}"));
            }
        }
        for (v, name) in [
            (self.min_interval_s, "min_interval_s"),
            (self.rebaseline_s, "rebaseline_s"),
            (self.rebaseline_load_s, "rebaseline_load_s"),
            (self.max_node_sd.unwrap_or(0.0), "max_node_sd"),
            (self.contact_threshold.unwrap_or(0.0), "contact_threshold"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be a finite number >= 0, got {v}"));
            }
        }
        Ok(())
    }
}

/// A detected no-load window.
#[derive(Debug, Clone, PartialEq)]
pub struct Baseline {
    /// Level per node (trimmed mean, in the stream's units).
    pub mean: Vec<f64>,
    /// Reference noise per node (one standard deviation, in the judging domain: reading units,
    /// or natural-log units for a resistance).
    pub noise: Vec<f64>,
    pub first_seq: u64,
    pub last_seq: u64,
    pub t_start_ns: u64,
    pub t_end_ns: u64,
    pub frames: usize,
    /// Accepted as a new level after `rebaseline_s` (a remount), not as slow drift.
    pub remount: bool,
}

/// Statistics of one node over one window (judging domain).
#[derive(Debug, Clone, Copy, Default)]
struct NodeStats {
    level: f64,
    spread: f64,
    noise: f64,
    /// Smallest non-zero step between consecutive values (0 if none).
    quantum: f64,
}

/// Expected value of |Z| over the lower 90 % of a standard half-normal: turns the trimmed mean
/// of |differences| into a standard deviation.
const TRIMMED_ABS_NORMAL: f64 = 0.6574;

/// Statistics of `values` (one node's window, judging domain); `scratch` is reused.
fn node_stats(values: &[f64], scratch: &mut Vec<f64>) -> NodeStats {
    let w = values.len();
    scratch.clear();
    scratch.extend_from_slice(values);
    scratch.sort_by(f64::total_cmp);
    let cut = ((w as f64 * TRIM).floor() as usize).min((w - 1) / 2);
    let kept = &scratch[cut..w - cut];
    let level = kept.iter().sum::<f64>() / kept.len() as f64;
    // The spread: the standard deviation of the same central values, scaled to a normal's.
    // Trimmed, not a median deviation: rare spikes are dropped, but a press that fills a
    // third of the window still counts.
    let var = kept.iter().map(|v| (v - level).powi(2)).sum::<f64>() / kept.len() as f64;
    let spread = var.sqrt() / TRIMMED_SD_NORMAL;
    scratch.clear();
    let mut quantum = f64::INFINITY;
    for p in values.windows(2) {
        let d = (p[1] - p[0]).abs();
        if d > 0.0 {
            quantum = quantum.min(d);
        }
        scratch.push(d);
    }
    scratch.sort_by(f64::total_cmp);
    let keep = ((scratch.len() as f64 * 0.9).ceil() as usize).clamp(1, scratch.len());
    let mean_abs = scratch[..keep].iter().sum::<f64>() / keep as f64;
    NodeStats {
        level,
        spread,
        noise: mean_abs / (std::f64::consts::SQRT_2 * TRIMMED_ABS_NORMAL),
        quantum: if quantum.is_finite() { quantum } else { 0.0 },
    }
}

/// Streaming detector; no allocation per frame or window (buffers are sized once per geometry).
#[derive(Debug, Clone)]
pub struct BaselineDetector {
    cfg: DetectorConfig,
    n: usize,
    /// Window values, node-major (`k * window_frames + i`), judging domain.
    buf: Vec<f64>,
    /// Window values in the stream's units, node-major (for the published level).
    raw: Vec<f64>,
    count: usize,
    first_seq: u64,
    last_seq: Option<u64>,
    t_start_ns: u64,
    stats: Vec<NodeStats>,
    /// Noise of the last windows, node-major ring (`k * NOISE_HISTORY + j`).
    history: Vec<f64>,
    history_len: usize,
    history_next: usize,
    /// Smallest non-zero step seen per node over the whole stream.
    quantum: Vec<f64>,
    /// Reference noise per node (judging domain).
    sigma: Vec<f64>,
    scratch: Vec<f64>,
    /// Each node's level minus the baseline in use, for the window just judged (judging
    /// domain, which rises with the reading).
    shift: Vec<f64>,
    /// The baseline in use, judging domain and stream units (valid when `has_current`).
    current: Vec<f64>,
    current_raw: Vec<f64>,
    has_current: bool,
    last_emit_ns: Option<u64>,
    /// A steady level away from the baseline and since when (valid when `candidate_since`).
    candidate: Vec<f64>,
    candidate_since: Option<u64>,
    /// The window just completed (returned by reference).
    out: Baseline,
}

impl BaselineDetector {
    pub fn new(cfg: DetectorConfig) -> BaselineDetector {
        BaselineDetector {
            cfg,
            n: 0,
            buf: Vec::new(),
            raw: Vec::new(),
            count: 0,
            first_seq: 0,
            last_seq: None,
            t_start_ns: 0,
            stats: Vec::new(),
            history: Vec::new(),
            history_len: 0,
            history_next: 0,
            quantum: Vec::new(),
            sigma: Vec::new(),
            scratch: Vec::new(),
            shift: Vec::new(),
            current: Vec::new(),
            current_raw: Vec::new(),
            has_current: false,
            last_emit_ns: None,
            candidate: Vec::new(),
            candidate_since: None,
            out: Baseline {
                mean: Vec::new(),
                noise: Vec::new(),
                first_seq: 0,
                last_seq: 0,
                t_start_ns: 0,
                t_end_ns: 0,
                frames: 0,
                remount: false,
            },
        }
    }

    /// The baseline in use, if any (stream units).
    pub fn current(&self) -> Option<&[f64]> {
        self.has_current.then_some(&self.current_raw[..])
    }

    /// Judges the readings in the log domain from now on (a stream found to report ohms); only
    /// before the first window completes.
    pub fn set_log_domain(&mut self, on: bool) {
        if self.history_len == 0 && self.count == 0 {
            self.cfg.log_domain = on;
        }
    }

    /// Sets the direction of the readings with force (before the first window completes).
    pub fn set_rises(&mut self, rises: Option<bool>) {
        if self.history_len == 0 && self.count == 0 {
            self.cfg.rises = rises;
        }
    }

    /// Starts from a known no-load level (stream units, one per node), e.g. a calibration's:
    /// the first windows are then judged against it (a stream that starts loaded, even steady
    /// or saturated, is not taken as unloaded), and a new level replaces it only as a remount.
    /// Nothing is published until a window confirms a level.
    pub fn seed(&mut self, level: &[f64]) {
        if level.len() != self.n {
            self.resize(level.len());
        }
        for (k, &v) in level.iter().enumerate() {
            self.current[k] = self.domain(v);
            self.current_raw[k] = v;
        }
        self.has_current = true;
    }

    /// The reference noise per node (judging domain), once a window has completed.
    pub fn noise(&self) -> Option<&[f64]> {
        (self.history_len > 0).then_some(&self.sigma[..])
    }

    fn resize(&mut self, n: usize) {
        let w = self.cfg.window_frames;
        self.n = n;
        self.buf = vec![0.0; n * w];
        self.raw = vec![0.0; n * w];
        self.stats = vec![NodeStats::default(); n];
        self.history = vec![0.0; n * NOISE_HISTORY];
        self.history_len = 0;
        self.history_next = 0;
        self.quantum = vec![f64::INFINITY; n];
        self.sigma = vec![0.0; n];
        self.scratch = Vec::with_capacity(w.max(NOISE_HISTORY));
        self.shift = vec![0.0; n];
        self.current = vec![0.0; n];
        self.current_raw = vec![0.0; n];
        self.candidate = vec![0.0; n];
        self.out.mean = vec![0.0; n];
        self.out.noise = vec![0.0; n];
        self.has_current = false;
        self.candidate_since = None;
        self.count = 0;
    }

    fn domain(&self, v: f64) -> f64 {
        if self.cfg.log_domain {
            v.max(1e-9).ln()
        } else {
            v
        }
    }

    /// Feeds one frame; returns a baseline when a window completes as no-load (and the minimum
    /// interval has passed).
    pub fn push(&mut self, seq: u64, t_ns: u64, nodes: &[f32]) -> Option<&Baseline> {
        if nodes.len() != self.n {
            // New geometry: start from scratch (a seed for another geometry is dropped).
            self.resize(nodes.len());
        }
        if self.last_seq.is_some_and(|l| seq != l + 1) {
            self.count = 0;
        }
        self.last_seq = Some(seq);
        if self.count == 0 {
            self.first_seq = seq;
            self.t_start_ns = t_ns;
        }
        let w = self.cfg.window_frames;
        for (k, &v) in nodes.iter().enumerate() {
            let v = v as f64;
            self.raw[k * w + self.count] = v;
            self.buf[k * w + self.count] = self.domain(v);
        }
        self.count += 1;
        if self.count < w {
            return None;
        }
        let frames = self.count;
        self.count = 0;
        self.measure();
        if !self.judge() {
            self.candidate_since = None;
            return None;
        }
        let limit = |sigma: f64, sigmas: f64, fixed: Option<f64>| fixed.unwrap_or(sigma * sigmas);
        let beyond = |me: &Self, k: usize, v: f64| {
            v > limit(me.sigma[k], me.cfg.contact_sigmas, me.cfg.contact_threshold)
        };
        // Steady and away from the baseline: a held press, or a new unloaded level.
        let remount = self.has_current && (0..self.n).any(|k| beyond(self, k, self.shift[k].abs()));
        // Knowing the direction of a load, a level on the unloaded side cannot be a press: it
        // is the new unloaded level at once (a remount, or a sensor that relaxed).
        let unloading = remount
            && self.cfg.rises.is_some()
            && (0..self.n).all(|k| !beyond(self, k, self.toward_load(k)));
        if unloading {
            self.last_emit_ns = None;
        }
        if remount && !unloading {
            let too_far = (0..self.n)
                .any(|k| self.shift[k].abs() > self.sigma[k] * self.cfg.max_rebaseline_sigmas);
            if too_far {
                self.candidate_since = None;
                return None;
            }
            let same = self.candidate_since.is_some()
                && (0..self.n).all(|k| {
                    (self.candidate[k] - self.stats[k].level).abs()
                        <= limit(
                            self.sigma[k],
                            self.cfg.contact_sigmas,
                            self.cfg.contact_threshold,
                        )
                });
            if !same {
                for k in 0..self.n {
                    self.candidate[k] = self.stats[k].level;
                }
                self.candidate_since = Some(self.t_start_ns);
                return None;
            }
            let since = self.candidate_since.unwrap_or(t_ns);
            // Known direction: this level lies toward load (else it would be `unloading`).
            let wait = if self.cfg.rises.is_some() {
                self.cfg.rebaseline_load_s
            } else {
                self.cfg.rebaseline_s
            };
            if (t_ns.saturating_sub(since) as f64) < wait * 1e9 {
                return None;
            }
            // Accepted as a new baseline: publish now regardless of the interval.
            self.last_emit_ns = None;
        }
        self.candidate_since = None;
        for k in 0..self.n {
            self.current[k] = self.stats[k].level;
            self.current_raw[k] = self.out.mean[k];
        }
        self.has_current = true;
        let due = self
            .last_emit_ns
            .is_none_or(|t| t_ns.saturating_sub(t) as f64 >= self.cfg.min_interval_s * 1e9);
        if !due {
            return None;
        }
        self.last_emit_ns = Some(t_ns);
        self.out.noise.copy_from_slice(&self.sigma);
        self.out.first_seq = self.first_seq;
        self.out.last_seq = seq;
        self.out.t_start_ns = self.t_start_ns;
        self.out.t_end_ns = t_ns;
        self.out.frames = frames;
        self.out.remount = remount;
        Some(&self.out)
    }

    /// Measures the completed window: per-node statistics, the published levels, the noise
    /// history and the reference noise.
    fn measure(&mut self) {
        let w = self.cfg.window_frames;
        let slot = self.history_next;
        for k in 0..self.n {
            let s = node_stats(&self.buf[k * w..(k + 1) * w], &mut self.scratch);
            if s.quantum > 0.0 {
                self.quantum[k] = self.quantum[k].min(s.quantum);
            }
            self.stats[k] = s;
            self.history[k * NOISE_HISTORY + slot] = s.noise;
            // The published level: the same trimmed mean, in the stream's units.
            let raw = &self.raw[k * w..(k + 1) * w];
            self.out.mean[k] = if self.cfg.log_domain {
                node_stats(raw, &mut self.scratch).level
            } else {
                s.level
            };
        }
        self.history_next = (slot + 1) % NOISE_HISTORY;
        self.history_len = (self.history_len + 1).min(NOISE_HISTORY);
        for k in 0..self.n {
            self.scratch.clear();
            self.scratch.extend_from_slice(
                &self.history[k * NOISE_HISTORY..k * NOISE_HISTORY + self.history_len],
            );
            self.scratch.sort_by(f64::total_cmp);
            let quiet = self.scratch[(self.history_len - 1) / 4];
            self.sigma[k] = quiet.max(self.floor(k));
        }
    }

    /// The least noise a node can be said to have: half its resolution, or a tiny share of its
    /// level when it never moved.
    fn floor(&self, k: usize) -> f64 {
        let q = self.quantum[k];
        if q.is_finite() {
            0.5 * q
        } else {
            1e-6 * (1.0 + self.stats[k].level.abs())
        }
    }

    /// Whether the window is steady; fills each node's level shift from the baseline in use.
    fn judge(&mut self) -> bool {
        let mut steady = true;
        for k in 0..self.n {
            let s = self.stats[k];
            let noise = s.noise.max(self.floor(k));
            let spread_ok = match self.cfg.max_node_sd {
                Some(max) => s.spread <= max,
                None => {
                    s.spread <= self.cfg.steady_ratio * noise
                        && noise <= self.cfg.noise_ratio * self.sigma[k]
                }
            };
            steady &= spread_ok;
            self.shift[k] = if self.has_current {
                s.level - self.current[k]
            } else {
                0.0
            };
        }
        steady
    }

    /// Node `k`'s shift counted toward load (its size when the direction is not known).
    fn toward_load(&self, k: usize) -> f64 {
        let d = self.shift[k];
        match self.cfg.rises {
            Some(true) => d,
            Some(false) => -d,
            None => d.abs(),
        }
    }
}

#[cfg(test)]
mod tests;
