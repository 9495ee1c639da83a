//! Statistics every consumer keeps: a counter of frames lost from gaps in the per-sensor
//! sequence number (the sample-age histogram is `taxel_consumers::age`).

/// Counts frames lost from jumps in a per-sensor sequence number.
#[derive(Debug, Clone, Default)]
pub struct SeqTracker {
    last: Option<u64>,
    /// Frames missing between received ones.
    pub dropped: u64,
    /// Frames received.
    pub received: u64,
    /// Times the sequence started over (a restarted source counts from 0 again).
    pub restarts: u64,
}

impl SeqTracker {
    /// Records `seq`; returns how many frames were skipped before it. A sequence number at or
    /// below the last one is a restarted source: counting starts over from it.
    pub fn observe(&mut self, seq: u64) -> u64 {
        self.received += 1;
        let gap = match self.last {
            Some(l) if seq > l + 1 => seq - l - 1,
            _ => 0,
        };
        self.dropped += gap;
        if self.last.is_some_and(|l| seq <= l) {
            self.restarts += 1;
        }
        self.last = Some(seq);
        gap
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_are_counted() {
        let mut t = SeqTracker::default();
        for s in [5, 6, 7, 10, 11, 15] {
            t.observe(s);
        }
        assert_eq!((t.received, t.dropped), (6, 5));
    }

    #[test]
    fn a_restarted_source_starts_the_count_over() {
        let mut t = SeqTracker::default();
        for s in [100, 101, 0, 1, 3] {
            t.observe(s);
        }
        assert_eq!((t.received, t.dropped, t.restarts), (5, 1, 1));
    }
}
