//! The fixture every multi-process test starts its pipeline with: a unique iceoryx2 prefix, a
//! temporary directory for its files, the `taxel` processes started under that prefix (each
//! role's usual start-up, waited for with a deadline), and the teardown: SIGINT and a clean
//! exit for every process the test stops, and, when the fixture goes out of scope (also after
//! a failed assertion), every process still running killed, the prefix's dead nodes cleaned
//! and its management segment released.

use std::ops::{Index, IndexMut};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use crate::Proc;

/// How long a process may take to print its ready line or to exit after SIGINT.
pub const LIMIT: Duration = Duration::from_secs(20);

/// A prefix no other test (or run) uses: `tx<tag><pid>_<n>_`.
pub fn unique_prefix(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "tx{}{}_{}_",
        tag,
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    )
}

/// Files in /dev/shm whose name starts with `prefix`.
pub fn shm_files(prefix: &str) -> Vec<String> {
    std::fs::read_dir(Path::new("/dev/shm"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(prefix))
                .collect()
        })
        .unwrap_or_default()
}

/// Replaces the file at `path` atomically (write a temporary beside it, rename it over), as
/// editors and deploy tools do.
pub fn replace(path: &Path, bytes: &[u8]) {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).expect("write temporary");
    std::fs::rename(&tmp, path).expect("rename");
}

/// One process of a [`Pipeline`] (an index into it: `pipeline[role]` is its [`Proc`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Role(usize);

/// A test's pipeline: its prefix, its directory and its processes.
pub struct Pipeline {
    exe: PathBuf,
    /// The iceoryx2 service prefix every process of this pipeline runs under.
    pub prefix: String,
    procs: Vec<Proc>,
    dir: tempfile::TempDir,
}

/// `taxel_testkit::pipeline!("tag")`: a [`Pipeline`] of the calling package's `taxel` binary.
#[macro_export]
macro_rules! pipeline {
    ($tag:expr) => {
        $crate::Pipeline::new(env!("CARGO_BIN_EXE_taxel"), $tag)
    };
}

impl Pipeline {
    /// A pipeline of the executable `exe` (the `taxel` launcher) under a fresh prefix made from
    /// `tag`, with a fresh temporary directory.
    pub fn new(exe: &str, tag: &str) -> Pipeline {
        Pipeline {
            exe: PathBuf::from(exe),
            prefix: unique_prefix(tag),
            procs: Vec::new(),
            dir: tempfile::tempdir().expect("tempdir"),
        }
    }

    /// The executable the pipeline runs.
    pub fn exe(&self) -> &Path {
        &self.exe
    }

    /// The pipeline's temporary directory (removed when the fixture is dropped).
    pub fn dir(&self) -> &Path {
        self.dir.path()
    }

    /// `name` inside the pipeline's directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// `name` inside the pipeline's directory, as an argument.
    pub fn arg(&self, name: &str) -> String {
        self.path(name).display().to_string()
    }

    /// Writes `contents` to `name` inside the pipeline's directory; returns its path as an
    /// argument.
    pub fn write(&self, name: &str, contents: impl AsRef<[u8]>) -> String {
        let p = self.path(name);
        std::fs::write(&p, contents).unwrap_or_else(|e| panic!("write {}: {e}", p.display()));
        p.display().to_string()
    }

    /// `taxel args...` under the pipeline's prefix, not started.
    pub fn command(&self, args: &[&str]) -> Command {
        let mut cmd = Command::new(&self.exe);
        cmd.args(args).env("TAXEL_PREFIX", &self.prefix);
        cmd
    }

    /// Runs `taxel args...` to completion; returns (exit code, stdout, stderr).
    pub fn run(&self, args: &[&str]) -> (i32, String, String) {
        let out = self
            .command(args)
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .output()
            .expect("run taxel");
        (
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    }

    /// Starts `taxel args...` as the process `name`.
    pub fn spawn(&mut self, name: &str, args: &[&str]) -> Role {
        let p = Proc::start(name, self.command(args));
        self.procs.push(p);
        Role(self.procs.len() - 1)
    }

    /// Starts `taxel args...` and waits until it prints `ready`.
    pub fn spawn_ready(&mut self, name: &str, args: &[&str], ready: &str) -> Role {
        let r = self.spawn(name, args);
        self[r].wait_for(ready, LIMIT);
        r
    }

    /// `taxel logger record --sensor SENSORS --out OUT ARGS...`, ready.
    pub fn logger(&mut self, sensors: &str, out: &str, args: &[&str]) -> Role {
        let mut all = vec!["logger", "record", "--sensor", sensors, "--out", out];
        all.extend_from_slice(args);
        self.spawn_ready("logger", &all, "logger ready")
    }

    /// `taxel calibrator run --sensor SENSOR --calibration CAL ARGS...`, ready.
    pub fn calibrator(&mut self, sensor: &str, cal: &str, args: &[&str]) -> Role {
        let mut all = vec![
            "calibrator",
            "run",
            "--sensor",
            sensor,
            "--calibration",
            cal,
        ];
        all.extend_from_slice(args);
        self.spawn_ready("calibrator", &all, "calibrator ready")
    }

    /// `taxel estimator run --sensor SENSOR ARGS...`, ready.
    pub fn estimator(&mut self, sensor: &str, args: &[&str]) -> Role {
        let mut all = vec!["estimator", "run", "--sensor", sensor];
        all.extend_from_slice(args);
        self.spawn_ready("estimator", &all, "estimator ready")
    }

    /// `taxel latency --sensor SENSOR ARGS...` as the process `name`, ready.
    pub fn latency(&mut self, name: &str, sensor: &str, args: &[&str]) -> Role {
        let mut all = vec!["latency", "--sensor", sensor];
        all.extend_from_slice(args);
        self.spawn_ready(name, &all, "latency probe ready")
    }

    /// `taxel publisher --sensor SENSOR ARGS...` (the source and its options in `args`),
    /// started without waiting: a short replay may be over before a ready line could be awaited.
    pub fn publisher(&mut self, sensor: &str, args: &[&str]) -> Role {
        let mut all = vec!["publisher", "--sensor", sensor];
        all.extend_from_slice(args);
        self.spawn("publisher", &all)
    }

    /// Like [`Pipeline::publisher`], and waits until it is ready.
    pub fn publisher_ready(&mut self, sensor: &str, args: &[&str]) -> Role {
        let r = self.publisher(sensor, args);
        self[r].wait_for("publisher ready", LIMIT);
        r
    }

    /// Waits (at most `limit`) until `role` exits by itself, and asserts it exited 0.
    pub fn finish(&mut self, role: Role, limit: Duration) {
        let p = &mut self[role];
        let st = p.wait_exit(limit);
        let out = p.output();
        assert!(st.success(), "{} exited with {st}:\n{out}", p.name);
    }

    /// The teardown of the processes `roles`: SIGINT to all of them at once (as Ctrl-C), then
    /// each must exit 0 within [`LIMIT`].
    pub fn stop(&mut self, roles: &[Role]) {
        for r in roles {
            self[*r].sigint();
        }
        for r in roles {
            self.finish(*r, LIMIT);
        }
    }

    /// Waits (at most `limit`) until no iceoryx2 node, alive or dead, is left under the prefix,
    /// releases the prefix and asserts that nothing of it is left in /dev/shm.
    pub fn assert_released(&self, limit: Duration) {
        let t0 = Instant::now();
        loop {
            let (alive, dead) = taxel_runtime::ipc::count_nodes(&self.prefix).expect("list nodes");
            if alive + dead == 0 {
                break;
            }
            assert!(
                t0.elapsed() < limit,
                "{alive} alive, {dead} dead nodes remain"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        taxel_runtime::ipc::release_prefix(&self.prefix).expect("release");
        assert_eq!(shm_files(&self.prefix), Vec::<String>::new());
    }
}

impl Index<Role> for Pipeline {
    type Output = Proc;
    fn index(&self, r: Role) -> &Proc {
        &self.procs[r.0]
    }
}

impl IndexMut<Role> for Pipeline {
    fn index_mut(&mut self, r: Role) -> &mut Proc {
        &mut self.procs[r.0]
    }
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        // Kill whatever still runs (a failed test), then clean up after it.
        self.procs.clear();
        let _ = taxel_runtime::ipc::clean_dead_nodes(&self.prefix);
        let _ = taxel_runtime::ipc::release_prefix(&self.prefix);
    }
}
