//! The adaptive waiter's model of a periodic stream, free of system calls so it can be tested
//! with made-up clocks. It learns three distributions from recent samples and plans each
//! wake-up from their quantiles:
//! - the capture grid, indexed by the samples' sequence numbers: period and phase fitted
//!   robustly (the median of many 16-sample slopes, a low quantile of recent residuals as
//!   the phase), so one late capture does not shift the prediction of the next, as it would if the
//!   next sample were predicted from the last;
//! - the hop: capture-to-arrival delay of samples that arrived while we were polling (the only
//!   ones whose arrival time we saw);
//! - our own sleep overshoot (how late `nanosleep` returns; about 30 us on a VM, with a tail).
//!
//! The plan asks to wake early enough that a high quantile of the overshoot still lands before
//! the earliest expected arrival. How long polling may go on is not planned here but bounded by a
//! token bucket in the caller: polling spends tokens, time refills them at a fixed share of a
//! core, so a late sample is waited for while the budget lasts and the long-run CPU stays bounded.

/// Samples kept per distribution.
const N: usize = 128;
/// Refit the grid after this many new captures.
const REFIT_EVERY: u32 = 16;
/// Captures needed before a plan is made.
const MIN_CAPTURES: usize = 12;
/// Quantile of the capture residuals taken as the grid's phase (captures are rarely early).
const PHASE_Q: f64 = 0.05;
/// Quantile of the hop taken as the earliest arrival.
const HOP_Q: f64 = 0.05;
/// Quantile of our sleep overshoot the wake-up must survive.
const OVER_Q: f64 = 0.99;
/// Extra margin before the earliest arrival (ns).
const GUARD_NS: f64 = 2_000.0;
/// Quantile of the capture residuals that, less the phase, is the stream's spread: most
/// samples, so a host stall that delays a few does not make a regular stream look irregular.
const SPREAD_Q: f64 = 0.75;
/// A stream whose capture residuals spread wider than this share of the period has no rhythm
/// worth polling for.
const MAX_SPREAD: f64 = 0.3;
/// Samples between the two ends of each slope the period is the median of.
const SLOPE_SPAN: usize = 16;
/// Captures the phase is fitted to (the newest).
const PHASE_WINDOW: usize = 48;
/// A gap longer than this many periods (or a capture going backwards) restarts learning.
const RESET_PERIODS: f64 = 200.0;

/// The last `N` values of one quantity.
#[derive(Debug, Clone)]
struct Ring {
    v: [f64; N],
    len: usize,
    next: usize,
}

impl Ring {
    fn new() -> Ring {
        Ring {
            v: [0.0; N],
            len: 0,
            next: 0,
        }
    }

    fn push(&mut self, x: f64) {
        self.v[self.next] = x;
        self.next = (self.next + 1) % N;
        self.len = (self.len + 1).min(N);
    }

    /// The `q` quantile (nearest rank) of the values held, or None when empty. Sorts a copy on
    /// the stack: no allocation.
    fn quantile(&self, q: f64) -> Option<f64> {
        if self.len == 0 {
            return None;
        }
        let mut s = [0.0f64; N];
        s[..self.len].copy_from_slice(&self.v[..self.len]);
        let s = &mut s[..self.len];
        s.sort_unstable_by(f64::total_cmp);
        let i = ((q * (self.len - 1) as f64).round() as usize).min(self.len - 1);
        Some(s[i])
    }
}

/// Median of `v` (sorted in place); None when empty.
fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_unstable_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// When the next sample is due and how early to wake for it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plan {
    /// The earliest expected arrival (ns, CLOCK_MONOTONIC).
    pub arrival_ns: u64,
    /// Wake this long before it for a high quantile of our sleeps to end in time (ns).
    pub lead_ns: u64,
    /// How late a sleep usually ends (the median overshoot, ns): waking `lead_ns` early costs
    /// about `lead_ns - usual_overshoot_ns` of polling.
    pub usual_overshoot_ns: u64,
}

/// What the model has learned, in microseconds, for reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Learned {
    pub period_us: f64,
    /// Spread of captures around the grid (75th minus 5th percentile).
    pub capture_spread_us: f64,
    /// Earliest (5th percentile) capture-to-arrival delay.
    pub hop_us: f64,
    /// The sleep overshoot the plan allows for (99th percentile).
    pub overshoot_us: f64,
}

/// The model; see the module documentation.
#[derive(Debug, Clone)]
pub struct Rhythm {
    /// Recent captures: sequence number and time (ns), relative to `base_seq` and `base`.
    cap: [(i64, f64); N],
    cap_len: usize,
    cap_next: usize,
    base: u64,
    base_seq: u64,
    /// The newest sample: sequence number and capture time.
    last: Option<(u64, u64)>,
    period: f64,
    /// Grid: index `anchor_k` falls at `base + anchor_t`.
    anchor_k: i64,
    anchor_t: f64,
    spread: f64,
    since_fit: u32,
    hop: Ring,
    over: Ring,
    hop_lo: f64,
    over_hi: f64,
    over_mid: f64,
}

impl Default for Rhythm {
    fn default() -> Rhythm {
        Rhythm::new()
    }
}

impl Rhythm {
    pub fn new() -> Rhythm {
        Rhythm {
            cap: [(0, 0.0); N],
            cap_len: 0,
            cap_next: 0,
            base: 0,
            base_seq: 0,
            last: None,
            period: 0.0,
            anchor_k: 0,
            anchor_t: 0.0,
            spread: f64::INFINITY,
            since_fit: 0,
            hop: Ring::new(),
            over: Ring::new(),
            // Until measured: a fast transport and a VM-sized overshoot.
            hop_lo: 1_000.0,
            over_hi: 60_000.0,
            over_mid: 30_000.0,
        }
    }

    fn reset_grid(&mut self) {
        self.cap_len = 0;
        self.cap_next = 0;
        self.last = None;
        self.period = 0.0;
        self.spread = f64::INFINITY;
        self.since_fit = 0;
    }

    /// Sample `seq` (the publisher's sequence number, one per period) captured at `capture`
    /// (ns) was received.
    pub fn captured(&mut self, seq: u64, capture: u64) {
        if let Some((last_seq, c)) = self.last {
            let back = seq <= last_seq || capture <= c;
            let gap = capture.saturating_sub(c) as f64;
            if back || (self.period > 0.0 && gap > RESET_PERIODS * self.period) {
                // A restarted publisher (sequence or clock went back) or a long pause.
                self.reset_grid();
            }
        }
        if self.last.is_none() {
            self.base = capture;
            self.base_seq = seq;
        }
        // Both differences are non-negative: the grid restarted on anything going back.
        let k = (seq - self.base_seq).min(i64::MAX as u64) as i64;
        self.cap[self.cap_next] = (k, (capture - self.base) as f64);
        self.cap_next = (self.cap_next + 1) % N;
        self.cap_len = (self.cap_len + 1).min(N);
        self.last = Some((seq, capture));
        self.since_fit += 1;
        if self.cap_len >= MIN_CAPTURES
            && (self.since_fit >= REFIT_EVERY || self.period == 0.0 || self.cap_len < N / 2)
        {
            self.fit();
        }
    }

    /// Captures held, oldest first.
    fn captures(&self) -> impl Iterator<Item = (i64, f64)> + '_ {
        let start = if self.cap_len < N { 0 } else { self.cap_next };
        (0..self.cap_len).map(move |i| self.cap[(start + i) % N])
    }

    /// Fits the period to all captures held (the median of slopes across `SLOPE_SPAN`
    /// samples: each slope's jitter is divided by the span, and a phase jump spoils only the
    /// few slopes that straddle it) and the phase to the newest
    /// `PHASE_WINDOW` (a low quantile of the residuals: captures come late, not early), so a
    /// publisher that re-anchors its schedule is followed within that many samples.
    fn fit(&mut self) {
        self.since_fit = 0;
        let n = self.cap_len;
        let mut pts = [(0i64, 0.0f64); N];
        for (slot, p) in pts.iter_mut().zip(self.captures()) {
            *slot = p;
        }
        let pts = &pts[..n];
        let mut buf = [0.0f64; N];
        let span = (n / 2).clamp(1, SLOPE_SPAN);
        let mut m = 0;
        for i in 0..n - span {
            let dk = (pts[i + span].0 - pts[i].0) as f64;
            if dk >= 1.0 {
                buf[m] = (pts[i + span].1 - pts[i].1) / dk;
                m += 1;
            }
        }
        let Some(period) = median(&mut buf[..m]) else {
            return;
        };
        if !(period.is_finite() && period > 0.0) {
            return;
        }
        let recent = &pts[n.saturating_sub(PHASE_WINDOW)..];
        let (k0, t0) = recent[0];
        for (b, &(k, t)) in buf.iter_mut().zip(recent) {
            *b = t - t0 - period * (k - k0) as f64;
        }
        let r = &mut buf[..recent.len()];
        r.sort_unstable_by(f64::total_cmp);
        let at = |q: f64| r[((q * (r.len() - 1) as f64).round() as usize).min(r.len() - 1)];
        let (lo, hi) = (at(PHASE_Q), at(SPREAD_Q));
        self.period = period;
        self.anchor_k = k0;
        self.anchor_t = t0 + lo;
        self.spread = hi - lo;
    }

    /// A sample arrived `hop` ns after its capture while we were polling.
    pub fn hop(&mut self, hop: u64) {
        self.hop.push((hop as f64).min(1e7));
        if let Some(q) = self.hop.quantile(HOP_Q) {
            self.hop_lo = q;
        }
    }

    /// A sleep ended `over` ns after its target.
    pub fn slept(&mut self, over: u64) {
        self.over.push((over as f64).min(1e7));
        if let (Some(hi), Some(mid)) = (self.over.quantile(OVER_Q), self.over.quantile(0.5)) {
            self.over_hi = hi;
            self.over_mid = mid;
        }
    }

    /// The stream's period (ns) once known.
    pub fn period_ns(&self) -> Option<f64> {
        (self.period > 0.0).then_some(self.period)
    }

    /// When to wake for the sample after the last one seen, or None while the stream's rhythm
    /// is unknown or too irregular to poll for.
    pub fn plan(&self) -> Option<Plan> {
        let (seq, _) = self.last?;
        if self.period <= 0.0 || self.spread > MAX_SPREAD * self.period {
            return None;
        }
        let next = (seq - self.base_seq).min(i64::MAX as u64 - 1) as i64 + 1;
        let grid = self.base as f64 + self.anchor_t + self.period * (next - self.anchor_k) as f64;
        let arrival = grid + self.hop_lo;
        Some(Plan {
            arrival_ns: arrival.max(0.0) as u64,
            lead_ns: (self.over_hi + GUARD_NS) as u64,
            usual_overshoot_ns: self.over_mid as u64,
        })
    }

    pub fn learned(&self) -> Learned {
        Learned {
            period_us: self.period / 1e3,
            capture_spread_us: if self.spread.is_finite() {
                self.spread / 1e3
            } else {
                0.0
            },
            hop_us: self.hop_lo / 1e3,
            overshoot_us: self.over_hi / 1e3,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny deterministic generator (xorshift) for jitter.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Captures on a 1 ms grid, late by 25-35 us, with one in 50 late by 300 us.
    fn late_capture(r: &mut Rng, k: u64) -> u64 {
        let mut late = 25_000.0 + 10_000.0 * r.next();
        if r.next() < 0.02 {
            late += 300_000.0;
        }
        5_000_000_000 + k * 1_000_000 + late as u64
    }

    #[test]
    fn quantiles_of_a_ring() {
        let mut r = Ring::new();
        assert_eq!(r.quantile(0.5), None);
        for i in 0..300 {
            r.push(i as f64);
        }
        // Only the last 128 (172..=299) are held.
        assert_eq!(r.quantile(0.0), Some(172.0));
        assert_eq!(r.quantile(1.0), Some(299.0));
        assert_eq!(r.quantile(0.5), Some(236.0));
    }

    #[test]
    fn a_late_capture_does_not_move_the_next_plan() {
        let mut r = Rng(7);
        let mut m = Rhythm::new();
        assert_eq!(m.plan(), None);
        for k in 0..200 {
            m.captured(k, late_capture(&mut r, k));
        }
        let p = m.period_ns().expect("period learned");
        assert!((p - 1e6).abs() < 500.0, "period {p}");
        // The next grid point is 5 s + 200 ms; the phase is the low edge of the lateness.
        let planned = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        let grid = 5_000_000_000.0 + 200.0 * 1e6;
        assert!(
            (planned - grid - 25_000.0).abs() < 3_000.0,
            "planned {planned}, grid {grid}"
        );
        // A capture 300 us late does not shift the following plan.
        m.captured(200, 5_000_000_000 + 200 * 1_000_000 + 330_000);
        let after = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        assert!(
            (after - planned - 1e6).abs() < 3_000.0,
            "after {after}, planned {planned}"
        );
    }

    #[test]
    fn a_very_late_capture_does_not_shift_the_grid() {
        let mut r = Rng(13);
        let mut m = Rhythm::new();
        for k in 0..200 {
            m.captured(k, late_capture(&mut r, k));
        }
        // 650 us late, then on time again: the plan after it is for the next grid point.
        m.captured(200, 5_000_000_000 + 200 * 1_000_000 + 650_000);
        m.captured(201, 5_000_000_000 + 201 * 1_000_000 + 30_000);
        let planned = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        let grid = 5_000_000_000.0 + 202.0 * 1e6 + 25_000.0;
        assert!(
            (planned - grid).abs() < 3_000.0,
            "planned {planned}, grid {grid}"
        );
    }

    #[test]
    fn a_re_anchored_schedule_is_followed() {
        let mut r = Rng(17);
        let mut m = Rhythm::new();
        for k in 0..200 {
            m.captured(k, late_capture(&mut r, k));
        }
        // The publisher fell behind and re-anchored its schedule 400 us later; the sequence
        // goes on.
        for k in 200..260 {
            m.captured(k, late_capture(&mut r, k) + 400_000);
        }
        let planned = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        let grid = 5_000_000_000.0 + 260.0 * 1e6 + 425_000.0;
        assert!(
            (planned - grid).abs() < 3_000.0,
            "planned {planned}, grid {grid}"
        );
    }

    #[test]
    fn a_stall_does_not_stop_the_plans() {
        let mut r = Rng(19);
        let mut m = Rhythm::new();
        for k in 0..200 {
            m.captured(k, late_capture(&mut r, k));
        }
        // The host stalls the publisher for 3.3 ms: four frames go out late, back to back.
        for (k, at) in [
            (200u64, 203_300_000u64),
            (201, 203_310_000),
            (202, 203_320_000),
            (203, 203_330_000),
        ] {
            m.captured(k, 5_000_000_000 + at);
        }
        for k in 204..220 {
            m.captured(k, late_capture(&mut r, k));
        }
        assert!(m.plan().is_some(), "{:?}", m.learned());
    }

    #[test]
    fn a_clock_or_sequence_going_back_restarts_learning() {
        let mut r = Rng(23);
        let mut m = Rhythm::new();
        for k in 0..100 {
            m.captured(k, late_capture(&mut r, k));
        }
        assert!(m.plan().is_some());
        // A capture time from before the last one (another publisher's clock), then a sequence
        // number from near the top of the range: neither panics, both restart the grid.
        m.captured(100, 1_000);
        assert_eq!(m.plan(), None);
        m.captured(u64::MAX - 5, 2_000);
        m.captured(3, 3_000);
        assert_eq!(m.plan(), None);
        for k in 4..40u64 {
            m.captured(k, 3_000 + (k - 3) * 1_000_000);
        }
        let p = m.period_ns().expect("relearned");
        assert!((p - 1e6).abs() < 1.0, "period {p}");
    }

    #[test]
    fn dropped_samples_keep_the_grid() {
        let mut r = Rng(3);
        let mut m = Rhythm::new();
        for k in (0..400).filter(|k| k % 7 != 3 && !(100..110).contains(k)) {
            m.captured(k, late_capture(&mut r, k));
        }
        let p = m.period_ns().expect("period learned");
        assert!((p - 1e6).abs() < 500.0, "period {p}");
        let planned = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        let grid = 5_000_000_000.0 + 400.0 * 1e6 + 25_000.0;
        assert!(
            (planned - grid).abs() < 3_000.0,
            "planned {planned}, grid {grid}"
        );
    }

    #[test]
    fn the_wake_up_allows_for_a_high_quantile_of_the_overshoot() {
        let mut r = Rng(11);
        let mut m = Rhythm::new();
        for k in 0..100 {
            m.captured(k, late_capture(&mut r, k));
            m.hop(1_500 + (r.next() * 1_000.0) as u64);
            m.slept(30_000 + (r.next() * 40_000.0) as u64);
        }
        let plan = m.plan().expect("a plan");
        let lead = plan.lead_ns as f64;
        // 99th percentile of U(30, 70) us is ~69.6 us, plus the guard; the median is ~50 us.
        assert!((lead - 71_600.0).abs() < 2_500.0, "lead {lead}");
        let mid = plan.usual_overshoot_ns as f64;
        assert!((mid - 50_000.0).abs() < 5_000.0, "median {mid}");
        let l = m.learned();
        assert!((l.hop_us - 1.55).abs() < 0.2, "{l:?}");
    }

    #[test]
    fn no_rhythm_no_plan() {
        let mut r = Rng(5);
        let mut m = Rhythm::new();
        let mut t = 1_000_000_000u64;
        for k in 0..200 {
            t += 200_000 + (r.next() * 1_800_000.0) as u64;
            m.captured(k, t);
        }
        assert_eq!(m.plan(), None, "{:?}", m.learned());
    }

    #[test]
    fn a_restarted_stream_is_relearned() {
        let mut r = Rng(9);
        let mut m = Rhythm::new();
        for k in 0..200 {
            m.captured(k, late_capture(&mut r, k));
        }
        // The publisher restarts at once (its sequence starts again) on a 500 us grid with
        // another phase.
        for k in 0..200u64 {
            m.captured(k, 5_000_000_000 + 200_500_000 + k * 500_000 + 123_000);
        }
        let p = m.period_ns().expect("period learned");
        assert!((p - 5e5).abs() < 100.0, "period {p}");
        let planned = m.plan().expect("a plan").arrival_ns as f64 - m.hop_lo;
        let grid = 5_200_500_000.0 + 200.0 * 5e5 + 123_000.0;
        assert!((planned - grid).abs() < 1_000.0, "planned {planned}");
    }
}
