//! The supervisor behind `taxel up`, `taxel demo` and `taxel soak`: starts every process of a
//! pipeline as a child, restarts a process that dies with exponential backoff inside a restart
//! budget (the others keep running), cleans the iceoryx2 resources a dead node left before the
//! restart, logs every death with its exit reason, samples each child's peak memory, and on
//! shutdown stops everything stage by stage (consumers first, sources last) with SIGINT.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use taxel_runtime::{ipc, now_ns, Shutdown};
use tracing::{info, warn};

use crate::children::{exit_reason, peak_rss_kib, spawn, stop_all, Proc};

/// One process of a pipeline: `taxel <args...>`, stopped in `stage` order.
#[derive(Debug, Clone)]
pub struct ProcSpec {
    pub name: String,
    pub stage: u8,
    pub args: Vec<String>,
    /// Index in `args` of an output file that a restart must not overwrite: restart n writes
    /// `NAME.n.EXT` instead of `NAME.EXT` (the logger's recording).
    pub numbered_output: Option<usize>,
}

impl ProcSpec {
    pub fn new(name: &str, stage: u8, args: Vec<String>) -> ProcSpec {
        ProcSpec {
            name: name.to_string(),
            stage,
            args,
            numbered_output: None,
        }
    }

    /// The arguments of restart `n` (0: the first start).
    pub fn args_for(&self, n: u32) -> Vec<String> {
        let mut args = self.args.clone();
        if let Some(a) = self.numbered_output.and_then(|i| args.get_mut(i)) {
            if n > 0 {
                *a = numbered(a, n);
            }
        }
        args
    }
}

/// `dir/run.taxrec` -> `dir/run.N.taxrec` (`dir/run` -> `dir/run.N`).
pub fn numbered(path: &str, n: u32) -> String {
    let p = std::path::Path::new(path);
    let stem = p
        .file_stem()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    let name = match p.extension() {
        Some(ext) => format!("{stem}.{n}.{}", ext.to_string_lossy()),
        None => format!("{stem}.{n}"),
    };
    p.with_file_name(name).display().to_string()
}

/// Restart policy.
#[derive(Debug, Clone)]
pub struct Policy {
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// At most this many restarts of one process within `window`.
    pub max_restarts: u32,
    pub window: Duration,
    /// Running this long resets the backoff to `backoff_initial`.
    pub stable_after: Duration,
    /// Per stage, at shutdown, before SIGKILL.
    pub stop_grace: Duration,
}

/// A period during which a process was not running (CLOCK_MONOTONIC ns, as `now_ns`).
#[derive(Debug, Clone, Copy)]
pub struct Downtime {
    pub died_ns: u64,
    /// When its replacement was started (None: never restarted).
    pub restarted_ns: Option<u64>,
}

/// What the supervisor knows about one process over the whole run.
pub struct Slot {
    pub spec: ProcSpec,
    proc: Option<Proc>,
    started: Instant,
    pub restarts: u32,
    recent: VecDeque<Instant>,
    backoff: Duration,
    due: Option<Instant>,
    /// The restart budget ran out: it stays stopped.
    pub gave_up: bool,
    /// It exited 0 by itself (a finished replay, `--seconds`): not restarted.
    pub finished: bool,
    /// Exit reasons of every incarnation that died.
    pub deaths: Vec<String>,
    pub downtimes: Vec<Downtime>,
    /// Largest VmHWM seen over all incarnations (KiB).
    pub peak_kib: u64,
    pub final_status: Option<String>,
    pub final_ok: bool,
}

impl Slot {
    /// The current incarnation's pid, if running.
    pub fn pid(&self) -> Option<u32> {
        self.proc
            .as_ref()
            .filter(|p| p.status.is_none())
            .map(|p| p.pid())
    }

    fn sample_memory(&mut self) {
        if let Some(k) = self.pid().and_then(peak_rss_kib) {
            self.peak_kib = self.peak_kib.max(k);
        }
    }
}

/// A running pipeline.
pub struct Supervisor {
    prefix: String,
    log: String,
    policy: Policy,
    pub slots: Vec<Slot>,
    pub t0: Instant,
    last_memory: Instant,
}

/// Totals at the end of a run.
pub struct Outcome {
    /// Every process ended with exit 0 and none was given up on or had to be killed.
    pub all_ok: bool,
    pub restarts: u32,
}

impl Supervisor {
    /// Starts every process in order. A process that fails to start makes the whole start fail
    /// (after stopping the ones already running).
    pub fn start(
        prefix: &str,
        log: &str,
        policy: Policy,
        specs: Vec<ProcSpec>,
    ) -> anyhow::Result<Supervisor> {
        let cleaned = ipc::clean_dead_nodes(prefix).unwrap_or(0);
        if cleaned > 0 {
            info!("cleaned stale resources of {cleaned} dead node(s) under prefix {prefix}");
        }
        let mut sup = Supervisor {
            prefix: prefix.to_string(),
            log: log.to_string(),
            policy,
            slots: Vec::new(),
            t0: Instant::now(),
            last_memory: Instant::now(),
        };
        for spec in specs {
            let backoff = sup.policy.backoff_initial;
            match spawn(&spec.name, spec.stage, &spec.args, prefix, log, 0) {
                Ok(p) => {
                    info!("started {} pid {}", spec.name, p.pid());
                    sup.slots.push(Slot {
                        spec,
                        proc: Some(p),
                        started: Instant::now(),
                        restarts: 0,
                        recent: VecDeque::new(),
                        backoff,
                        due: None,
                        gave_up: false,
                        finished: false,
                        deaths: Vec::new(),
                        downtimes: Vec::new(),
                        peak_kib: 0,
                        final_status: None,
                        final_ok: false,
                    });
                }
                Err(e) => {
                    sup.stop();
                    return Err(e);
                }
            }
        }
        Ok(sup)
    }

    /// Looks at every child once: reaps the dead, schedules and performs restarts.
    pub fn tick(&mut self) {
        let now = Instant::now();
        let sample = now.duration_since(self.last_memory) >= Duration::from_secs(1);
        if sample {
            self.last_memory = now;
        }
        let mut restart_now = Vec::new();
        for (i, slot) in self.slots.iter_mut().enumerate() {
            if sample {
                slot.sample_memory();
            }
            if let Some(due) = slot.due {
                if now >= due {
                    restart_now.push(i);
                }
                continue;
            }
            let Some(p) = slot.proc.as_mut() else {
                continue;
            };
            let Some(st) = p.poll() else { continue };
            let pid = p.pid();
            let reason = exit_reason(st);
            slot.proc = None;
            if st.success() {
                info!(
                    "{} pid {pid} finished ({reason}); not restarted",
                    slot.spec.name
                );
                slot.finished = true;
                slot.final_status = Some(reason);
                slot.final_ok = true;
                continue;
            }
            slot.deaths.push(reason.clone());
            slot.downtimes.push(Downtime {
                died_ns: now_ns(),
                restarted_ns: None,
            });
            if now.duration_since(slot.started) >= self.policy.stable_after {
                slot.backoff = self.policy.backoff_initial;
            }
            while slot
                .recent
                .front()
                .is_some_and(|t| now.duration_since(*t) > self.policy.window)
            {
                slot.recent.pop_front();
            }
            if slot.recent.len() as u32 >= self.policy.max_restarts {
                warn!(
                    "{} pid {pid} died ({reason}); restart budget exhausted ({} restarts within {:.0} s): it stays stopped, the others keep running",
                    slot.spec.name,
                    slot.recent.len(),
                    self.policy.window.as_secs_f64()
                );
                slot.gave_up = true;
                slot.final_status = Some(format!("gave up ({reason})"));
                continue;
            }
            warn!(
                "{} pid {pid} died ({reason}); restart {} in {} ms",
                slot.spec.name,
                slot.restarts + 1,
                slot.backoff.as_millis()
            );
            slot.due = Some(now + slot.backoff);
            slot.backoff = (slot.backoff * 2).min(self.policy.backoff_max);
        }
        if restart_now.is_empty() {
            return;
        }
        // Dead nodes (their processes are reaped above) are cleaned before their replacement
        // opens the same services.
        let cleaned = match ipc::clean_dead_nodes(&self.prefix) {
            Ok(n) => n,
            Err(e) => {
                warn!("cannot clean dead iceoryx2 nodes: {e}");
                0
            }
        };
        for i in restart_now {
            let slot = &mut self.slots[i];
            slot.due = None;
            let n = slot.restarts + 1;
            let args = slot.spec.args_for(n);
            match spawn(
                &slot.spec.name,
                slot.spec.stage,
                &args,
                &self.prefix,
                &self.log,
                n,
            ) {
                Ok(p) => {
                    let output = slot
                        .spec
                        .numbered_output
                        .and_then(|i| args.get(i))
                        .map_or(String::new(), |o| format!("; now writing {o}"));
                    info!(
                        "restarted {} pid {} (restart {n}; cleaned stale resources of {cleaned} dead node(s){output})",
                        slot.spec.name,
                        p.pid()
                    );
                    slot.proc = Some(p);
                    slot.restarts = n;
                    slot.recent.push_back(Instant::now());
                    slot.started = Instant::now();
                    if let Some(d) = slot.downtimes.last_mut() {
                        d.restarted_ns = Some(now_ns());
                    }
                }
                Err(e) => {
                    warn!("cannot restart {}: {e:#}; it stays stopped", slot.spec.name);
                    slot.gave_up = true;
                    slot.final_status = Some(format!("gave up (cannot start: {e})"));
                }
            }
        }
    }

    /// Sends `sig` to the named process (its peak memory is sampled first). Returns its pid.
    pub fn signal(&mut self, name: &str, sig: i32) -> Option<u32> {
        let slot = self.slots.iter_mut().find(|s| s.spec.name == name)?;
        slot.sample_memory();
        let p = slot.proc.as_ref().filter(|p| p.status.is_none())?;
        p.signal(sig);
        Some(p.pid())
    }

    /// Ticks every 50 ms until shutdown is requested or `until` passes; `hook` runs after
    /// every tick (status, fault injection).
    pub fn run(
        &mut self,
        shutdown: &Shutdown,
        until: Option<Instant>,
        mut hook: impl FnMut(&mut Supervisor),
    ) {
        while !shutdown.requested() && until.is_none_or(|u| Instant::now() < u) {
            self.tick();
            hook(self);
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Stops every running process stage by stage (SIGINT; SIGKILL past the grace period).
    pub fn stop(&mut self) -> Outcome {
        for slot in &mut self.slots {
            slot.sample_memory();
            slot.due = None;
        }
        let grace = self.policy.stop_grace;
        let mut running: Vec<&mut Proc> = self
            .slots
            .iter_mut()
            .filter_map(|s| s.proc.as_mut())
            .collect();
        let killed = stop_all(&mut running, grace);
        let mut all_ok = killed.is_empty();
        let mut restarts = 0;
        for slot in &mut self.slots {
            restarts += slot.restarts;
            if let Some(p) = slot.proc.take() {
                let ok = p.status.is_some_and(|s| s.success());
                slot.final_ok = ok;
                slot.final_status = Some(if killed.contains(&slot.spec.name) {
                    format!(
                        "did not stop within {} ms and was killed",
                        grace.as_millis()
                    )
                } else {
                    p.status.map_or("still running?".to_string(), exit_reason)
                });
            } else if slot.final_status.is_none() {
                slot.final_status = Some("down at the stop (its restart was pending)".to_string());
            }
            all_ok &= slot.final_ok && !slot.gave_up;
        }
        Outcome { all_ok, restarts }
    }

    /// The summary lines (`  name   exited 0 [after N restart(s): reasons]`).
    pub fn summary_lines(&self) -> Vec<String> {
        self.slots
            .iter()
            .map(|s| {
                let st = s.final_status.clone().unwrap_or_default();
                let st = if s.final_ok && st == "exit 0" {
                    "exited 0".to_string()
                } else {
                    st
                };
                let restarts = if s.restarts > 0 || !s.deaths.is_empty() {
                    format!(
                        " | restarted {} time(s); deaths: {}",
                        s.restarts,
                        s.deaths.join(", ")
                    )
                } else {
                    String::new()
                };
                format!("  {:<22} {st}{restarts}", s.spec.name)
            })
            .collect()
    }

    /// Checks the prefix for leftover nodes after a stop; releases it when none is left.
    /// Returns the line to print and whether no node is alive.
    pub fn shared_memory_report(&self) -> (String, bool) {
        match ipc::count_nodes(&self.prefix) {
            Ok((0, 0)) => {
                let released = ipc::release_prefix(&self.prefix).unwrap_or(false);
                (
                    format!(
                        "  shared memory: no iceoryx2 nodes left under prefix {:?}{}",
                        self.prefix,
                        if released {
                            "; prefix segment released"
                        } else {
                            ""
                        }
                    ),
                    true,
                )
            }
            Ok((alive, dead)) => {
                let cleaned = ipc::clean_dead_nodes(&self.prefix).unwrap_or(0);
                (
                    format!(
                        "  shared memory: {alive} node(s) still alive, {dead} dead (cleaned {cleaned})"
                    ),
                    alive == 0,
                )
            }
            Err(e) => (format!("  shared memory: cannot list nodes: {e}"), false),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_restarted_logger_writes_a_numbered_file() {
        assert_eq!(numbered("/d/run.taxrec", 2), "/d/run.2.taxrec");
        assert_eq!(numbered("run", 1), "run.1");
        let mut spec = ProcSpec::new("logger", 0, vec!["--out".into(), "/d/x.taxrec".into()]);
        spec.numbered_output = Some(1);
        assert_eq!(spec.args_for(0)[1], "/d/x.taxrec");
        assert_eq!(spec.args_for(3)[1], "/d/x.3.taxrec");
    }
}
