//! taxel-calibrator owns force calibration: the calibration file format and its validation
//! (`calibration`), the model forms it can hold (`forms`), fitting calibrations from recordings
//! (`fit`), hot reload of the files while the stream runs (`reload`), the dynamic terms and
//! their state (`dynamics`), the figures of a fit (`plots`), and the calibrator process that
//! turns raw frames plus the latest curvature estimate into `ForceSample`s, for one sensor or
//! many (`run`; each sensor's state in `lane`). The offline evaluation that runs it beside the
//! estimator lives in taxel-evaluation.

pub mod calibration;
pub mod cli;
pub mod dynamics;
pub mod fit;
pub mod forms;
pub mod lane;
pub mod plots;
pub mod reload;
pub mod run;

/// Nodes of the central 2 x 2 block (the paper's indenter), or of the whole array when it is
/// smaller, row-major.
pub fn central_block(rows: usize, cols: usize) -> Vec<usize> {
    let span = |n: usize| -> Vec<usize> {
        if n <= 2 {
            (0..n).collect()
        } else {
            vec![n / 2 - 1, n / 2]
        }
    };
    let mut out = Vec::new();
    for r in span(rows) {
        for c in span(cols) {
            out.push(r * cols + c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn central_blocks() {
        assert_eq!(super::central_block(4, 4), vec![5, 6, 9, 10]);
        assert_eq!(super::central_block(1, 1), vec![0]);
        assert_eq!(super::central_block(3, 5), vec![1, 2, 6, 7]);
    }
}
