//! Child processes of the launcher: each role runs as `taxel <role> ...` (this executable), in
//! its own process group so a terminal Ctrl-C reaches only the launcher, which then stops the
//! children in order. Children watch the launcher's pid and stop if it disappears. Also: exit
//! reasons for logs and peak memory from /proc.

use std::os::unix::process::CommandExt;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use taxel_runtime::process::{PARENT_PID_ENV, RESTART_ENV};

/// A running child.
pub struct Proc {
    pub name: String,
    /// Stop order: lower stops first.
    pub stage: u8,
    child: Child,
    pub status: Option<ExitStatus>,
}

/// Starts `taxel <args...>` as a child; `restart` > 0 is passed as [`RESTART_ENV`].
pub fn spawn(
    name: &str,
    stage: u8,
    args: &[String],
    prefix: &str,
    log: &str,
    restart: u32,
) -> anyhow::Result<Proc> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.args(args)
        .env(PARENT_PID_ENV, std::process::id().to_string())
        .env("TAXEL_PREFIX", prefix)
        .env("RUST_LOG", log)
        .stdin(Stdio::null())
        .process_group(0);
    if restart > 0 {
        cmd.env(RESTART_ENV, restart.to_string());
    } else {
        cmd.env_remove(RESTART_ENV);
    }
    let child = cmd
        .spawn()
        .map_err(|e| anyhow::anyhow!("cannot start {name}: {e}"))?;
    Ok(Proc {
        name: name.to_string(),
        stage,
        child,
        status: None,
    })
}

impl Proc {
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Exit status if the child has ended (reaps it).
    pub fn poll(&mut self) -> Option<ExitStatus> {
        if self.status.is_none() {
            if let Ok(Some(s)) = self.child.try_wait() {
                self.status = Some(s);
            }
        }
        self.status
    }

    pub fn signal(&self, sig: i32) {
        if self.status.is_none() {
            // SAFETY: kill(2) with a pid we spawned and have not reaped yet.
            unsafe {
                libc::kill(self.child.id() as i32, sig);
            }
        }
    }
}

/// Why a child ended, for logs: `exit 1`, `SIGKILL`, ...
pub fn exit_reason(st: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    if let Some(c) = st.code() {
        return format!("exit {c}");
    }
    match st.signal() {
        Some(sig) => signal_name(sig),
        None => st.to_string(),
    }
}

/// The name of a signal number (`SIGKILL`), or `signal N`.
pub fn signal_name(sig: i32) -> String {
    let name = match sig {
        libc::SIGHUP => "SIGHUP",
        libc::SIGINT => "SIGINT",
        libc::SIGQUIT => "SIGQUIT",
        libc::SIGILL => "SIGILL",
        libc::SIGABRT => "SIGABRT",
        libc::SIGBUS => "SIGBUS",
        libc::SIGFPE => "SIGFPE",
        libc::SIGKILL => "SIGKILL",
        libc::SIGSEGV => "SIGSEGV",
        libc::SIGPIPE => "SIGPIPE",
        libc::SIGTERM => "SIGTERM",
        _ => return format!("signal {sig}"),
    };
    name.to_string()
}

/// Peak resident memory (VmHWM) of a process in KiB, from /proc.
pub fn peak_rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// Stops children stage by stage with SIGINT, waiting up to `grace` per stage before SIGKILL.
/// Returns the names of children that had to be killed.
pub fn stop_all(procs: &mut [&mut Proc], grace: Duration) -> Vec<String> {
    let mut killed = Vec::new();
    let mut stages: Vec<u8> = procs.iter().map(|p| p.stage).collect();
    stages.sort_unstable();
    stages.dedup();
    for stage in stages {
        for p in procs.iter_mut().filter(|p| p.stage == stage) {
            if p.poll().is_none() {
                p.signal(libc::SIGINT);
            }
        }
        let t0 = Instant::now();
        loop {
            let pending = procs
                .iter_mut()
                .filter(|p| p.stage == stage)
                .filter_map(|p| p.poll().is_none().then_some(()))
                .count();
            if pending == 0 {
                break;
            }
            if t0.elapsed() > grace {
                for p in procs.iter_mut().filter(|p| p.stage == stage) {
                    if p.poll().is_none() {
                        p.signal(libc::SIGKILL);
                        let _ = p.child.wait().map(|s| p.status = Some(s));
                        killed.push(p.name.clone());
                    }
                }
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    killed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_reasons_name_codes_and_signals() {
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(exit_reason(ExitStatus::from_raw(1 << 8)), "exit 1");
        assert_eq!(exit_reason(ExitStatus::from_raw(libc::SIGKILL)), "SIGKILL");
        assert_eq!(signal_name(64), "signal 64");
        assert!(peak_rss_kib(std::process::id()).is_some_and(|k| k > 0));
    }
}
