//! Hot reload of the curvature model file. The estimator loop polls the file's metadata about
//! every 100 ms (editing in place and atomic replacement by rename are both seen), waits until
//! it has stopped changing, then loads and fully validates the new model (format, version,
//! checksum, node count) before handing it over. A truncated, garbage, other-version or
//! wrong-geometry file, or a deleted one, is reported once per change and the loaded model keeps
//! serving; a later good file is picked up.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use taxel_runtime::filewatch::FileSignature;
use tracing::{error, info};

use crate::model::CurvatureModel;

/// How long a changed file must stay unchanged before it is read.
pub const SETTLE: Duration = Duration::from_millis(50);

fn signature(path: &Path) -> Option<FileSignature> {
    FileSignature::of(path)
}

/// Watches one model file.
pub struct ModelWatch {
    path: PathBuf,
    last: Option<FileSignature>,
    pending: Option<(Option<FileSignature>, Instant)>,
    /// Loads that succeeded after the first (the generation of the serving model - 1).
    pub reloads: u32,
}

impl ModelWatch {
    /// Starts watching `path`, whose current content is the model already loaded.
    pub fn new(path: PathBuf) -> ModelWatch {
        let last = signature(&path);
        ModelWatch {
            path,
            last,
            pending: None,
            reloads: 0,
        }
    }

    /// Checks the file; returns a new, valid model when one has arrived. `n_nodes` is the
    /// sensor's node count once known (a model for another geometry is refused).
    pub fn poll(&mut self, n_nodes: Option<usize>) -> Option<CurvatureModel> {
        let sig = signature(&self.path);
        if sig == self.last {
            self.pending = None;
            return None;
        }
        match self.pending {
            Some((s, since)) if s == sig && since.elapsed() >= SETTLE => {}
            Some((s, _)) if s == sig => return None,
            _ => {
                self.pending = Some((sig, Instant::now()));
                return None;
            }
        }
        self.pending = None;
        self.last = sig;
        let shown = self.path.display();
        if sig.is_none() {
            error!("curvature model {shown} was deleted; the loaded model keeps serving");
            return None;
        }
        let loaded = CurvatureModel::load(&self.path).and_then(|m| {
            if let Some(n) = n_nodes {
                m.check_nodes(&shown.to_string(), n)?;
            }
            Ok(m)
        });
        match loaded {
            Ok(m) => {
                self.reloads += 1;
                info!(
                    model = %shown,
                    kind = %m.kind,
                    version = format!("{:08x}", m.model_version),
                    generation = self.reloads + 1,
                    "curvature model reloaded"
                );
                Some(m)
            }
            Err(e) => {
                error!("curvature model refused, the loaded model keeps serving: {e}");
                None
            }
        }
    }
}
