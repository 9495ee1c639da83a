//! Device clock vs host clock: unwraps the device's 32-bit microsecond counter, and fits
//! `host = offset + (1 + drift) device` over a sliding window by least squares, giving the
//! offset, the drift (ppm) and the jitter (residual standard deviation) of arrivals.

use std::collections::VecDeque;

/// Points kept for the fit.
const WINDOW: usize = 2000;

#[derive(Debug, Clone, Default)]
pub struct ClockModel {
    last_raw: Option<u64>,
    wraps: u64,
    points: VecDeque<(f64, f64)>,
}

/// A fit of the device clock against the host clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockFit {
    /// Host time minus device time at the newest point (ms).
    pub offset_ms: f64,
    /// Device clock rate error relative to the host (ppm; positive: device runs slow).
    pub drift_ppm: f64,
    /// Standard deviation of arrival times around the fit (us).
    pub jitter_us: f64,
    pub points: usize,
}

impl ClockModel {
    /// Unwraps a device time that wraps at `wrap` (2^32 for the binary format).
    pub fn unwrap(&mut self, raw_us: u64, wrap: u64) -> u64 {
        if let Some(last) = self.last_raw {
            if raw_us + wrap / 2 < last {
                self.wraps += 1;
            }
        }
        self.last_raw = Some(raw_us);
        raw_us + self.wraps * wrap
    }

    /// Adds a (device us, host ns) pair.
    pub fn add(&mut self, device_us: u64, host_ns: u64) {
        if self.points.len() == WINDOW {
            self.points.pop_front();
        }
        self.points
            .push_back((device_us as f64, host_ns as f64 / 1000.0));
    }

    /// Forgets everything (device restarted or reconnected).
    pub fn reset(&mut self) {
        *self = ClockModel::default();
    }

    pub fn fit(&self) -> Option<ClockFit> {
        let n = self.points.len();
        if n < 10 {
            return None;
        }
        let (x0, y0) = self.points[0];
        let (mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0);
        for &(x, y) in &self.points {
            let (x, y) = (x - x0, y - y0);
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
        }
        let nf = n as f64;
        let den = nf * sxx - sx * sx;
        if den.abs() < 1e-9 {
            return None;
        }
        let slope = (nf * sxy - sx * sy) / den;
        let icpt = (sy - slope * sx) / nf;
        let mut ss = 0.0;
        for &(x, y) in &self.points {
            let r = (y - y0) - (icpt + slope * (x - x0));
            ss += r * r;
        }
        let (xl, _) = self.points[n - 1];
        let offset_us = y0 + icpt + slope * (xl - x0) - xl;
        Some(ClockFit {
            offset_ms: offset_us / 1000.0,
            drift_ppm: (slope - 1.0) * 1e6,
            jitter_us: (ss / nf).sqrt(),
            points: n,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unwraps_and_fits_drift_and_jitter() {
        let mut m = ClockModel::default();
        let wrap = 1u64 << 32;
        let mut raw = wrap - 5_000_000; // wraps after 5 s
        for i in 0..1000u64 {
            let dev = m.unwrap(raw % wrap, wrap);
            // host runs 100 ppm fast relative to device, offset 2 s, jitter +-50 us
            let jitter = if i % 2 == 0 { 50.0 } else { -50.0 };
            let host_us = 2_000_000.0 + (dev as f64 - (wrap - 5_000_000) as f64) * 1.0001 + jitter;
            m.add(dev, (host_us * 1000.0) as u64);
            raw += 10_000;
        }
        let f = m.fit().expect("fit");
        assert!((f.drift_ppm - 100.0).abs() < 1.0, "{f:?}");
        assert!((f.jitter_us - 50.0).abs() < 2.0, "{f:?}");
    }
}
