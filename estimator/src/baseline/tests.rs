//! The detector on streams with each property it must handle: 10- and 12-bit boards, readings in
//! ohms, white noise from 0.3 to 5 counts, slow wander, rare spikes; presses, a hand's tremor
//! and remounts.

use super::*;
use taxel_sim::rng::Rng;

const RATE_HZ: f64 = 100.0;

/// A synthetic board: per-node unloaded level, noise, wander and spikes, and a load profile.
struct Stream {
    base: Vec<f64>,
    noise: f64,
    /// Random-walk wander per second (counts), common to every node.
    wander_per_s: f64,
    spike_every: usize,
    spike: f64,
    /// Reading change per newton on each node (sign: the readout's direction).
    gain: Vec<f64>,
    resolution: f64,
    /// Multiplicative noise (a resistance's noise scales with its level).
    relative: bool,
    rng: Rng,
    wander: f64,
    seq: u64,
}

impl Stream {
    fn new(base: Vec<f64>, noise: f64, gain: f64, seed: u64) -> Stream {
        let n = base.len();
        Stream {
            base,
            noise,
            wander_per_s: 0.0,
            spike_every: 0,
            spike: 0.0,
            gain: (0..n).map(|k| gain * (1.0 + 0.1 * k as f64)).collect(),
            resolution: 1.0,
            relative: false,
            rng: Rng::new(seed, 7),
            wander: 0.0,
            seq: 0,
        }
    }

    /// The next frame under `force` (N) plus a tremor of `tremor_n` at 9 Hz.
    fn frame(&mut self, force: f64, tremor_n: f64) -> Vec<f32> {
        let t = self.seq as f64 / RATE_HZ;
        let f = force + tremor_n * (2.0 * std::f64::consts::PI * 9.0 * t).sin();
        self.wander += self.wander_per_s * (1.0 / RATE_HZ).sqrt() * self.rng.normal();
        let spike = self.spike_every > 0 && self.seq % self.spike_every as u64 == 17;
        let mut out = Vec::with_capacity(self.base.len());
        for k in 0..self.base.len() {
            let mut v = self.base[k] + self.wander + self.gain[k] * f;
            let e = self.noise * self.rng.normal();
            v += if self.relative { v * e } else { e };
            if spike && k == 3 {
                v += self.spike;
            }
            if self.resolution > 0.0 {
                v = (v / self.resolution).round() * self.resolution;
            }
            out.push(v.max(0.0) as f32);
        }
        self.seq += 1;
        out
    }

    /// Feeds `seconds` of `force` (and tremor) and returns the baselines published.
    fn feed(
        &mut self,
        d: &mut BaselineDetector,
        seconds: f64,
        force: f64,
        tremor: f64,
    ) -> Vec<Baseline> {
        let mut got = Vec::new();
        for _ in 0..(seconds * RATE_HZ).round() as usize {
            let seq = self.seq;
            let nodes = self.frame(force, tremor);
            if let Some(b) = d.push(seq, (seq as f64 / RATE_HZ * 1e9) as u64, &nodes) {
                got.push(b.clone());
            }
        }
        got
    }
}

fn detector(log_domain: bool) -> BaselineDetector {
    BaselineDetector::new(DetectorConfig {
        log_domain,
        ..DetectorConfig::default()
    })
}

/// Runs the standard protocol on a stream: 3 s unloaded, a 3 s press with tremor, a 3 s held
/// press without tremor, 3 s unloaded. Asserts the baselines come from the unloaded spans only
/// and match the unloaded level within a few noise sd.
fn protocol(s: &mut Stream, d: &mut BaselineDetector, press_n: f64, what: &str) {
    let start = s.seq;
    let first = s.feed(d, 3.0, 0.0, 0.0);
    assert!(!first.is_empty(), "{what}: no baseline in the first 3 s");
    let at = first[0].last_seq - start;
    assert!(at < 200, "{what}: first baseline only at frame {at}");
    for (k, &m) in first[0].mean.iter().enumerate() {
        let tol = if s.relative {
            0.05 * s.base[k]
        } else {
            3.0 * s.noise.max(0.5) + s.wander.abs() + 1.0
        };
        assert!(
            (m - s.base[k]).abs() <= tol + s.wander.abs(),
            "{what}: node {k} level {m} vs {}",
            s.base[k]
        );
    }
    assert!(
        s.feed(d, 3.0, press_n, 0.15 * press_n).is_empty(),
        "{what}: a press with tremor was taken as no load"
    );
    assert!(
        s.feed(d, 3.0, press_n, 0.0).is_empty(),
        "{what}: a steady press was taken as no load"
    );
    let after = s.feed(d, 3.0, 0.0, 0.0);
    assert!(!after.is_empty(), "{what}: no baseline after the press");
    assert!(
        after.iter().all(|b| !b.remount),
        "{what}: unloading was taken as a remount"
    );
}

#[test]
fn ten_bit_amplifier_with_little_noise() {
    for noise in [0.3, 1.4] {
        let base: Vec<f64> = (0..16).map(|k| 100.0 + 3.0 * k as f64).collect();
        let mut s = Stream::new(base, noise, 40.0, 1);
        protocol(
            &mut s,
            &mut detector(false),
            2.0,
            &format!("10-bit, noise {noise}"),
        );
    }
}

#[test]
fn twelve_bit_divider_with_five_counts_of_noise() {
    let base: Vec<f64> = (0..16).map(|k| 450.0 + 60.0 * k as f64).collect();
    let mut s = Stream::new(base, 5.0, 300.0, 2);
    protocol(&mut s, &mut detector(false), 1.0, "12-bit, noise 5");
}

#[test]
fn readings_in_ohms_with_noise_that_scales_with_the_level() {
    let base: Vec<f64> = (0..16).map(|k| 20_000.0 + 1500.0 * k as f64).collect();
    let mut s = Stream::new(base, 0.004, -1500.0, 3);
    s.relative = true;
    s.resolution = 1.0;
    protocol(&mut s, &mut detector(true), 2.0, "ohms");
}

#[test]
fn slow_wander_is_followed_and_spikes_ignored() {
    let base: Vec<f64> = (0..16).map(|k| 300.0 + 10.0 * k as f64).collect();
    let mut s = Stream::new(base, 1.4, 50.0, 4);
    s.wander_per_s = 0.8;
    s.spike_every = 150;
    s.spike = 60.0;
    let mut d = detector(false);
    let got = s.feed(&mut d, 60.0, 0.0, 0.0);
    // One baseline a second (the minimum interval) for the whole minute, none a "remount".
    assert!(got.len() >= 50, "{} baselines in 60 s", got.len());
    assert!(got.iter().all(|b| !b.remount));
    // The spikes (60 counts on node 3 every 1.5 s) do not pull its level.
    let last = got.last().map_or(0.0, |b| b.mean[3] - b.mean[2]);
    assert!((last - 10.0).abs() < 3.0, "node 3 - node 2 = {last}");
    // The reference noise is the white noise, not the spikes or the wander.
    let noise = d.noise().map_or(0.0, |n| n[3]);
    assert!((1.0..2.0).contains(&noise), "noise {noise}");
    protocol(&mut s, &mut d, 2.0, "wander and spikes");
}

#[test]
fn a_remount_becomes_the_new_baseline_after_a_while_but_a_press_never_does() {
    let base: Vec<f64> = vec![100.0; 16];
    let mut s = Stream::new(base, 0.5, 40.0, 5);
    let mut d = BaselineDetector::new(DetectorConfig {
        rebaseline_s: 2.0,
        ..DetectorConfig::default()
    });
    assert!(!s.feed(&mut d, 2.0, 0.0, 0.0).is_empty());
    // Remounted: every node 8 counts (16 sd) higher, steady. Not before 2 s, then yes.
    for b in s.base.iter_mut() {
        *b += 8.0;
    }
    assert!(s.feed(&mut d, 1.5, 0.0, 0.0).is_empty());
    let new = s.feed(&mut d, 3.0, 0.0, 0.0);
    assert!(
        !new.is_empty() && new[0].remount,
        "remount accepted after rebaseline_s"
    );
    assert!((new[0].mean[0] - 108.0).abs() < 0.5, "{}", new[0].mean[0]);
    // A steady press (200 counts on the loaded nodes) is never a baseline.
    assert!(s.feed(&mut d, 10.0, 5.0, 0.0).is_empty());
    assert!((d.current().map_or(0.0, |c| c[0]) - 108.0).abs() < 0.5);
}

#[test]
fn gaps_restart_the_window_and_the_interval_limits_publishing() {
    let mut d = BaselineDetector::new(DetectorConfig {
        window_frames: 10,
        ..DetectorConfig::default()
    });
    for s in 0..5 {
        assert!(d.push(s, s, &[1.0]).is_none());
    }
    // seq jumps: the partial window is discarded.
    for s in 10..19 {
        assert!(d.push(s, s, &[1.0]).is_none());
    }
    assert!(d.push(19, 19, &[1.0]).is_some());
    // 1 ms per frame: the next allowed one is 1 s later.
    let mut emitted = 0;
    for s in 20..1000u64 {
        if d.push(s, s * 1_000_000, &[1.0]).is_some() {
            emitted += 1;
        }
    }
    assert_eq!(emitted, 0);
    assert!(d.current().is_some());
}

#[test]
fn fixed_overrides_replace_the_adaptive_thresholds() {
    let base: Vec<f64> = vec![100.0; 4];
    let mut s = Stream::new(base, 2.0, 40.0, 6);
    // A spread limit far below the noise: nothing is steady.
    let mut d = BaselineDetector::new(DetectorConfig {
        max_node_sd: Some(0.5),
        ..DetectorConfig::default()
    });
    assert!(s.feed(&mut d, 5.0, 0.0, 0.0).is_empty());
    let bad = DetectorConfig {
        contact_threshold: Some(f64::NAN),
        ..DetectorConfig::default()
    };
    assert!(bad
        .validate()
        .expect_err("refused")
        .contains("contact_threshold"));
}

#[test]
fn a_stream_that_starts_in_a_hand_gets_its_baseline_only_once_released() {
    for (noise, gain) in [(0.3, 40.0), (5.0, 300.0)] {
        let base: Vec<f64> = (0..16).map(|k| 200.0 + 5.0 * k as f64).collect();
        let mut s = Stream::new(base, noise, gain, 8);
        let mut d = detector(false);
        // Held by a hand (tremor 0.1 N at 9 Hz on 3 N), then a slow ramp down.
        assert!(
            s.feed(&mut d, 4.0, 3.0, 0.1).is_empty(),
            "noise {noise}: tremor taken as no load"
        );
        for i in 0..30 {
            let f = 3.0 * (1.0 - i as f64 / 30.0);
            assert!(
                s.feed(&mut d, 0.1, f, 0.0).is_empty(),
                "noise {noise}: a ramp taken as no load"
            );
        }
        let got = s.feed(&mut d, 2.0, 0.0, 0.0);
        assert!(!got.is_empty(), "noise {noise}: no baseline once released");
        assert!(
            (got[0].mean[0] - 200.0).abs() < 3.0 * noise + 1.0,
            "{}",
            got[0].mean[0]
        );
    }
}

#[test]
fn a_seeded_detector_does_not_take_a_steady_loaded_start_as_unloaded() {
    let base: Vec<f64> = (0..4).map(|k| 5000.0 - 10.0 * k as f64).collect();
    let mut s = Stream::new(base.clone(), 2.0, -600.0, 9);
    let mut d = detector(false);
    d.seed(&base);
    // Starts pressed to saturation-like steadiness (the reading far below the seed).
    assert!(s.feed(&mut d, 10.0, 6.0, 0.0).is_empty());
    let got = s.feed(&mut d, 2.0, 0.0, 0.0);
    assert!(
        !got.is_empty() && !got[0].remount,
        "the unloaded level confirms the seed"
    );
    assert!((got[0].mean[0] - 5000.0).abs() < 2.0);
    // Unseeded, the same start is (unavoidably) taken as the first baseline.
    let mut s = Stream::new(base, 2.0, -600.0, 9);
    let mut d = detector(false);
    let first = s.feed(&mut d, 10.0, 6.0, 0.0);
    assert!(!first.is_empty() && first[0].mean[0] < 2000.0);
}

#[test]
fn a_window_that_is_partly_a_press_is_not_steady() {
    let base = vec![5000.0; 2];
    let mut s = Stream::new(base.clone(), 3.0, -600.0, 10);
    let mut d = detector(false);
    d.seed(&base);
    // Windows of 100 frames: 65 at rest, then a 35-frame press, over and over.
    for _ in 0..6 {
        assert!(s.feed(&mut d, 0.65, 0.0, 0.0).len() <= 1);
        assert!(s.feed(&mut d, 0.35, 5.0, 0.0).is_empty());
    }
    assert!(
        (d.current().map_or(0.0, |c| c[0]) - 5000.0).abs() < 5.0,
        "{:?}",
        d.current()
    );
}

#[test]
fn knowing_the_direction_a_level_on_the_unloaded_side_replaces_the_baseline_at_once() {
    // A stream cut from the middle of a session: it starts in a steady press, which is
    // (unavoidably) the first baseline, then unloads.
    let base: Vec<f64> = (0..4).map(|k| 5000.0 - 10.0 * k as f64).collect();
    for (rises, gain) in [(false, -600.0), (true, 600.0)] {
        let mut s = Stream::new(base.clone(), 2.0, gain, 11);
        let mut d = BaselineDetector::new(DetectorConfig {
            rises: Some(rises),
            ..DetectorConfig::default()
        });
        let first = s.feed(&mut d, 3.0, 4.0, 0.0);
        assert!(!first.is_empty() && (first[0].mean[0] - 5000.0).abs() > 1000.0);
        // Unloaded: the first steady window replaces it, published at once as a new level.
        let got = s.feed(&mut d, 1.5, 0.0, 0.0);
        assert!(!got.is_empty() && got[0].remount, "rises {rises}: {got:?}");
        assert!((got[0].mean[0] - 5000.0).abs() < 2.0, "{}", got[0].mean[0]);
        // A steady press afterwards is still never a baseline.
        assert!(s.feed(&mut d, 10.0, 4.0, 0.0).is_empty());
        // Not knowing the direction, the unloaded level is too far from the first baseline to
        // be a remount, and is never taken.
        let mut s = Stream::new(base.clone(), 2.0, gain, 11);
        let mut d = detector(false);
        s.feed(&mut d, 3.0, 4.0, 0.0);
        assert!(s.feed(&mut d, 1.5, 0.0, 0.0).is_empty(), "rises {rises}");
    }
}

#[test]
fn knowing_the_direction_a_light_press_held_still_for_15_s_is_not_a_remount() {
    // A light press (0.1 N: 4-5 counts on a node, 8-10 noise sd) held without tremor, as a
    // protocol's 15 s hold at a low force on a stiff mounting: with the direction known it
    // must stay 30 s to be taken for a remount.
    let base: Vec<f64> = vec![100.0; 16];
    let mut s = Stream::new(base, 0.5, 40.0, 17);
    let mut d = BaselineDetector::new(DetectorConfig {
        rises: Some(true),
        ..DetectorConfig::default()
    });
    assert!(!s.feed(&mut d, 2.0, 0.0, 0.0).is_empty());
    assert!(s.feed(&mut d, 15.0, 0.1, 0.0).is_empty(), "a 15 s hold");
    assert!(!s.feed(&mut d, 3.0, 0.0, 0.0).is_empty(), "unloaded again");
    // The same level for 35 s is a remount (the sensor was mounted on a higher curvature).
    let got = s.feed(&mut d, 35.0, 0.1, 0.0);
    assert!(!got.is_empty() && got[0].remount, "{got:?}");
    // Not knowing the direction, 5 s are enough (rebaseline_s).
    let mut s = Stream::new(vec![100.0; 16], 0.5, 40.0, 17);
    let mut d = detector(false);
    assert!(!s.feed(&mut d, 2.0, 0.0, 0.0).is_empty());
    assert!(!s.feed(&mut d, 15.0, 0.1, 0.0).is_empty());
}
