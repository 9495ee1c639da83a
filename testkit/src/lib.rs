//! taxel-testkit owns what the integration tests of several crates share: a child process
//! (a taxel role, a bridge) whose stdout and stderr lines are collected as they arrive, waited
//! on for a line (or its n-th occurrence) or for its exit with a deadline, stopped with SIGINT
//! as Ctrl-C would, and killed when the test ends early; and the [`Pipeline`] fixture that
//! every multi-process test starts its processes with (unique prefix, temporary directory,
//! each role's start-up, teardown); the helpers of relay tests (`relay`: bridges, a raw-frame
//! publisher and far-side receiver, delivery counts) and a network link emulated in user
//! space (`netem`: delay, loss and cuts between two network namespaces). Test support only;
//! nothing here ships.

pub mod netem;
mod pipeline;
pub mod relay;

pub use pipeline::{replace, shm_files, unique_prefix, Pipeline, Role, LIMIT};

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

/// A child process whose output lines are collected.
pub struct Proc {
    pub name: String,
    pub child: Child,
    lines: Receiver<String>,
    /// Every line read so far (stderr and stdout interleaved as they arrived).
    pub seen: Vec<String>,
}

impl Proc {
    /// Starts `cmd` (program, arguments and environment set by the caller) with
    /// `RUST_LOG=info`, `NO_COLOR=1` unless the caller set them, no stdin, and both output
    /// streams collected. Panics (it is a test) when the program cannot start.
    pub fn start(name: &str, mut cmd: Command) -> Proc {
        let set = |cmd: &Command, key: &str| cmd.get_envs().any(|(k, _)| k == key);
        if !set(&cmd, "RUST_LOG") {
            cmd.env("RUST_LOG", "info");
        }
        if !set(&cmd, "NO_COLOR") {
            cmd.env("NO_COLOR", "1");
        }
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("spawn {name}: {e}"));
        let (tx, rx) = channel();
        let tx2 = tx.clone();
        let err = child.stderr.take().expect("stderr");
        let out = child.stdout.take().expect("stdout");
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let _ = tx2.send(l);
            }
        });
        Proc {
            name: name.to_string(),
            child,
            lines: rx,
            seen: Vec::new(),
        }
    }

    /// Collects output lines that have arrived so far.
    pub fn pump(&mut self) {
        while let Ok(l) = self.lines.try_recv() {
            self.seen.push(l);
        }
    }

    /// Waits until a line containing `needle` appears; fails if the process exits first or
    /// `limit` passes.
    pub fn wait_for(&mut self, needle: &str, limit: Duration) {
        let t0 = Instant::now();
        loop {
            self.pump();
            if self.seen.iter().any(|l| l.contains(needle)) {
                return;
            }
            if let Ok(Some(st)) = self.child.try_wait() {
                self.pump();
                panic!(
                    "{} exited ({st}) before {needle:?}:\n{}",
                    self.name,
                    self.seen.join("\n")
                );
            }
            assert!(
                t0.elapsed() < limit,
                "{} did not print {needle:?} within {limit:?}:\n{}",
                self.name,
                self.seen.join("\n")
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// How many lines printed so far contain `needle`.
    pub fn count(&mut self, needle: &str) -> usize {
        self.pump();
        self.seen.iter().filter(|l| l.contains(needle)).count()
    }

    /// Waits until `needle` has been printed at least `n` times; fails if the process exits
    /// first or `limit` passes.
    pub fn wait_count(&mut self, needle: &str, n: usize, limit: Duration) {
        let t0 = Instant::now();
        while self.count(needle) < n {
            if let Ok(Some(st)) = self.child.try_wait() {
                self.pump();
                panic!(
                    "{} exited ({st}) before printing {needle:?} {n} times:\n{}",
                    self.name,
                    self.seen.join("\n")
                );
            }
            assert!(
                t0.elapsed() < limit,
                "{} did not print {needle:?} {n} times within {limit:?}:\n{}",
                self.name,
                self.seen.join("\n")
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The last line printed so far that contains `needle` (empty when there is none).
    pub fn last_line(&mut self, needle: &str) -> String {
        self.pump();
        self.seen
            .iter()
            .rfind(|l| l.contains(needle))
            .cloned()
            .unwrap_or_default()
    }

    /// Sends SIGINT (what Ctrl-C sends).
    pub fn sigint(&self) {
        // SAFETY: kill(2) on our own unreaped child.
        unsafe {
            libc::kill(self.child.id() as i32, libc::SIGINT);
        }
    }

    /// Waits for exit with a deadline (kills and fails past it).
    pub fn wait_exit(&mut self, limit: Duration) -> ExitStatus {
        let t0 = Instant::now();
        loop {
            if let Ok(Some(st)) = self.child.try_wait() {
                // Let the reader threads deliver the last lines.
                std::thread::sleep(Duration::from_millis(100));
                self.pump();
                return st;
            }
            if t0.elapsed() > limit {
                let _ = self.child.kill();
                let _ = self.child.wait();
                self.pump();
                panic!(
                    "{} did not exit within {limit:?}:\n{}",
                    self.name,
                    self.seen.join("\n")
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGINT, then the exit status (10 s at most).
    pub fn stop(&mut self) -> ExitStatus {
        self.sigint();
        self.wait_exit(Duration::from_secs(10))
    }

    /// Everything printed so far.
    pub fn output(&mut self) -> String {
        self.pump();
        self.seen.join("\n")
    }
}

impl Drop for Proc {
    /// A process still running (a failed test) gets SIGINT first, so a supervisor (`taxel up`,
    /// `taxel demo`) stops its own children instead of leaving them running as orphans; after
    /// 3 s it is killed.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.sigint();
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(3) {
                if let Ok(Some(_)) = self.child.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
