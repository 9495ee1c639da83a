//! taxel-evaluation owns the offline evaluation: the paper's protocol on an object recording
//! (`protocol`: every frame through the live estimator's and calibrator's code, error per force
//! level, flat vs curvature-aware, and the hold drift of `holds`), its figures (`plots`), the
//! reproduction of the paper's Table I on the simulator (`table1`), and the generalisation and
//! dynamic-calibration checks on every simulator family, world B and the real recordings
//! (`worlds`). It is a library, not a process: it links the estimator and the calibrator so
//! that neither links the other. Its commands are `taxel calibrator eval` (`eval`) and
//! `taxel evaluate` (`cli`).

pub mod cli;
pub mod eval;
pub mod holds;
pub mod plots;
pub mod protocol;
pub mod table1;
pub mod worlds;
