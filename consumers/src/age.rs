//! Sample-age statistics: an HdrHistogram of `now - t_capture_ns` (recording never allocates)
//! and the JSON report of the latency probe.

use hdrhistogram::Histogram;

/// Ages in nanoseconds, 3 significant digits, up to 100 s.
pub struct AgeHistogram {
    h: Histogram<u64>,
}

impl Default for AgeHistogram {
    fn default() -> Self {
        AgeHistogram::new()
    }
}

impl AgeHistogram {
    pub fn new() -> AgeHistogram {
        let h = Histogram::new_with_bounds(1, 100_000_000_000, 3)
            .expect("constant histogram bounds are valid");
        AgeHistogram { h }
    }

    pub fn record_ns(&mut self, age_ns: u64) {
        self.h.saturating_record(age_ns.max(1));
    }

    pub fn len(&self) -> u64 {
        self.h.len()
    }

    pub fn is_empty(&self) -> bool {
        self.h.is_empty()
    }

    /// Percentile `q` (0..=100) in microseconds.
    pub fn percentile_us(&self, q: f64) -> f64 {
        if self.h.is_empty() {
            return 0.0;
        }
        self.h.value_at_quantile(q / 100.0) as f64 / 1000.0
    }

    pub fn max_us(&self) -> f64 {
        self.h.max() as f64 / 1000.0
    }

    pub fn reset(&mut self) {
        self.h.reset();
    }
}

/// The latency probe's JSON object (the documented contract, plus extra fields).
pub fn json_report(received: u64, dropped: u64, h: &AgeHistogram, extra: &[(&str, f64)]) -> String {
    let mut s = format!(
        "{{\"received\": {received}, \"dropped\": {dropped}, \"p50_us\": {:.1}, \"p90_us\": {:.1}, \"p99_us\": {:.1}, \"p999_us\": {:.1}, \"max_us\": {:.1}",
        h.percentile_us(50.0),
        h.percentile_us(90.0),
        h.percentile_us(99.0),
        h.percentile_us(99.9),
        h.max_us()
    );
    for (k, v) in extra {
        s.push_str(&format!(", \"{k}\": {v}"));
    }
    s.push('}');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_and_json() {
        let mut h = AgeHistogram::new();
        for us in 1..=1000u64 {
            h.record_ns(us * 1000);
        }
        assert!((h.percentile_us(50.0) - 500.0).abs() < 1.0);
        assert!((h.percentile_us(99.0) - 990.0).abs() < 2.0);
        let j = json_report(1000, 2, &h, &[]);
        assert!(
            j.starts_with("{\"received\": 1000, \"dropped\": 2, \"p50_us\": "),
            "{j}"
        );
        assert!(j.ends_with('}'));
        for key in ["p90_us", "p99_us", "p999_us", "max_us"] {
            assert!(j.contains(key));
        }
    }
}
