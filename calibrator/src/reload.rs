//! Hot reload of the calibration files: one watcher thread polls every file's metadata every
//! 20 ms (so editing in place and atomic replacement by rename are both seen), waits until a
//! changed file stops changing, then parses and validates it off the hot path and hands the new
//! model over a channel, tagged with the file. The hot loop only does a non-blocking `try_recv`
//! per sample. A file that fails to load is reported once per change, naming the sensors it
//! serves, and their previous model keeps serving; other files and sensors are not affected.

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

/// One file the watcher follows: its path, the geometry its calibrations must have, and the
/// sensors it serves (named in the log lines).
#[derive(Debug, Clone)]
pub struct Watched {
    pub path: PathBuf,
    pub rows: usize,
    pub cols: usize,
    pub sensors: Vec<String>,
}

/// The watcher thread (one for every file of the process) and the receiving end of its
/// channel.
pub struct Watcher {
    rx: Receiver<(usize, Arc<Loaded>)>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Watcher {
    /// Starts watching `path`, whose current content (already loaded by the caller as
    /// generation 1) has signature as of now.
    pub fn spawn(path: PathBuf, rows: usize, cols: usize) -> std::io::Result<Watcher> {
        Watcher::spawn_many(vec![Watched {
            path,
            rows,
            cols,
            sensors: Vec::new(),
        }])
    }

    /// Starts watching several files in one thread (each already loaded by the caller as its
    /// generation 1). A file that fails to load is reported with the sensors it serves; the
    /// other files are not affected.
    pub fn spawn_many(files: Vec<Watched>) -> std::io::Result<Watcher> {
        let (tx, rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::Builder::new()
            .name("calibration-watch".into())
            .spawn(move || watch(files, tx, stop2))?;
        Ok(Watcher {
            rx,
            stop,
            handle: Some(handle),
        })
    }

    /// A newly loaded calibration, if one is waiting (never blocks); for a watcher of one file.
    pub fn try_next(&self) -> Option<Arc<Loaded>> {
        let mut newest = None;
        while let Ok((_, l)) = self.rx.try_recv() {
            newest = Some(l);
        }
        newest
    }

    /// Hands every newly loaded calibration to `f` with the index of its file (never blocks).
    pub fn try_each(&self, mut f: impl FnMut(usize, Arc<Loaded>)) {
        while let Ok((i, l)) = self.rx.try_recv() {
            f(i, l);
        }
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

/// What the watcher knows of one file.
struct FileState {
    seen: Option<FileSignature>,
    generation: u32,
    missing_reported: bool,
    /// Changed at the last poll: look again after half a poll before reading it.
    settling: Option<FileSignature>,
}

fn watch(files: Vec<Watched>, tx: Sender<(usize, Arc<Loaded>)>, stop: Arc<AtomicBool>) {
    let mut state: Vec<FileState> = files
        .iter()
        .map(|f| FileState {
            seen: signature(&f.path),
            generation: 1,
            missing_reported: false,
            settling: None,
        })
        .collect();
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(POLL);
        let mut any_settling = false;
        for (f, st) in files.iter().zip(state.iter_mut()) {
            st.settling = None;
            let now = signature(&f.path);
            if now == st.seen {
                continue;
            }
            let Some(sig) = now else {
                if !st.missing_reported {
                    warn!(file = %f.path.display(), sensors = %f.sensors.join(","), "calibration file is gone; keeping the loaded model until a new file appears");
                    st.missing_reported = true;
                }
                st.seen = None;
                continue;
            };
            st.missing_reported = false;
            st.settling = Some(sig);
            any_settling = true;
        }
        if !any_settling {
            continue;
        }
        // Let a writer finish: the file must look the same for one more poll.
        std::thread::sleep(POLL / 2);
        for (i, (f, st)) in files.iter().zip(state.iter_mut()).enumerate() {
            let Some(sig) = st.settling.take() else {
                continue;
            };
            if signature(&f.path) != Some(sig) {
                continue;
            }
            st.seen = Some(sig);
            match load_for(&f.path, f.rows, f.cols) {
                Ok(calibration) => {
                    st.generation += 1;
                    info!(
                        file = %f.path.display(),
                        sensors = %f.sensors.join(","),
                        id = %calibration.id,
                        version = calibration.version,
                        generation = st.generation,
                        "calibration reloaded"
                    );
                    let loaded = Arc::new(Loaded {
                        calibration,
                        generation: st.generation,
                    });
                    if tx.send((i, loaded)).is_err() {
                        return;
                    }
                }
                Err(e) if f.sensors.is_empty() => {
                    error!("calibration rejected, previous model keeps serving: {e}")
                }
                Err(e) => error!(
                    "calibration rejected for sensor(s) {}, their previous model keeps serving (the other sensors are not affected): {e}",
                    f.sensors.join(",")
                ),
            }
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
