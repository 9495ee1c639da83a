//! Helpers for the multi-process tests: spawn the real `taxel` binary with a unique iceoryx2
//! prefix, wait for log lines with a deadline, signal and reap children.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

pub const TAXEL: &str = env!("CARGO_BIN_EXE_taxel");

/// A prefix no other test (or run) uses.
pub fn unique_prefix(tag: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "tx{}{}_{}_",
        tag,
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    )
}

/// A child process whose stderr lines are collected.
pub struct Proc {
    pub name: String,
    pub child: Child,
    lines: Receiver<String>,
    pub seen: Vec<String>,
}

pub fn spawn(name: &str, prefix: &str, args: &[&str]) -> Proc {
    let mut child = Command::new(TAXEL)
        .args(args)
        .env("TAXEL_PREFIX", prefix)
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn taxel");
    let (tx, rx) = channel();
    let err = child.stderr.take().expect("stderr");
    let out = child.stdout.take().expect("stdout");
    let tx2 = tx.clone();
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

/// Spawns `taxel args...` and waits (20 s at most) until it logs `ready`.
pub fn spawn_ready(name: &str, prefix: &str, args: &[&str], ready: &str) -> Proc {
    let mut p = spawn(name, prefix, args);
    p.wait_for(ready, Duration::from_secs(20));
    p
}

impl Proc {
    /// Collects output lines that have arrived so far.
    pub fn pump(&mut self) {
        while let Ok(l) = self.lines.try_recv() {
            self.seen.push(l);
        }
    }

    /// Waits until a line containing `needle` appears.
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
                std::thread::sleep(Duration::from_millis(50));
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

    pub fn output(&mut self) -> String {
        self.pump();
        self.seen.join("\n")
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Runs `taxel args...` to completion and returns (exit code, stdout, stderr).
pub fn run(prefix: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(TAXEL)
        .args(args)
        .env("TAXEL_PREFIX", prefix)
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

/// `taxel logger record --sensor SENSORS --out OUT`, ready.
#[allow(dead_code)] // not every test binary records
pub fn spawn_logger(prefix: &str, sensors: &str, out: &str) -> Proc {
    spawn_ready(
        "logger",
        prefix,
        &["logger", "record", "--sensor", sensors, "--out", out],
        "logger ready",
    )
}
