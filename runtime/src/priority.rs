//! Real-time scheduling for the processes of a pipeline (`--realtime PRIORITY`): on a small
//! computer shared with other work, a frame's age at its p99 is mostly time spent waiting for a
//! core; with SCHED_FIFO the pipeline's processes run as soon as they wake. Linux schedules
//! threads: the policy is set on the calling thread, before the process starts any other
//! (they inherit it).

/// `--realtime PRIORITY` of a pipeline process.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RealtimeArg {
    /// Run at real-time priority PRIORITY (SCHED_FIFO, 1-99; needs root, CAP_SYS_NICE or an
    /// rtprio limit). For processes that wait on events (the default `--wake event`): a
    /// busy-polling process at real-time priority takes its core from everything else.
    #[arg(long, value_name = "PRIORITY", value_parser = clap::value_parser!(u8).range(1..=99))]
    pub realtime: Option<u8>,
}

impl RealtimeArg {
    /// Switches the calling thread (call it first thing in `main`, before any other thread
    /// starts) to SCHED_FIFO at the priority asked for (nothing without the flag); a one-line
    /// error naming the flag when the system refuses, or when the process busy-polls (`busy`:
    /// it would keep its core from everything else, the kernel's own threads included).
    pub fn apply(&self, busy: bool) -> Result<(), String> {
        let Some(priority) = self.realtime else {
            return Ok(());
        };
        if busy {
            return Err(format!(
                "--realtime {priority} with --wake busy: a busy-polling process at real-time \
                 priority keeps its core from everything else; use --wake event or adaptive"
            ));
        }
        let param = libc::sched_param {
            sched_priority: i32::from(priority),
        };
        // SAFETY: sched_setscheduler reads `param` and changes the calling thread's policy.
        let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if rc != 0 {
            let e = std::io::Error::last_os_error();
            return Err(format!(
                "--realtime {priority}: the system refused real-time priority ({e}); run as \
                 root, give the binary CAP_SYS_NICE, or raise the rtprio limit"
            ));
        }
        tracing::info!(priority, "running at real-time priority (SCHED_FIFO)");
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The policy of the calling thread and its priority.
    fn policy() -> (i32, i32) {
        let mut p = libc::sched_param { sched_priority: 0 };
        // SAFETY: reads this process's scheduling parameters into `p`.
        let got = unsafe { libc::sched_getparam(0, &mut p) };
        assert_eq!(got, 0);
        // SAFETY: no arguments but the pid.
        (unsafe { libc::sched_getscheduler(0) }, p.sched_priority)
    }

    #[test]
    fn nothing_without_the_flag_and_fifo_or_a_clear_refusal_with_it() {
        let before = policy();
        RealtimeArg::default().apply(false).expect("no flag");
        assert_eq!(policy(), before);
        // On a thread of its own, so the test's other threads keep their policy.
        let child = std::thread::spawn(|| {
            let r = RealtimeArg { realtime: Some(3) }.apply(false);
            (r, policy())
        });
        let (r, (pol, prio)) = child.join().expect("thread");
        match r {
            Ok(()) => {
                assert_eq!(pol, libc::SCHED_FIFO);
                assert_eq!(prio, 3);
            }
            Err(e) => assert!(e.starts_with("--realtime 3: the system refused"), "{e}"),
        }
        let e = RealtimeArg { realtime: Some(3) }
            .apply(true)
            .expect_err("busy");
        assert!(e.starts_with("--realtime 3 with --wake busy"), "{e}");
    }
}
