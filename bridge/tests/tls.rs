//! Two `taxel-bridge` processes on loopback with certificates of one CA (`taxel-bridge certs`)
//! relay 1 kHz raw frames over Zenoh's TLS transport, in order; the same over plain TCP in the
//! same run, for the cost of TLS (printed, not asserted). Then two strangers connect to the
//! listening bridge, each with a publisher of the same stream in its own domain: one with a
//! certificate of another CA (it trusts the listener's CA, so only the listener can refuse it),
//! one with no certificate at all. Both are refused and logged, and none of their frames
//! reaches the listener's domain.

mod common;

use std::time::Duration;

use common::*;
use taxel_msgs::{RawFrame, Stream};
use taxel_runtime::ipc::Ipc;
use taxel_testkit::Proc;

/// Frames measured per transport.
const FRAMES: u64 = 2000;
/// Frames tolerated lost (0.5 %, as in loopback.rs).
const MAX_LOST: u64 = FRAMES / 200;
/// Seqs the strangers publish (never sent by domain A).
const STRANGER_SEQ: u64 = 1_000_000;

struct Measured {
    d: Delivery,
    ages: Vec<u64>,
}

/// Two bridges (B listens, A connects), FRAMES frames from domain A to domain B.
fn relay(tag: &str, listen: &[String], connect: &[String], keep: bool) -> (Measured, Proc, Proc) {
    let report = args(&["--report-s", "1"]);
    let with = |extra: &[String]| [report.clone(), extra.to_vec()].concat();
    let Relayed {
        delivery: d,
        ages,
        mut a,
        mut b,
    } = relay_pair(
        &BridgeExe::standalone(BRIDGE),
        tag,
        [None, None],
        &with(listen),
        &with(connect),
        FRAMES,
    );
    if !keep {
        let (sa, sb) = (a.stop(), b.stop());
        assert!(sa.success(), "bridge A: {sa}\n{}", a.seen.join("\n"));
        assert!(sb.success(), "bridge B: {sb}\n{}", b.seen.join("\n"));
    }
    (Measured { d, ages }, a, b)
}

fn report(kind: &str, m: &Measured) {
    println!(
        "bridge {kind} on loopback: {FRAMES} frames at 1 kHz, received {}, lost {}, out of order {}, duplicates {}; age p50 {:.0} us, p90 {:.0} us, p99 {:.0} us, max {:.0} us",
        m.d.received,
        FRAMES - m.d.received,
        m.d.out_of_order,
        m.d.duplicates,
        percentile_us(&m.ages, 50.0),
        percentile_us(&m.ages, 90.0),
        percentile_us(&m.ages, 99.0),
        percentile_us(&m.ages, 100.0),
    );
}

fn check(kind: &str, m: &Measured) {
    assert!(
        FRAMES - m.d.received <= MAX_LOST,
        "{kind}: lost {} of {FRAMES} (bound {MAX_LOST}): gaps {:?}",
        FRAMES - m.d.received,
        m.d.gaps
    );
    assert_eq!(m.d.out_of_order, 0, "{kind}: frames out of order");
    assert_eq!(m.d.duplicates, 0, "{kind}: frames repeated");
}

/// A stranger: a bridge in its own domain `prefix` connecting to `endpoint` with `extra`
/// arguments, and a publisher of `taxel/glove0/raw` there.
struct Stranger {
    bridge: Proc,
    _ipc: Ipc,
    publisher: taxel_runtime::ipc::StreamPublisher<RawFrame>,
}

fn stranger(name: &str, prefix: &str, endpoint: &str, extra: &[String]) -> Stranger {
    let mut a = args(&[
        "--prefix",
        prefix,
        "--allow",
        "taxel/glove0/*",
        "--connect",
        endpoint,
    ]);
    a.extend_from_slice(extra);
    let mut bridge = spawn(name, None, &a);
    bridge.wait_for("bridge ready", Duration::from_secs(20));
    let ipc = Ipc::open(prefix, "test-stranger").expect("stranger node");
    let publisher = ipc
        .publisher::<RawFrame>("glove0", Stream::Raw)
        .expect("stranger publisher");
    Stranger {
        bridge,
        _ipc: ipc,
        publisher,
    }
}

#[test]
fn frames_cross_over_tls_and_strangers_are_refused() {
    let tag = format!("ttl{}", std::process::id());
    let prefixes: Vec<String> = ["pa_", "pb_", "ta_", "tb_", "sc_", "sd_"]
        .iter()
        .map(|s| format!("{tag}{s}"))
        .collect();
    let _cleanup = Cleanup(prefixes);
    let dir = tempfile::tempdir().expect("dir");
    let ca1 = make_certs(&dir.path().join("ca1"), &[]);
    let ca2 = make_certs(&dir.path().join("ca2"), &[]);
    let both = dir.path().join("both.pem");
    let text = |p: std::path::PathBuf| std::fs::read_to_string(p).expect("read");
    std::fs::write(&both, text(ca1.join("ca.pem")) + &text(ca2.join("ca.pem"))).expect("write");

    // Plain TCP first, for comparison.
    let port = free_port();
    let tcp = format!("tcp/127.0.0.1:{port}");
    let (m_tcp, _, _) = relay(
        &format!("{tag}p"),
        &args(&["--listen", &tcp]),
        &args(&["--connect", &tcp]),
        false,
    );
    report("TCP", &m_tcp);

    // TLS with mutual authentication; B keeps listening for the strangers.
    let port = free_port();
    let tls = format!("tls/127.0.0.1:{port}");
    let mut listen = args(&["--listen", &tls]);
    listen.extend(tls_args(&ca1, "server", &ca1.join("ca.pem")));
    let mut connect = args(&["--connect", &tls]);
    connect.extend(tls_args(&ca1, "client", &ca1.join("ca.pem")));
    let (m_tls, mut a, mut b) = relay(&format!("{tag}t"), &listen, &connect, true);
    report("TLS", &m_tls);
    println!(
        "TLS / TCP age p50: {:.2} (p99 {:.2})",
        percentile_us(&m_tls.ages, 50.0) / percentile_us(&m_tcp.ages, 50.0),
        percentile_us(&m_tls.ages, 99.0) / percentile_us(&m_tcp.ages, 99.0),
    );
    check("TCP", &m_tcp);
    check("TLS", &m_tls);

    // The strangers: another CA's certificate (trusting both CAs, so its own checks pass and
    // only the listener can refuse it), and no certificate (a Zenoh file with the CA only).
    let zfile = dir.path().join("nocert.json5");
    std::fs::write(
        &zfile,
        format!(
            r#"{{ listen: {{ endpoints: [] }}, transport: {{ link: {{ tls: {{ root_ca_certificate: "{}" }} }} }} }}"#,
            ca1.join("ca.pem").display()
        ),
    )
    .expect("write");
    let watch = Receiver::start(&format!("{tag}tb_"), STRANGER_SEQ, Duration::from_secs(5));
    let mut c_extra = tls_args(&ca2, "client", &both);
    c_extra.push("--report-s".into());
    c_extra.push("1".into());
    let mut c = stranger(
        "stranger C (other CA)",
        &format!("{tag}sc_"),
        &tls,
        &c_extra,
    );
    let mut d = stranger(
        "stranger D (no certificate)",
        &format!("{tag}sd_"),
        &tls,
        &args(&["--zenoh-config", &zfile.display().to_string()]),
    );
    for i in 0..300 {
        c.publisher.send(&frame(STRANGER_SEQ + i)).expect("send C");
        d.publisher
            .send(&frame(STRANGER_SEQ + 10_000 + i))
            .expect("send D");
        std::thread::sleep(Duration::from_millis(10));
    }
    b.wait_count("refused a peer", 2, Duration::from_secs(10));
    let leaked = watch.finish();
    let (sc, sd) = (c.bridge.stop(), d.bridge.stop());
    let (sa, sb) = (a.stop(), b.stop());
    for p in [&c.bridge, &d.bridge] {
        assert!(
            !p.seen
                .iter()
                .any(|l| l.contains("zenoh peers connected: 1")),
            "{} got connected:\n{}",
            p.name,
            p.seen.join("\n")
        );
    }
    assert!(sc.success() && sd.success(), "strangers: {sc} {sd}");
    assert!(sa.success(), "bridge A: {sa}\n{}", a.seen.join("\n"));
    assert!(sb.success(), "bridge B: {sb}\n{}", b.seen.join("\n"));
    let refusals: Vec<&String> = b
        .seen
        .iter()
        .filter(|l| l.contains("refused a peer"))
        .collect();
    for l in refusals.iter().take(4) {
        println!("bridge B: {}", l.trim());
    }
    let why = |needle: &str| refusals.iter().any(|l| l.contains(needle));
    assert!(
        why("BadSignature") || why("UnknownIssuer"),
        "no refusal of the other CA's certificate:\n{}",
        b.seen.join("\n")
    );
    assert!(
        why("no certificates"),
        "no refusal of the peer without a certificate:\n{}",
        b.seen.join("\n")
    );
    let counted = b.last_line("refused TLS peers:");
    println!("bridge B: {}", counted.trim());
    let n: u64 = counted
        .rsplit(' ')
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(n >= 2, "refusals not counted: {counted:?}");
    assert!(
        leaked.is_empty(),
        "{} frames of the strangers reached domain B (first seq {})",
        leaked.len(),
        leaked[0].seq
    );
}

/// Bad TLS arguments: one line naming the flag and the file, exit 2, no panic.
#[test]
fn bad_tls_files_are_refused_in_one_line() {
    let dir = tempfile::tempdir().expect("dir");
    let ca = make_certs(&dir.path().join("ca"), &[]);
    let other = make_certs(&dir.path().join("other"), &[]);
    let f = |d: &std::path::Path, n: &str| d.join(n).display().to_string();
    let base = |cert: String, key: String, ca_file: String| {
        args(&[
            "--allow",
            "taxel/*",
            "--listen",
            "tls/0.0.0.0:7447",
            "--tls-cert",
            &cert,
            "--tls-key",
            &key,
            "--tls-ca",
            &ca_file,
        ])
    };
    let missing = f(&ca, "missing.pem");
    for (a, needle) in [
        (
            base(missing.clone(), f(&ca, "server.key"), f(&ca, "ca.pem")),
            format!("--tls-cert {missing}"),
        ),
        (
            base(f(&ca, "server.pem"), f(&ca, "client.key"), f(&ca, "ca.pem")),
            format!("--tls-key {}", f(&ca, "client.key")),
        ),
        (
            base(f(&ca, "server.pem"), f(&ca, "server.pem"), f(&ca, "ca.pem")),
            "--tls-key".to_string(),
        ),
        (
            base(f(&ca, "server.key"), f(&ca, "server.key"), f(&ca, "ca.pem")),
            "--tls-cert".to_string(),
        ),
        (
            base(f(&ca, "server.pem"), f(&ca, "server.key"), f(&ca, "ca.key")),
            "--tls-ca".to_string(),
        ),
        (
            base(
                f(&ca, "server.pem"),
                f(&ca, "server.key"),
                f(&other, "ca.pem"),
            ),
            format!("--tls-cert {}", f(&ca, "server.pem")),
        ),
        (
            args(&[
                "--allow",
                "taxel/*",
                "--listen",
                "tls/0.0.0.0:7447",
                "--tls-cert",
                &f(&ca, "server.pem"),
            ]),
            "--tls-key, --tls-ca".to_string(),
        ),
        (
            args(&["--allow", "taxel/*", "--listen", "tls/0.0.0.0:7447"]),
            "--tls-cert".to_string(),
        ),
        (
            args(&["certs", "--out", &f(&ca, ""), "--host", "a b"]),
            "--host".to_string(),
        ),
        (
            args(&["certs", "--out", &f(&ca, "")]),
            "--force".to_string(),
        ),
    ] {
        let out = bridge_cmd(None, &a).output().expect("run taxel-bridge");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{a:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{a:?}: {err}");
        assert!(err.contains(&needle), "{a:?}: {needle:?} not in {err}");
        assert!(!err.contains("panicked"), "{a:?}: {err}");
    }
}
