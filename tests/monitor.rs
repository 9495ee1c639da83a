//! The live monitor driven as a person would: `taxel monitor` in a real terminal (a detached
//! tmux session of fixed size), read back with capture-pane, keys sent with send-keys, against a
//! running two-sensor demo. Skips with a message when tmux is not installed.

use std::process::Command;
use std::time::{Duration, Instant};

use taxel_testkit::{pipeline, Pipeline};

struct Tmux {
    socket: String,
}

impl Tmux {
    fn cmd(&self, args: &[&str]) -> String {
        let out = Command::new("tmux")
            .arg("-L")
            .arg(&self.socket)
            .args(args)
            .output()
            .expect("run tmux");
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    fn screen(&self) -> String {
        self.cmd(&["capture-pane", "-p", "-t", "m"])
    }

    /// Waits (with a deadline) until the screen satisfies `ok`; returns it.
    fn wait_screen(&self, what: &str, ok: impl Fn(&str) -> bool) -> String {
        let t0 = Instant::now();
        loop {
            let s = self.screen();
            if ok(&s) {
                return s;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "the screen never showed {what}:\n{s}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn keys(&self, k: &str) {
        self.cmd(&["send-keys", "-t", "m", k]);
    }

    /// Starts `taxel monitor args` of pipeline `p` in a new 120 x 40 session; the shell prints
    /// the exit code after it and stays open so the restored screen can be read.
    fn start(&self, p: &Pipeline, args: &str) {
        let shell = format!(
            "TAXEL_PREFIX={} '{}' monitor {args}; echo MONITOR_EXIT=$?; sleep 60",
            p.prefix,
            p.exe().display()
        );
        self.cmd(&["kill-session", "-t", "m"]);
        // Killing the last session makes the tmux server exit; a new-session that reaches it
        // while it shuts down fails ("server exited unexpectedly"), so try again briefly.
        let mut last = String::new();
        for _ in 0..20 {
            let out = Command::new("tmux")
                .args(["-L", &self.socket, "new-session", "-d", "-s", "m"])
                .args(["-x", "120", "-y", "40", &shell])
                .output()
                .expect("tmux new-session");
            if out.status.success() {
                return;
            }
            last = String::from_utf8_lossy(&out.stderr).into_owned();
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!("tmux new-session failed: {last}");
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        self.cmd(&["kill-server"]);
    }
}

/// The number after `key` on the screen (e.g. "rate 200.0 Hz").
fn number_after(screen: &str, key: &str) -> Option<f64> {
    let i = screen.find(key)? + key.len();
    let rest = screen[i..].trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// The `k`-th word after process `name` in the process panel (0 health, 1 pid, 2 restarts).
fn proc_field(screen: &str, name: &str, k: usize) -> Option<String> {
    let i = screen.find(&format!("{name} "))? + name.len();
    screen[i..]
        .split_whitespace()
        .nth(k)
        .map(|w| w.trim_end_matches('│').to_string())
}

fn has_live_numbers(s: &str) -> bool {
    number_after(s, "rate ").is_some_and(|r| r > 0.0)
        && number_after(s, "frames ").is_some_and(|f| f > 0.0)
        && number_after(s, "││force ").is_some()
}

#[test]
fn monitor_shows_live_sensors_switches_and_quits_cleanly() {
    if Command::new("tmux").arg("-V").output().is_err() {
        eprintln!("SKIP monitor test: tmux is not installed");
        return;
    }
    let mut p = pipeline!("mon");
    let out = p.dir().display().to_string();
    let demo = p.spawn(
        "demo",
        &[
            "demo",
            "--sensors",
            "2",
            "--rate-hz",
            "200",
            "--seconds",
            "120",
            "--out",
            &out,
        ],
    );
    p[demo].wait_for("[s1]", Duration::from_secs(30));

    let tmux = Tmux {
        socket: format!("taxel-test-{}", p.prefix),
    };
    // Sensors discovered from the service listing.
    tmux.start(&p, "");
    let s = tmux.wait_screen("both sensors with live numbers", |s| {
        s.contains("1 s0")
            && s.contains("2 s1")
            && s.contains("s0 | view: raw counts")
            && has_live_numbers(s)
    });
    assert!(s.contains("publisher-s0"), "process table:\n{s}");
    assert!(s.contains("calibrator-s1"), "process table:\n{s}");
    assert!(s.contains("alive"), "process health:\n{s}");
    assert!(s.contains("calibration v"), "calibration:\n{s}");

    // A calibration edit shows up as a reload.
    let cal = p.path("calibration.toml");
    let text = std::fs::read_to_string(&cal).expect("demo calibration");
    assert!(text.contains("version = 1"), "{text}");
    std::fs::write(&cal, text.replace("version = 1", "version = 2")).expect("edit calibration");
    tmux.wait_screen("the reloaded calibration", |s| {
        s.contains("calibration v2 gen 2 | reloaded")
    });

    // A killed publisher is restarted by the demo's supervisor: the monitor sees a new node.
    let pid: i32 = proc_field(&s, "publisher-s1", 1)
        .and_then(|p| p.parse().ok())
        .expect("publisher-s1 pid on screen");
    // SAFETY: kill(2) on a process of the demo this test started.
    unsafe {
        libc::kill(pid, libc::SIGKILL);
    }
    tmux.wait_screen("the publisher's restart", |s| {
        proc_field(s, "publisher-s1", 0) == Some("restarting".into())
            && proc_field(s, "publisher-s1", 2) == Some("r1".into())
    });
    tmux.wait_screen("the restarted publisher alive", |s| {
        proc_field(s, "publisher-s1", 0) == Some("alive".into())
            && proc_field(s, "publisher-s1", 1) != Some(pid.to_string())
    });

    tmux.keys("v");
    tmux.wait_screen("the baseline-subtracted view", |s| {
        s.contains("view: baseline-subtracted counts")
    });
    tmux.keys("v");
    tmux.wait_screen("the force view", |s| s.contains("view: force (N"));
    tmux.keys("2");
    tmux.wait_screen("sensor s1 selected", |s| {
        s.contains("s1 | view: force (N") && has_live_numbers(s)
    });
    tmux.keys("Tab");
    tmux.wait_screen("back to s0", |s| s.contains("s0 | view: force (N"));
    tmux.keys("q");
    let s = tmux.wait_screen("the exit code", |s| s.contains("MONITOR_EXIT="));
    assert!(s.contains("MONITOR_EXIT=0"), "monitor exit:\n{s}");
    assert!(!s.contains("view:"), "the UI is still on screen:\n{s}");
    assert!(
        number_after(&s, "taxel monitor: s0").is_some_and(|f| f > 0.0),
        "summary line:\n{s}"
    );
    // Terminal restored: alternate screen left, cursor visible.
    assert_eq!(
        tmux.cmd(&["display", "-p", "-t", "m", "#{alternate_on} #{cursor_flag}"])
            .trim(),
        "0 1"
    );

    // One sensor by flag; Ctrl-C quits cleanly too.
    tmux.start(&p, "--sensor s1");
    let s = tmux.wait_screen("sensor s1 with live numbers", |s| {
        s.contains("s1 | view: raw counts") && has_live_numbers(s)
    });
    assert!(
        !s.contains("2 s1"),
        "only the chosen sensor has a tab:\n{s}"
    );
    tmux.keys("C-c");
    let s = tmux.wait_screen("the exit code", |s| s.contains("MONITOR_EXIT="));
    assert!(
        s.contains("MONITOR_EXIT=0"),
        "monitor exit after Ctrl-C:\n{s}"
    );
    assert_eq!(
        tmux.cmd(&["display", "-p", "-t", "m", "#{alternate_on} #{cursor_flag}"])
            .trim(),
        "0 1"
    );

    p[demo].sigint();
    p.finish(demo, Duration::from_secs(30));
}

#[test]
fn monitor_refuses_bad_flags_before_touching_the_terminal() {
    let p = pipeline!("monbad");
    let (code, _, err) = p.run(&["monitor", "--fps", "0"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--fps"), "{err}");
    let (code, _, err) = p.run(&["monitor", "--sensor", "a/b"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("a/b"), "{err}");
}
