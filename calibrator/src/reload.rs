//! Hot reload of the calibration file: a watcher thread polls the file's metadata every 20 ms
//! (so editing in place and atomic replacement by rename are both seen), waits until the file
//! stops changing, then parses and validates it off the hot path and hands the new model over a
//! channel. The hot loop only does a non-blocking `try_recv` per sample. A file that fails to
//! load is reported once per change and the previous model keeps serving.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use taxel_runtime::filewatch::FileSignature;
use tracing::{error, info, warn};

use crate::calibration::Calibration;

/// Poll period of the watcher.
pub const POLL: Duration = Duration::from_millis(20);

/// A calibration as loaded by the watcher.
#[derive(Debug)]
pub struct Loaded {
    pub calibration: Calibration,
    /// 1 for the first successful load, +1 for each reload.
    pub generation: u32,
}

fn signature(path: &Path) -> Option<FileSignature> {
    FileSignature::of(path)
}

/// Loads a calibration and checks it fits an array of `rows x cols`.
pub fn load_for(path: &Path, rows: usize, cols: usize) -> Result<Calibration, String> {
    let cal = Calibration::load(path).map_err(|e| e.to_string())?;
    if (cal.rows, cal.cols) != (rows, cols) {
        return Err(format!(
            "{}: made for a {} x {} array, but the sensor is {rows} x {cols}",
            path.display(),
            cal.rows,
            cal.cols
        ));
    }
    Ok(cal)
}

/// The watcher thread and the receiving end of its channel.
pub struct Watcher {
    rx: Receiver<Arc<Loaded>>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Watcher {
    /// Starts watching `path`, whose current content (already loaded by the caller as
    /// generation 1) has signature as of now.
    pub fn spawn(path: PathBuf, rows: usize, cols: usize) -> std::io::Result<Watcher> {
        let (tx, rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::Builder::new()
            .name("calibration-watch".into())
            .spawn(move || watch(path, rows, cols, tx, stop2))?;
        Ok(Watcher {
            rx,
            stop,
            handle: Some(handle),
        })
    }

    /// A newly loaded calibration, if one is waiting (never blocks).
    pub fn try_next(&self) -> Option<Arc<Loaded>> {
        let mut newest = None;
        while let Ok(l) = self.rx.try_recv() {
            newest = Some(l);
        }
        newest
    }
}

impl Drop for Watcher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn watch(path: PathBuf, rows: usize, cols: usize, tx: Sender<Arc<Loaded>>, stop: Arc<AtomicBool>) {
    let mut seen = signature(&path);
    let mut generation = 1u32;
    let mut missing_reported = false;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(POLL);
        let now = signature(&path);
        if now == seen {
            continue;
        }
        let Some(sig) = now else {
            if !missing_reported {
                warn!(file = %path.display(), "calibration file is gone; keeping the loaded model until a new file appears");
                missing_reported = true;
            }
            seen = None;
            continue;
        };
        missing_reported = false;
        // Let a writer finish: the file must look the same for one more poll.
        std::thread::sleep(POLL / 2);
        if signature(&path) != Some(sig) {
            continue;
        }
        seen = Some(sig);
        match load_for(&path, rows, cols) {
            Ok(calibration) => {
                generation += 1;
                info!(
                    file = %path.display(),
                    id = %calibration.id,
                    version = calibration.version,
                    generation,
                    "calibration reloaded"
                );
                if tx
                    .send(Arc::new(Loaded {
                        calibration,
                        generation,
                    }))
                    .is_err()
                {
                    return;
                }
            }
            Err(e) => error!("calibration rejected, previous model keeps serving: {e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    const SIM: &str = include_str!("../../calibrations/sim-default.toml");

    fn wait_for(w: &Watcher, limit: Duration) -> Option<Arc<Loaded>> {
        let t0 = Instant::now();
        while t0.elapsed() < limit {
            if let Some(l) = w.try_next() {
                return Some(l);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        None
    }

    #[test]
    fn edits_and_renames_are_picked_up_and_bad_files_are_not() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("cal.toml");
        std::fs::write(&path, SIM).expect("write");
        let w = Watcher::spawn(path.clone(), 4, 4).expect("spawn");

        // In-place edit with a new version.
        std::thread::sleep(Duration::from_millis(30));
        std::fs::write(&path, SIM.replacen("version = 1", "version = 7", 1)).expect("edit");
        let l = wait_for(&w, Duration::from_secs(3)).expect("edit seen");
        assert_eq!((l.calibration.version, l.generation), (7, 2));

        // Garbage, truncation and a deletion are refused; nothing is handed over.
        std::fs::write(&path, b"\x00\xff garbage").expect("garbage");
        std::thread::sleep(Duration::from_millis(120));
        std::fs::write(&path, &SIM[..SIM.len() / 3]).expect("truncate");
        std::thread::sleep(Duration::from_millis(120));
        std::fs::remove_file(&path).expect("delete");
        assert!(wait_for(&w, Duration::from_millis(200)).is_none());

        // Atomic replacement by rename, as editors do.
        let tmp = dir.path().join("cal.toml.tmp");
        std::fs::write(&tmp, SIM.replacen("version = 1", "version = 8", 1)).expect("tmp");
        std::fs::rename(&tmp, &path).expect("rename");
        let l = wait_for(&w, Duration::from_secs(3)).expect("rename seen");
        assert_eq!((l.calibration.version, l.generation), (8, 3));
    }

    #[test]
    fn wrong_geometry_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("cal.toml");
        std::fs::write(&path, SIM).expect("write");
        let e = load_for(&path, 8, 8).expect_err("4x4 file on 8x8 sensor");
        assert!(e.contains("4 x 4"), "{e}");
    }
}
