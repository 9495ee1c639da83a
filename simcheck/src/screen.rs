//! Screening a candidate before its full held-out test. Most candidates a diagnosis tests are
//! rejected, most of them far from the bar (an effect the recording does not have removes
//! nothing). Each variant is first held out in a view of the recording whose parameter search
//! looks at every [`FACTOR`]-th sample of the usual grid and runs the effects' states on a
//! grid as much sparser (about a quarter of the cost); its held-out predictions still cover every
//! sample, so the screen's verdict is measured against the current model exactly as the full
//! test's is. The full test's search on each fold starts from the screen's fit on that fold's
//! training half, with half the budget. Only a variant that removes less than [`MIN_GAIN`] of the held-out SSE there
//! (half the acceptance rule's least gain) stops at the screen; every other one gets the full
//! test, and only a full test can accept.

use crate::cv::{Verdict, MIN_REL_GAIN};

/// How much sparser the screening view's search grid is.
pub const FACTOR: usize = 4;

/// Least share of the held-out SSE a variant must remove in the screen to get the full test.
pub const MIN_GAIN: f64 = 0.5 * MIN_REL_GAIN;

/// The search budget of the full test, whose folds start from the screen's fits on the same
/// training halves: half the screen's.
pub fn full_evals(screen_evals: usize) -> usize {
    screen_evals.div_ceil(2)
}

/// Whether the screen's verdict leaves the variant worth the full held-out test.
pub fn worth_full_test(v: &Verdict) -> bool {
    v.rel_gain >= MIN_GAIN
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_variant_that_removes_next_to_nothing_stops_at_the_screen() {
        let v = |gain: f64| Verdict {
            rmse_before: 1.0,
            rmse_after: (1.0 - gain).sqrt(),
            rel_gain: gain,
            n_eff: 100.0,
            ic_gain: -1.0,
            ..Verdict::default()
        };
        assert!(!worth_full_test(&v(-0.02)));
        assert!(!worth_full_test(&v(0.002)));
        // A variant short of the acceptance rule's gain by less than half still gets the test.
        assert!(worth_full_test(&v(0.006)));
        assert!(worth_full_test(&v(0.3)));
    }
}
