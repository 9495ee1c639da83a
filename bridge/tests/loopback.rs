//! Two `taxel-bridge` processes on loopback join two iceoryx2 domains (two service prefixes on
//! one host, which do not see each other's services). A publisher in domain A sends raw frames
//! at 1 kHz; a subscriber in domain B must receive them all (loss bound below), strictly in
//! order, woken by the relayed events; a subscriber in domain A must see each frame exactly once
//! (no echo from B). Loss and latency (capture to receipt in B, one clock) are printed, and the
//! bridges' own reports are checked.

use std::net::TcpListener;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::channel;
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::messaging_pattern::MessagingPattern;
use taxel_msgs::{RawFrame, Stream};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::now_ns;
use taxel_testkit::Proc;

mod common;
use common::{args, frame, free_port, percentile_us, Cleanup, BRIDGE};

/// Frames measured.
const FRAMES: u64 = 2000;
/// Their period (1 kHz, a glove's rate).
const PERIOD: Duration = Duration::from_millis(1);
/// Frames the test tolerates losing over the link (0.5 %): the Zenoh carrier buffers 64 frames
/// (the streams 256), so a loss means a bridge stalled for more than about 64 ms. Every loss is
/// reported.
const MAX_LOST: u64 = FRAMES / 200;

/// Starts `taxel-bridge args...` on this host.
fn spawn(name: &str, a: &[&str]) -> Proc {
    common::spawn(name, None, &args(a))
}

/// What domain B's subscriber saw of the measured frames.
struct Received {
    seqs: Vec<u64>,
    ages_ns: Vec<u64>,
    wakeups: u64,
}

/// Domain B's subscriber: waits for the mirror of `taxel/glove0/raw`, opens it with taxel's own
/// settings (so the mirror's QoS must fit), reports readiness, then collects frames with
/// `seq >= start` until `done` and the last one arrived (or 5 s after `done`).
fn receiver(
    prefix: String,
    ready: std::sync::mpsc::Sender<()>,
    got_any: Arc<AtomicBool>,
    start: Arc<AtomicU64>,
    done: Arc<AtomicBool>,
) -> Received {
    let config = taxel_runtime::ipc::config(&prefix).expect("config");
    let name = ServiceName::new("taxel/glove0/raw").expect("name");
    let t0 = Instant::now();
    while !ipc::Service::does_exist(&name, &config, MessagingPattern::PublishSubscribe)
        .expect("does_exist")
    {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the mirror of taxel/glove0/raw never appeared in domain B"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let ipc = Ipc::open(&prefix, "test-receiver").expect("node B");
    let sub = ipc
        .subscriber::<RawFrame>("glove0", Stream::Raw)
        .expect("taxel's subscriber opens the mirror");
    ready.send(()).expect("ready");
    let mut r = Received {
        seqs: Vec::new(),
        ages_ns: Vec::new(),
        wakeups: 0,
    };
    let mut done_at = None;
    loop {
        let mut n = 0;
        let _ = sub
            .listener()
            .expect("a subscriber with a listener")
            .timed_wait(|_| n += 1, Duration::from_millis(50));
        r.wakeups += n;
        let first = start.load(Ordering::SeqCst);
        sub.poll_each(|f| {
            got_any.store(true, Ordering::SeqCst);
            if first > 0 && f.seq >= first {
                r.seqs.push(f.seq);
                r.ages_ns.push(now_ns().saturating_sub(f.t_capture_ns));
            }
            Ok(())
        })
        .expect("receive");
        if done.load(Ordering::SeqCst) {
            let at = *done_at.get_or_insert_with(Instant::now);
            if r.seqs.last() == Some(&(first + FRAMES - 1)) || at.elapsed() > Duration::from_secs(5)
            {
                return r;
            }
        }
    }
}

#[test]
fn frames_cross_between_two_domains_in_order_without_echo() {
    let tag = format!("tbr{}", std::process::id());
    let (pa, pb) = (format!("{tag}a_"), format!("{tag}b_"));
    let _cleanup = Cleanup(vec![pa.clone(), pb.clone()]);
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let allow = "taxel/glove0/*";

    let mut b = spawn(
        "bridge B",
        &[
            "--prefix",
            &pb,
            "--allow",
            allow,
            "--listen",
            &endpoint,
            "--report-s",
            "1",
        ],
    );
    b.wait_for("bridge ready", Duration::from_secs(20));
    let mut a = spawn(
        "bridge A",
        &[
            "--prefix",
            &pa,
            "--allow",
            allow,
            "--connect",
            &endpoint,
            "--report-s",
            "1",
        ],
    );
    a.wait_for("zenoh peers connected: 1", Duration::from_secs(20));

    let ipc_a = Ipc::open(&pa, "test-publisher").expect("node A");
    let publisher = ipc_a
        .publisher::<RawFrame>("glove0", Stream::Raw)
        .expect("publisher A");
    // Domain A's own subscriber: a frame echoed back by B would show up twice here.
    let echo_watch = ipc_a
        .subscriber::<RawFrame>("glove0", Stream::Raw)
        .expect("subscriber A");

    let (ready_tx, ready_rx) = channel();
    let got_any = Arc::new(AtomicBool::new(false));
    let start = Arc::new(AtomicU64::new(0));
    let done = Arc::new(AtomicBool::new(false));
    let rx = {
        let (pb, got_any, start, done) = (pb.clone(), got_any.clone(), start.clone(), done.clone());
        std::thread::spawn(move || receiver(pb, ready_tx, got_any, start, done))
    };
    ready_rx
        .recv_timeout(Duration::from_secs(25))
        .expect("domain B's subscriber is ready");

    // Warm up until a frame has crossed: the bridges' ports connect on first use.
    let mut seq = 1;
    let t0 = Instant::now();
    while !got_any.load(Ordering::SeqCst) {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "no frame crossed in 20 s\nA:\n{}\nB:\n{}",
            {
                a.pump();
                a.seen.join("\n")
            },
            {
                b.pump();
                b.seen.join("\n")
            }
        );
        publisher.send(&frame(seq)).expect("send");
        seq += 1;
        let _ = echo_watch.poll_each(|_| Ok(()));
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(100));
    let _ = echo_watch.poll_each(|_| Ok(()));

    // The measured run: FRAMES frames at 1 kHz on an absolute schedule.
    let first = seq;
    start.store(first, Ordering::SeqCst);
    let mut seen_in_a = Vec::new();
    let t_start = Instant::now();
    for i in 0..FRAMES {
        let due = t_start + PERIOD * i as u32;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        publisher.send(&frame(first + i)).expect("send");
        echo_watch
            .poll_each(|f| {
                seen_in_a.push(f.seq);
                Ok(())
            })
            .expect("receive A");
    }
    let send_s = t_start.elapsed().as_secs_f64();
    done.store(true, Ordering::SeqCst);
    let r = rx.join().expect("receiver thread");
    // Anything B sent back would have arrived by now.
    std::thread::sleep(Duration::from_millis(300));
    echo_watch
        .poll_each(|f| {
            seen_in_a.push(f.seq);
            Ok(())
        })
        .expect("receive A");

    // Order: strictly increasing in B.
    for w in r.seqs.windows(2) {
        assert!(
            w[1] > w[0],
            "out of order in domain B: {} after {}",
            w[1],
            w[0]
        );
    }
    let lost = FRAMES - r.seqs.len() as u64;
    let mut ages = r.ages_ns.clone();
    ages.sort_unstable();
    assert!(!ages.is_empty(), "no measured frame arrived in domain B");
    println!(
        "bridge loopback: {FRAMES} frames at 1 kHz sent in {send_s:.2} s; received {} in domain B, lost {lost} ({:.2} %), {} event wake-ups; latency capture->B p50 {:.0} us, p90 {:.0} us, p99 {:.0} us, max {:.0} us",
        r.seqs.len(),
        lost as f64 * 100.0 / FRAMES as f64,
        r.wakeups,
        percentile_us(&ages, 50.0),
        percentile_us(&ages, 90.0),
        percentile_us(&ages, 99.0),
        percentile_us(&ages, 100.0),
    );
    let mut gaps = Vec::new();
    let mut expect = first;
    for &s in &r.seqs {
        if s > expect {
            gaps.push(format!(
                "{}..{} ({} frames, at +{} ms)",
                expect,
                s - 1,
                s - expect,
                expect - first
            ));
        }
        expect = s + 1;
    }
    if expect < first + FRAMES {
        gaps.push(format!(
            "{}.. (the last {} frames)",
            expect,
            first + FRAMES - expect
        ));
    }
    if !gaps.is_empty() {
        println!("frames missing in domain B: {}", gaps.join(", "));
    }
    let slow: Vec<String> = r
        .seqs
        .iter()
        .zip(&r.ages_ns)
        .filter(|(_, a)| **a > 10_000_000)
        .map(|(s, a)| format!("{}:{}ms", s - first, a / 1_000_000))
        .take(20)
        .collect();
    if !slow.is_empty() {
        println!(
            "frames older than 10 ms on arrival (index:age): {}",
            slow.join(" ")
        );
    }
    assert!(
        r.wakeups > 0,
        "no relayed event woke the subscriber in domain B"
    );

    // No echo: domain A saw each of its own frames exactly once.
    let measured_a: Vec<u64> = seen_in_a.into_iter().filter(|s| *s >= first).collect();
    let expected: Vec<u64> = (first..first + FRAMES).collect();
    assert_eq!(
        measured_a.len(),
        expected.len(),
        "domain A saw {} frames for {FRAMES} sent (an echo doubles them)",
        measured_a.len()
    );
    assert_eq!(
        measured_a, expected,
        "domain A's frames changed order or repeated"
    );

    // Both bridges stop on SIGINT with exit 0 and report what crossed.
    drop(publisher);
    drop(echo_watch);
    drop(ipc_a);
    let (sa, sb) = (a.stop(), b.stop());
    assert!(sa.success(), "bridge A: {sa}\n{}", a.seen.join("\n"));
    assert!(sb.success(), "bridge B: {sb}\n{}", b.seen.join("\n"));
    let line = |p: &Proc, dir: &str| {
        p.seen
            .iter()
            .find(|l| {
                l.trim_start()
                    .starts_with(&format!("{dir} taxel/glove0/raw: samples"))
            })
            .cloned()
            .unwrap_or_else(|| panic!("{}: no {dir} report:\n{}", p.name, p.seen.join("\n")))
    };
    let (out_a, in_b) = (line(&a, "out"), line(&b, "in"));
    println!("bridge A: {}\nbridge B: {}", out_a.trim(), in_b.trim());
    for p in [&a, &b] {
        for l in p.seen.iter().filter(|l| l.contains("WARN")) {
            println!("{}: {l}", p.name);
        }
    }
    let samples = |l: &str| -> u64 {
        l.split("samples ")
            .nth(1)
            .and_then(|r| r.split(',').next())
            .and_then(|n| n.parse().ok())
            .expect("sample count")
    };
    assert!(
        lost <= MAX_LOST,
        "lost {lost} of {FRAMES} frames (bound {MAX_LOST})"
    );
    assert!(samples(&out_a) >= FRAMES, "{out_a}");
    assert!(samples(&in_b) + MAX_LOST >= FRAMES, "{in_b}");
    assert!(in_b.contains("out of order 0"), "{in_b}");

    // Both bridges stopped cleanly: once the prefixes are released nothing is left in /dev/shm.
    drop(_cleanup);
    let left: Vec<String> = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(&pa) || n.starts_with(&pb))
                .collect()
        })
        .unwrap_or_default();
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
}

/// Bad arguments end with exit 2 and one line naming the flag; a taken port with exit 1.
#[test]
fn bad_arguments_are_refused_in_one_line() {
    for (args, needle) in [
        (vec!["--listen", "tcp/127.0.0.1:7447"], "--allow"),
        (
            vec![
                "--allow",
                "taxel/glove 0/*",
                "--listen",
                "tcp/127.0.0.1:7447",
            ],
            "--allow",
        ),
        (
            vec!["--allow", "taxel/*", "--listen", "udp/127.0.0.1:7447"],
            "--listen",
        ),
        (
            vec!["--allow", "taxel/*", "--connect", "tcp/127.0.0.1"],
            "--connect",
        ),
        (vec!["--allow", "taxel/*"], "--listen, --connect"),
        // Plain TCP: a network address needs --insecure-listen (or tls/ with certificates).
        (
            vec!["--allow", "taxel/*", "--listen", "tcp/0.0.0.0:7447"],
            "--insecure-listen",
        ),
        (
            vec![
                "--allow",
                "taxel/*",
                "--listen",
                "tcp/127.0.0.1:7447",
                "--report-s",
                "0",
            ],
            "--report-s",
        ),
    ] {
        let out = Command::new(BRIDGE)
            .args(&args)
            .env_remove("TAXEL_PREFIX")
            .output()
            .expect("run taxel-bridge");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }

    // A listen port another process holds: a runtime failure, one line, exit 1.
    let holder = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = holder.local_addr().expect("addr").port();
    let prefix = format!("tbr{}x_", std::process::id());
    let _cleanup = Cleanup(vec![prefix.clone()]);
    let out = Command::new(BRIDGE)
        .args(["--prefix", &prefix, "--allow", "taxel/*", "--listen"])
        .arg(format!("tcp/127.0.0.1:{port}"))
        .env("RUST_LOG", "off")
        .output()
        .expect("run taxel-bridge");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("zenoh"), "{err}");
}
