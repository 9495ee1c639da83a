//! What the tests of a relay (the bridge) share: the bridge as a child process (the standalone
//! `taxel-bridge` or the launcher's `taxel bridge`), certificates, a 1 kHz raw-frame publisher
//! and a far-side receiver that records what arrives, and the delivery counts (loss,
//! reordering, duplicates, gaps) of what it recorded.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::messaging_pattern::MessagingPattern;
use taxel_msgs::{sensor_id_bytes, RawFrame, Stream};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::now_ns;

use crate::Proc;

/// How to start a bridge: a program and the arguments before the bridge's own.
#[derive(Debug, Clone)]
pub struct BridgeExe {
    program: String,
    pre: Vec<String>,
}

impl BridgeExe {
    /// The standalone binary (`taxel-bridge ARGS`).
    pub fn standalone(path: &str) -> BridgeExe {
        BridgeExe {
            program: path.to_string(),
            pre: Vec::new(),
        }
    }

    /// The launcher (`taxel bridge ARGS`).
    pub fn launcher(path: &str) -> BridgeExe {
        BridgeExe {
            program: path.to_string(),
            pre: vec!["bridge".into()],
        }
    }

    /// A bridge command (outside any TAXEL_PREFIX of the environment), optionally run in a
    /// network namespace.
    pub fn command(&self, netns: Option<&str>, args: &[String]) -> Command {
        let mut cmd = match netns {
            Some(ns) => {
                let mut c = Command::new("ip");
                c.args(["netns", "exec", ns, &self.program]);
                c
            }
            None => Command::new(&self.program),
        };
        // With why each Zenoh session ended (`taxel_bridge::cli::SESSION_END` at debug: the
        // bridge's default filter keeps it, and RUST_LOG replaces that default).
        cmd.args(&self.pre)
            .args(args)
            .env_remove("TAXEL_PREFIX")
            .env(
                "RUST_LOG",
                "info,zenoh_transport::unicast::universal::link=debug",
            );
        cmd
    }

    pub fn spawn(&self, name: &str, netns: Option<&str>, args: &[String]) -> Proc {
        Proc::start(name, self.command(netns, args))
    }

    /// `bridge certs --out dir [--host h]...`: a CA and two pairs.
    pub fn make_certs(&self, dir: &Path, hosts: &[&str]) -> PathBuf {
        let mut a = vec![
            "certs".to_string(),
            "--out".into(),
            dir.display().to_string(),
        ];
        for h in hosts {
            a.extend(["--host".to_string(), h.to_string()]);
        }
        let out = self.command(None, &a).output().expect("run bridge certs");
        assert!(
            out.status.success(),
            "certs: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir.to_path_buf()
    }
}

/// Arguments from string slices.
pub fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

/// Removes what dead nodes of the test's prefixes left and the prefixes' management segments,
/// also when an assertion failed (declare it first, so it drops after the children).
pub struct Cleanup(pub Vec<String>);

impl Drop for Cleanup {
    fn drop(&mut self) {
        for p in &self.0 {
            let _ = taxel_runtime::ipc::clean_dead_nodes(p);
            let _ = taxel_runtime::ipc::release_prefix(p);
        }
    }
}

pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// The `--tls-*` arguments for pair `who` ("server" or "client") of `dir`, trusting `ca`.
pub fn tls_args(dir: &Path, who: &str, ca: &Path) -> Vec<String> {
    vec![
        "--tls-cert".into(),
        dir.join(format!("{who}.pem")).display().to_string(),
        "--tls-key".into(),
        dir.join(format!("{who}.key")).display().to_string(),
        "--tls-ca".into(),
        ca.display().to_string(),
    ]
}

pub fn frame(seq: u64) -> RawFrame {
    let mut f = RawFrame::ZERO;
    f.seq = seq;
    f.sensor = sensor_id_bytes("glove0").expect("id");
    f.rows = 4;
    f.cols = 4;
    f.counts[0] = seq as f32;
    f.t_capture_ns = now_ns();
    f
}

/// Percentile `q` of sorted nanoseconds, in microseconds.
pub fn percentile_us(sorted: &[u64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * q / 100.0).round() as usize;
    sorted[i] as f64 / 1000.0
}

/// One frame as the far side saw it: seq, receipt time (ns, CLOCK_MONOTONIC), age (ns).
#[derive(Debug, Clone, Copy)]
pub struct Arrival {
    pub seq: u64,
    pub at_ns: u64,
    pub age_ns: u64,
}

/// A subscriber to `taxel/glove0/raw` in `prefix`, on a thread, recording every frame with
/// `seq >= from` until `stop`.
pub struct Receiver {
    pub arrivals: Arc<Mutex<Vec<Arrival>>>,
    pub stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl Receiver {
    /// Waits (up to `limit`) for the mirror in `prefix`, then starts recording.
    pub fn start(prefix: &str, from: u64, limit: Duration) -> Receiver {
        let config = taxel_runtime::ipc::config(prefix).expect("config");
        let name = ServiceName::new("taxel/glove0/raw").expect("name");
        let t0 = Instant::now();
        while !ipc::Service::does_exist(&name, &config, MessagingPattern::PublishSubscribe)
            .expect("does_exist")
        {
            assert!(
                t0.elapsed() < limit,
                "taxel/glove0/raw never appeared in {prefix}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let arrivals = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (a, s, p) = (arrivals.clone(), stop.clone(), prefix.to_string());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let handle = std::thread::spawn(move || {
            let ipc = Ipc::open(&p, "test-receiver").expect("node");
            let sub = ipc
                .subscriber::<RawFrame>("glove0", Stream::Raw)
                .expect("taxel's subscriber opens the mirror");
            ready_tx.send(()).expect("ready");
            while !s.load(Ordering::SeqCst) {
                let _ = sub.wait_wakeup(Duration::from_millis(20));
                let now = now_ns();
                let mut got = Vec::new();
                sub.poll_each(|f| {
                    if f.seq >= from {
                        got.push(Arrival {
                            seq: f.seq,
                            at_ns: now,
                            age_ns: now.saturating_sub(f.t_capture_ns),
                        });
                    }
                    Ok(())
                })
                .expect("receive");
                if !got.is_empty() {
                    a.lock().expect("lock").extend(got);
                }
            }
        });
        ready_rx
            .recv_timeout(limit)
            .expect("the receiver's subscriber is ready");
        Receiver {
            arrivals,
            stop,
            handle: Some(handle),
        }
    }

    pub fn snapshot(&self) -> Vec<Arrival> {
        self.arrivals.lock().expect("lock").clone()
    }

    pub fn finish(mut self) -> Vec<Arrival> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            h.join().expect("receiver thread");
        }
        self.snapshot()
    }
}

/// Sends raw frames `first..first + n` at `period` on an absolute schedule; calls `each(i)`
/// before frame `i` (for impairments at chosen times).
pub fn send_frames(
    publisher: &taxel_runtime::ipc::StreamPublisher<RawFrame>,
    first: u64,
    n: u64,
    period: Duration,
    mut each: impl FnMut(u64),
) -> Vec<u64> {
    let mut sent_at = Vec::with_capacity(n as usize);
    let t0 = Instant::now();
    for i in 0..n {
        each(i);
        let due = t0 + period * i as u32;
        if let Some(w) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(w);
        }
        sent_at.push(now_ns());
        publisher.send(&frame(first + i)).expect("send");
    }
    sent_at
}

/// Publishes frames until `ok()` says the far side got one (the bridges' ports connect on
/// first use); returns the next seq.
pub fn warm_up(
    publisher: &taxel_runtime::ipc::StreamPublisher<RawFrame>,
    rx: &Receiver,
    limit: Duration,
    what: &mut dyn FnMut() -> String,
) -> u64 {
    let t0 = Instant::now();
    let mut seq = 1;
    while rx.snapshot().is_empty() {
        assert!(
            t0.elapsed() < limit,
            "no frame crossed in {limit:?}\n{}",
            what()
        );
        publisher.send(&frame(seq)).expect("send");
        seq += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(200));
    seq + 1000
}

/// Counts of what arrived of `first..first + n`.
#[derive(Debug, Default)]
pub struct Delivery {
    pub received: u64,
    pub duplicates: u64,
    pub out_of_order: u64,
    /// Runs of missing seqs: (first missing, how many).
    pub gaps: Vec<(u64, u64)>,
}

pub fn delivery(arr: &[Arrival], first: u64, n: u64) -> Delivery {
    let mut d = Delivery::default();
    let mut seen = std::collections::BTreeSet::new();
    let mut last = None;
    for a in arr.iter().filter(|a| a.seq >= first && a.seq < first + n) {
        if !seen.insert(a.seq) {
            d.duplicates += 1;
            continue;
        }
        if last.is_some_and(|l| a.seq < l) {
            d.out_of_order += 1;
        }
        last = Some(a.seq);
    }
    d.received = seen.len() as u64;
    let mut expect = first;
    for &s in &seen {
        if s > expect {
            d.gaps.push((expect, s - expect));
        }
        expect = s + 1;
    }
    if expect < first + n {
        d.gaps.push((expect, first + n - expect));
    }
    d
}

/// What a pair of bridges relayed: the delivery of the measured frames, their ages (sorted),
/// and both bridges, still running.
pub struct Relayed {
    pub delivery: Delivery,
    pub ages: Vec<u64>,
    pub a: Proc,
    pub b: Proc,
}

/// Bridge B (listening, in `netns[1]`) and bridge A (connecting, in `netns[0]`), each on
/// prefix `{tag}b_` / `{tag}a_` with `--allow 'taxel/glove0/*'` and its own `b_args` /
/// `a_args`; after a warm-up, `n` raw frames at 1 kHz from domain A to domain B.
pub fn relay_pair(
    exe: &BridgeExe,
    tag: &str,
    netns: [Option<&str>; 2],
    b_args: &[String],
    a_args: &[String],
    n: u64,
) -> Relayed {
    let (pa, pb) = (format!("{tag}a_"), format!("{tag}b_"));
    let allow = "taxel/glove0/*";
    let mut args_b = args(&["--prefix", &pb, "--allow", allow]);
    args_b.extend_from_slice(b_args);
    let mut b = exe.spawn(&format!("bridge B ({tag})"), netns[1], &args_b);
    b.wait_for("bridge ready", Duration::from_secs(20));
    let mut args_a = args(&["--prefix", &pa, "--allow", allow]);
    args_a.extend_from_slice(a_args);
    let mut a = exe.spawn(&format!("bridge A ({tag})"), netns[0], &args_a);
    a.wait_for("zenoh peers connected: 1", Duration::from_secs(20));
    let ipc_a = Ipc::open(&pa, "test-publisher").expect("node A");
    let publisher = ipc_a
        .publisher::<RawFrame>("glove0", Stream::Raw)
        .expect("publisher A");
    let rx = Receiver::start(&pb, 1, Duration::from_secs(25));
    let first = warm_up(&publisher, &rx, Duration::from_secs(20), &mut || {
        a.pump();
        b.pump();
        format!("A:\n{}\nB:\n{}", a.seen.join("\n"), b.seen.join("\n"))
    });
    send_frames(&publisher, first, n, Duration::from_millis(1), |_| {});
    std::thread::sleep(Duration::from_millis(500));
    let arr = rx.finish();
    let mut ages: Vec<u64> = arr
        .iter()
        .filter(|x| x.seq >= first && x.seq < first + n)
        .map(|x| x.age_ns)
        .collect();
    ages.sort_unstable();
    Relayed {
        delivery: delivery(&arr, first, n),
        ages,
        a,
        b,
    }
}
