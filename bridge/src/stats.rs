//! Per-stream statistics of what the bridge moves: samples, frames lost (gaps in `seq`),
//! samples out of order (`seq` not above the last one), and the age `now - t_capture_ns` when
//! it is meaningful. Every taxel payload starts with `seq` and `t_capture_ns`.
//!
//! Ages compare CLOCK_MONOTONIC of the capturing host with this host's: they are true ages only
//! when both are one machine (loopback, two domains on one host). Across hosts the two clocks
//! count from different boots; an age below zero or above [`AGE_PLAUSIBLE_NS`] is then not
//! recorded but counted as `foreign_clock`, and the report says so.

use hdrhistogram::Histogram;

/// Ages above this (60 s) are taken for a clock of another host.
pub const AGE_PLAUSIBLE_NS: u64 = 60_000_000_000;

/// Which way a stream's samples crossed, seen from this bridge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Published in this domain, sent to the peers.
    Out,
    /// Received from a peer, published into this domain.
    In,
}

impl Direction {
    pub fn label(self) -> &'static str {
        match self {
            Direction::Out => "out",
            Direction::In => "in",
        }
    }
}

/// Counts of one stream in one direction.
#[derive(Debug, Clone)]
pub struct StreamStats {
    last_seq: Option<u64>,
    pub samples: u64,
    pub lost: u64,
    pub out_of_order: u64,
    pub foreign_clock: u64,
    ages: Histogram<u64>,
}

impl Default for StreamStats {
    fn default() -> Self {
        StreamStats::new()
    }
}

impl StreamStats {
    pub fn new() -> StreamStats {
        // 1 ns .. 60 s at 3 significant digits: a fixed-size histogram, recording never allocates.
        let ages = Histogram::new_with_bounds(1, AGE_PLAUSIBLE_NS, 3)
            .expect("constant histogram bounds are valid");
        StreamStats {
            last_seq: None,
            samples: 0,
            lost: 0,
            out_of_order: 0,
            foreign_clock: 0,
            ages,
        }
    }

    /// Records one sample.
    pub fn observe(&mut self, seq: u64, t_capture_ns: u64, now_ns: u64) {
        self.samples += 1;
        match self.last_seq {
            Some(last) if seq > last + 1 => self.lost += seq - last - 1,
            Some(last) if seq <= last => self.out_of_order += 1,
            _ => {}
        }
        self.last_seq = Some(self.last_seq.map_or(seq, |l| l.max(seq)));
        match now_ns.checked_sub(t_capture_ns) {
            Some(age) if age <= AGE_PLAUSIBLE_NS => {
                self.ages.saturating_record(age.max(1));
            }
            _ => self.foreign_clock += 1,
        }
    }

    /// Adds another interval's counts (the sequence state stays this one's).
    pub fn merge(&mut self, other: &StreamStats) {
        self.samples += other.samples;
        self.lost += other.lost;
        self.out_of_order += other.out_of_order;
        self.foreign_clock += other.foreign_clock;
        let _ = self.ages.add(&other.ages);
    }

    /// Clears the counts, keeping the last sequence number (for per-interval reports).
    pub fn reset_counts(&mut self) {
        self.samples = 0;
        self.lost = 0;
        self.out_of_order = 0;
        self.foreign_clock = 0;
        self.ages.reset();
    }

    /// Age percentile `q` (0..=100) in microseconds; None without ages.
    pub fn age_us(&self, q: f64) -> Option<f64> {
        (!self.ages.is_empty()).then(|| self.ages.value_at_quantile(q / 100.0) as f64 / 1000.0)
    }

    pub fn age_max_us(&self) -> Option<f64> {
        (!self.ages.is_empty()).then(|| self.ages.max() as f64 / 1000.0)
    }

    /// One line: `samples 1000, lost 0, out of order 0, age p50 412 us p99 1203 us max 3101 us`.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "samples {}, lost {}, out of order {}",
            self.samples, self.lost, self.out_of_order
        );
        match (self.age_us(50.0), self.age_us(99.0), self.age_max_us()) {
            (Some(p50), Some(p99), Some(max)) => {
                s.push_str(&format!(
                    ", age p50 {p50:.0} us p99 {p99:.0} us max {max:.0} us"
                ));
            }
            _ if self.foreign_clock > 0 => {
                s.push_str(", age n/a (capture clock of another host)");
            }
            _ => {}
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_reorders_and_ages() {
        let mut s = StreamStats::new();
        let t0 = 1_000_000_000;
        for (seq, age_us) in [(1, 100), (2, 200), (5, 300), (4, 400), (6, 500)] {
            s.observe(seq, t0, t0 + age_us * 1000);
        }
        assert_eq!((s.samples, s.lost, s.out_of_order), (5, 2, 1));
        let p50 = s.age_us(50.0).expect("ages");
        assert!((p50 - 300.0).abs() < 1.0, "{p50}");
        assert!(s.summary().contains("lost 2, out of order 1"));
    }

    #[test]
    fn another_hosts_clock_is_not_an_age() {
        let mut s = StreamStats::new();
        s.observe(1, 5_000, 1_000);
        s.observe(2, 0, AGE_PLAUSIBLE_NS + 1);
        assert_eq!(s.foreign_clock, 2);
        assert!(s.age_us(50.0).is_none());
        assert!(s.summary().contains("another host"));
    }
}
