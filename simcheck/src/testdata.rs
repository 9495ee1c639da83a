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
