//! Test fixtures shared by the unit tests.

use crate::data::{Dataset, ReadoutMap};

/// One node, presses with independent levels and ramp durations (0.2-2 s) at 100 Hz.
pub fn presses() -> Dataset {
    presses_with_rest(1.0)
}

/// As [`presses`], read by a `rows` x `cols` matrix (every reading 0 until the test sets them).
pub fn presses_on(rows: usize, cols: usize) -> Dataset {
    let mut ds = presses();
    ds.rows = rows;
    ds.cols = cols;
    ds.n = rows * cols;
    ds.y = vec![0.0; ds.len() * ds.n];
    ds
}

/// As [`presses`], with `rest_s` seconds of no load before each press.
pub fn presses_with_rest(rest_s: f64) -> Dataset {
    let mut t = Vec::new();
    let mut force = Vec::new();
    let mut now = 0.0;
    for p in 0..40 {
        let level = 2.0 + (p * 7 % 13) as f64;
        let ramp = 0.2 + 1.8 * ((p * 5 % 11) as f64 / 10.0);
        for (dur, from, to) in [
            (rest_s, 0.0, 0.0),
            (ramp, 0.0, level),
            (1.0, level, level),
            (ramp, level, 0.0),
        ] {
            let steps = (dur * 100.0) as usize;
            for s in 0..steps {
                t.push(now);
                force.push(from + (to - from) * s as f64 / steps as f64);
                now += 0.01;
            }
        }
    }
    let len = t.len();
    Dataset {
        path: "presses".into(),
        rows: 1,
        cols: 1,
        n: 1,
        t,
        force,
        kappa: None,
        temp: None,
        trial: vec![0; len],
        n_trials: 1,
        trial_recorded: false,
        y: vec![0.0; len],
        map: ReadoutMap::Resistance,
        stats: Default::default(),
    }
}

/// A held-out result whose residual is `resid` (one block, one node; the fits are placeholders).
pub fn cv_of(resid: Vec<f64>) -> crate::cv::Cv {
    let sse = resid.iter().map(|r| r * r).sum();
    crate::cv::Cv {
        count: resid.len(),
        block_sse: vec![sse],
        node_sse: vec![sse],
        rest_block_sse: vec![0.0],
        resid,
        sse,
        fits: [
            crate::effects::Config::base(1.0, 0.0),
            crate::effects::Config::base(1.0, 0.0),
        ],
        colour: std::sync::OnceLock::new(),
    }
}

/// Two nodes through a falling divider, three mountings (node 0's sensitivity 0.8x in
/// trial 1, node 1's 1.25x in trial 2), and a common drift of the conductance by
/// 0.75-1.25 over the recording.
pub fn drifting() -> crate::data::Dataset {
    let mut ds = crate::testdata::presses_on(1, 2);
    let len = ds.len();
    ds.trial = (0..len).map(|i| i * 3 / len).collect();
    ds.n_trials = 3;
    ds.trial_recorded = true;
    ds.map = crate::data::ReadoutMap::Divider {
        max: 4095.0,
        r_ref: 10_000.0,
        rises: false,
    };
    let dur = ds.duration();
    ds.y = (0..len * 2)
        .map(|idx| {
            let (i, k) = (idx / 2, idx % 2);
            let f = match (ds.trial[i], k) {
                (1, 0) => 0.8,
                (2, 1) => 1.25,
                _ => 1.0,
            };
            let m = 1.0 + 0.25 * (std::f64::consts::TAU * ds.t[i] / dur).sin();
            let g = m * (20e-6 + 40e-6 * (1.0 + k as f64) * f * ds.force[i]);
            ds.map.from_g(g)
        })
        .collect();
    ds
}

/// Asserts that `a` and `b` have the same length and agree element by element to `rel`,
/// relative to the larger of the two (and at least 1e-12): `what` names them in the message.
pub fn assert_close(a: &[f64], b: &[f64], rel: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!(
            (x - y).abs() <= rel * x.abs().max(y.abs()).max(1e-12),
            "{what}: {a:?} against {b:?}"
        );
    }
}
