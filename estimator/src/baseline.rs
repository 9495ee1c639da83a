//! No-load baseline detection. Frames are grouped into consecutive windows of `window_frames`;
//! a window is "no load" when every node is steady (standard deviation at most `max_node_sd`)
//! and, once a baseline is known, no node's mean has moved more than `contact_threshold` from it
//! (so a steady press is not mistaken for a new baseline, in either direction of the reading,
//! while slow drift is followed). The first steady window gives the first baseline. A steady
//! level that differs from the baseline by more than `contact_threshold` but less than
//! `max_rebaseline_shift` on every node, and stays for `rebaseline_s`, becomes the new baseline:
//! the sensor was remounted (a held press moves the loaded nodes much further, and a human hand's
//! tremor keeps it from being steady).

/// Detector settings (readings in the units of the stream, ADC counts by default).
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorConfig {
    /// Frames per window (the paper averages 100 no-load samples).
    pub window_frames: usize,
    /// Largest per-node standard deviation in a no-load window.
    pub max_node_sd: f64,
    /// Largest per-node move of the window mean from the current baseline.
    pub contact_threshold: f64,
    /// Least time between two published baselines (s).
    pub min_interval_s: f64,
    /// How long a new steady level must last to replace the baseline (s).
    pub rebaseline_s: f64,
    /// Largest per-node move from the baseline that can still be a remount.
    pub max_rebaseline_shift: f64,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            window_frames: 100,
            max_node_sd: 1.5,
            contact_threshold: 4.0,
            min_interval_s: 1.0,
            rebaseline_s: 5.0,
            max_rebaseline_shift: 25.0,
        }
    }
}

impl DetectorConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.window_frames < 2 || self.window_frames > 1_000_000 {
            return Err(format!(
                "window_frames must be 2..=1000000, got {}",
                self.window_frames
            ));
        }
        for (v, name) in [
            (self.max_node_sd, "max_node_sd"),
            (self.contact_threshold, "contact_threshold"),
            (self.min_interval_s, "min_interval_s"),
            (self.rebaseline_s, "rebaseline_s"),
            (self.max_rebaseline_shift, "max_rebaseline_shift"),
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
    /// Mean reading per node.
    pub mean: Vec<f64>,
    pub first_seq: u64,
    pub last_seq: u64,
    pub t_start_ns: u64,
    pub t_end_ns: u64,
    pub frames: usize,
    /// Accepted as a new level after `rebaseline_s` (a remount), not as slow drift.
    pub remount: bool,
}

/// Streaming detector; no allocation per frame (buffers are sized once per geometry).
#[derive(Debug, Clone)]
pub struct BaselineDetector {
    cfg: DetectorConfig,
    n: usize,
    sum: Vec<f64>,
    sumsq: Vec<f64>,
    count: usize,
    first_seq: u64,
    last_seq: Option<u64>,
    t_start_ns: u64,
    /// The baseline in use (valid when `has_current`).
    current: Vec<f64>,
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
            sum: Vec::new(),
            sumsq: Vec::new(),
            count: 0,
            first_seq: 0,
            last_seq: None,
            t_start_ns: 0,
            current: Vec::new(),
            has_current: false,
            last_emit_ns: None,
            candidate: Vec::new(),
            candidate_since: None,
            out: Baseline {
                mean: Vec::new(),
                first_seq: 0,
                last_seq: 0,
                t_start_ns: 0,
                t_end_ns: 0,
                frames: 0,
                remount: false,
            },
        }
    }

    /// The baseline in use, if any.
    pub fn current(&self) -> Option<&[f64]> {
        self.has_current.then_some(&self.current[..])
    }

    fn restart(&mut self) {
        self.count = 0;
        self.sum.iter_mut().for_each(|v| *v = 0.0);
        self.sumsq.iter_mut().for_each(|v| *v = 0.0);
    }

    /// Feeds one frame; returns a baseline when a window completes as no-load (and the minimum
    /// interval has passed).
    pub fn push(&mut self, seq: u64, t_ns: u64, nodes: &[f32]) -> Option<&Baseline> {
        if nodes.len() != self.n {
            // New geometry: start from scratch.
            self.n = nodes.len();
            self.sum = vec![0.0; self.n];
            self.sumsq = vec![0.0; self.n];
            self.current = vec![0.0; self.n];
            self.candidate = vec![0.0; self.n];
            self.out.mean = vec![0.0; self.n];
            self.has_current = false;
            self.candidate_since = None;
            self.count = 0;
        }
        if self.last_seq.is_some_and(|l| seq != l + 1) {
            self.restart();
        }
        self.last_seq = Some(seq);
        if self.count == 0 {
            self.first_seq = seq;
            self.t_start_ns = t_ns;
        }
        for ((s, q), &v) in self.sum.iter_mut().zip(self.sumsq.iter_mut()).zip(nodes) {
            let v = v as f64;
            *s += v;
            *q += v * v;
        }
        self.count += 1;
        if self.count < self.cfg.window_frames {
            return None;
        }
        let m = self.count as f64;
        let mut steady = true;
        let mut shift: f64 = 0.0;
        for k in 0..self.n {
            let mu = self.sum[k] / m;
            let var = (self.sumsq[k] / m - mu * mu).max(0.0);
            if var.sqrt() > self.cfg.max_node_sd {
                steady = false;
            }
            if self.has_current {
                shift = shift.max((mu - self.current[k]).abs());
            }
            self.out.mean[k] = mu;
        }
        let frames = self.count;
        self.restart();
        if !steady {
            self.candidate_since = None;
            return None;
        }
        let remount = shift > self.cfg.contact_threshold;
        if remount {
            // Steady but away from the baseline: a held press, or a remount.
            if shift > self.cfg.max_rebaseline_shift {
                self.candidate_since = None;
                return None;
            }
            let same = self.candidate_since.is_some()
                && self
                    .candidate
                    .iter()
                    .zip(&self.out.mean)
                    .all(|(a, b)| (a - b).abs() <= self.cfg.contact_threshold);
            if !same {
                self.candidate.copy_from_slice(&self.out.mean);
                self.candidate_since = Some(self.t_start_ns);
                return None;
            }
            let since = self.candidate_since.unwrap_or(t_ns);
            if (t_ns.saturating_sub(since) as f64) < self.cfg.rebaseline_s * 1e9 {
                return None;
            }
            // Accepted as a new baseline: publish now regardless of the interval.
            self.last_emit_ns = None;
        }
        self.candidate_since = None;
        let due = self
            .last_emit_ns
            .is_none_or(|t| t_ns.saturating_sub(t) as f64 >= self.cfg.min_interval_s * 1e9);
        self.current.copy_from_slice(&self.out.mean);
        self.has_current = true;
        if !due {
            return None;
        }
        self.last_emit_ns = Some(t_ns);
        self.out.first_seq = self.first_seq;
        self.out.last_seq = seq;
        self.out.t_start_ns = self.t_start_ns;
        self.out.t_end_ns = t_ns;
        self.out.frames = frames;
        self.out.remount = remount;
        Some(&self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> DetectorConfig {
        DetectorConfig {
            window_frames: 10,
            min_interval_s: 0.0,
            ..DetectorConfig::default()
        }
    }

    #[test]
    fn steady_windows_give_baselines_and_presses_do_not() {
        let mut d = BaselineDetector::new(cfg());
        let mut seq = 0;
        let mut feed = |d: &mut BaselineDetector, level: f32, n: usize| {
            let mut out = Vec::new();
            for i in 0..n {
                let wobble = if i % 2 == 0 { 0.5 } else { -0.5 };
                if let Some(b) = d.push(seq, seq * 1_000_000, &[level + wobble, 100.0]) {
                    out.push(b.clone());
                }
                seq += 1;
            }
            out
        };
        let first = feed(&mut d, 110.0, 10);
        assert_eq!(first.len(), 1);
        assert!((first[0].mean[0] - 110.0).abs() < 1e-9);
        // A steady press far above the baseline is not a baseline.
        assert!(feed(&mut d, 300.0, 30).is_empty());
        // A ramp is not steady.
        let mut ramp = Vec::new();
        for i in 0..10 {
            ramp.extend(feed(&mut d, 110.0 + i as f32 * 2.0, 1));
        }
        assert!(ramp.is_empty());
        // Slow drift within the threshold is followed.
        let drift = feed(&mut d, 112.0, 10);
        assert_eq!(drift.len(), 1);
        assert!((drift[0].mean[0] - 112.0).abs() < 1e-9);
    }

    #[test]
    fn gaps_restart_the_window() {
        let mut d = BaselineDetector::new(cfg());
        for s in 0..5 {
            assert!(d.push(s, s, &[1.0]).is_none());
        }
        // seq jumps: the partial window is discarded.
        for s in 10..19 {
            assert!(d.push(s, s, &[1.0]).is_none());
        }
        assert!(d.push(19, 19, &[1.0]).is_some());
    }

    #[test]
    fn a_remount_becomes_the_new_baseline_after_a_while_but_a_press_never_does() {
        let mut d = BaselineDetector::new(DetectorConfig {
            window_frames: 10,
            min_interval_s: 0.0,
            rebaseline_s: 1.0,
            ..DetectorConfig::default()
        });
        let ms = 1_000_000u64;
        let mut seq = 0u64;
        let mut feed = |d: &mut BaselineDetector, levels: [f32; 2], frames: usize| {
            let mut got = Vec::new();
            for _ in 0..frames {
                if let Some(b) = d.push(seq, seq * 10 * ms, &levels) {
                    got.push(b.clone());
                }
                seq += 1;
            }
            got
        };
        assert_eq!(feed(&mut d, [100.0, 100.0], 10).len(), 1);
        // Remounted: every node 8 counts higher, steady. Not before 1 s, then yes.
        assert!(feed(&mut d, [108.0, 108.0], 90).is_empty());
        let new = feed(&mut d, [108.0, 108.0], 30);
        assert!(!new.is_empty(), "remount accepted after rebaseline_s");
        assert!(new[0].remount);
        assert!((new[0].mean[0] - 108.0).abs() < 1e-9);
        // A steady press 200 counts up on one node is never a baseline.
        assert!(feed(&mut d, [308.0, 108.0], 500).is_empty());
        assert!((d.current().map_or(0.0, |c| c[0]) - 108.0).abs() < 1e-9);
    }

    #[test]
    fn min_interval_limits_publishing() {
        let mut d = BaselineDetector::new(DetectorConfig {
            window_frames: 10,
            min_interval_s: 1.0,
            ..DetectorConfig::default()
        });
        let mut emitted = 0;
        for s in 0..1000u64 {
            // 1 ms per frame: the first window ends at 9 ms, the next allowed one at >= 1009 ms.
            if d.push(s, s * 1_000_000, &[5.0]).is_some() {
                emitted += 1;
            }
        }
        assert_eq!(emitted, 1);
        assert!(d.current().is_some());
    }
}
