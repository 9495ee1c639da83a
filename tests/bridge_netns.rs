//! Two hosts in one machine: network namespaces A and B, one `taxel bridge` in each (B listens
//! on tls/0.0.0.0, A connects to B's address, certificates of one CA), the glove's publisher in
//! domain A, and in domain B a far-side receiver and a `taxel logger` (iceoryx2 runs on shared
//! memory, which the namespaces share; only the bridges' traffic crosses between them).
//!
//! A and B are joined by a link emulated in user space (taxel-testkit `netem`: two TUN devices
//! and a thread between them; the development VM's kernel has no `sch_netem`): 5 ms delay each
//! way and 1 % of the packets dropped at random, then cut for 3 s (every packet dropped, both
//! ways) and restored. A third namespace C, joined to B by a veth pair, runs a bridge without a
//! certificate and a publisher of the same stream: it is refused and delivers nothing.
//!
//! Measured and printed: loss outside the cut, reordering, age p50/p99, reconnection time after
//! the cut (link restored to the first frame arriving). Asserted: >= 99 % delivered outside the
//! cut, every frame in order and at most once, the far bridge's own report counts a loss
//! whenever frames are missing, the far logger's file marks every hole with `GAP_BEFORE`
//! (never a silent hole), C refused and silent. Then, over the same impaired link without a
//! cut, a fresh pair of bridges over plain TCP and one over TLS each relay 3 000 frames: the
//! ratio of their age percentiles is printed (the cost of TLS on this link), and each must
//! deliver >= 99 % in order. Skipped with a message where network
//! namespaces or TUN devices cannot be created (not root, no `ip`, no /dev/net/tun).

use std::process::Command;
use std::time::Duration;

use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::{raw_flags, RawFrame, Stream};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::now_ns;
use taxel_testkit::netem::{End, Impairment, Link};
use taxel_testkit::relay::*;
use taxel_testkit::Proc;

const TAXEL: &str = env!("CARGO_BIN_EXE_taxel");

fn bridge() -> BridgeExe {
    BridgeExe::launcher(TAXEL)
}

fn spawn(name: &str, netns: Option<&str>, args: &[String]) -> Proc {
    bridge().spawn(name, netns, args)
}

/// Frames at 1 kHz: 4 s before the cut, 3 s cut, 6 s after.
const FRAMES: u64 = 13_000;
const CUT_AT: u64 = 4_000;
const CUT_MS: u64 = 3_000;
/// Frames sent this long after the link returns count as "outside the cut" (the target
/// reconnection time).
const RECONNECT_ALLOWANCE_MS: u64 = 2_000;
const STRANGER_SEQ: u64 = 1_000_000;

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {args:?}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// The namespaces of one run; deleted (with their veths) on drop.
struct Net {
    ns: Vec<String>,
}

impl Drop for Net {
    fn drop(&mut self) {
        for n in &self.ns {
            let _ = ip(&["netns", "del", n]);
        }
    }
}

/// Creates namespaces a, b, c and the veth pair c<->b (10.X.2.3 / 10.X.2.2). Returns None
/// (after printing why) where namespaces cannot be made.
fn setup(tag: &str, x: u32) -> Option<(Net, [String; 3])> {
    let names = [format!("{tag}a"), format!("{tag}b"), format!("{tag}c")];
    let mut net = Net { ns: Vec::new() };
    for n in &names {
        if let Err(e) = ip(&["netns", "add", n]) {
            println!("SKIPPED: cannot create network namespaces here ({e})");
            return None;
        }
        net.ns.push(n.clone());
    }
    let [a, b, c] = &names;
    let (vc, vb2) = (format!("{tag}vc"), format!("{tag}vd"));
    let (addr_c, addr_b) = (format!("10.{x}.2.3/24"), format!("10.{x}.2.2/24"));
    let steps: [&[&str]; 10] = [
        &["link", "add", &vc, "type", "veth", "peer", "name", &vb2],
        &["link", "set", &vc, "netns", c],
        &["link", "set", &vb2, "netns", b],
        &["-n", c, "addr", "add", &addr_c, "dev", &vc],
        &["-n", b, "addr", "add", &addr_b, "dev", &vb2],
        &["-n", c, "link", "set", &vc, "up"],
        &["-n", b, "link", "set", &vb2, "up"],
        &["-n", a, "link", "set", "lo", "up"],
        &["-n", b, "link", "set", "lo", "up"],
        &["-n", c, "link", "set", "lo", "up"],
    ];
    for s in steps {
        if let Err(e) = ip(s) {
            println!("SKIPPED: cannot set up the veth links here ({e})");
            return None;
        }
    }
    Some((net, names))
}

/// The far logger's record file: (seq, GAP_BEFORE) of each raw frame of the measured run.
fn logged_raw(path: &std::path::Path, first: u64, n: u64) -> Vec<(u64, bool)> {
    RecordFileReader::open(path)
        .expect("the far logger's file")
        .filter_map(|r| match r {
            Record::Raw(f) if f.seq >= first && f.seq < first + n => {
                Some((f.seq, f.flags & raw_flags::GAP_BEFORE != 0))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn two_hosts_over_an_impaired_link_with_a_cut() {
    let pid = std::process::id();
    let tag = format!("tn{}", pid % 100_000);
    let x = 100 + pid % 100;
    let Some((_net, [ns_a, ns_b, ns_c])) = setup(&tag, x) else {
        return;
    };
    let (ip_a, ip_b, ip_b2) = (
        format!("10.{x}.1.1"),
        format!("10.{x}.1.2"),
        format!("10.{x}.2.2"),
    );
    let (ta, tb) = (format!("{tag}ta"), format!("{tag}tb"));
    let link = match Link::start(
        End {
            netns: &ns_a,
            device: &ta,
            address: &ip_a,
        },
        End {
            netns: &ns_b,
            device: &tb,
            address: &ip_b,
        },
        Impairment::default(),
        u64::from(pid),
    ) {
        Ok(l) => l,
        Err(e) => {
            println!("SKIPPED: cannot create the emulated link (TUN devices) here ({e})");
            return;
        }
    };
    let (pa, pb, pc) = (format!("{tag}a_"), format!("{tag}b_"), format!("{tag}c_"));
    let _cleanup = Cleanup(vec![pa.clone(), pb.clone(), pc.clone()]);
    let dir = tempfile::tempdir().expect("dir");
    let certs = bridge().make_certs(&dir.path().join("certs"), &[&ip_b, &ip_b2]);
    let ca = certs.join("ca.pem");

    let allow = "taxel/glove0/*";
    let mut b_args = args(&[
        "--prefix",
        &pb,
        "--allow",
        allow,
        "--listen",
        "tls/0.0.0.0:7447",
        "--report-s",
        "2",
    ]);
    b_args.extend(tls_args(&certs, "server", &ca));
    let mut b = spawn("bridge B (ns b)", Some(&ns_b), &b_args);
    b.wait_for("bridge ready", Duration::from_secs(20));
    let endpoint = format!("tls/{ip_b}:7447");
    let mut a_args = args(&[
        "--prefix",
        &pa,
        "--allow",
        allow,
        "--connect",
        &endpoint,
        "--report-s",
        "2",
    ]);
    a_args.extend(tls_args(&certs, "client", &ca));
    let mut a = spawn("bridge A (ns a)", Some(&ns_a), &a_args);
    a.wait_for("zenoh peers connected: 1", Duration::from_secs(20));

    // C: no certificate (a Zenoh file with the CA only), a publisher of the same stream.
    let zfile = dir.path().join("nocert.json5");
    std::fs::write(
        &zfile,
        format!(
            r#"{{ listen: {{ endpoints: [] }}, transport: {{ link: {{ tls: {{ root_ca_certificate: "{}" }} }} }} }}"#,
            ca.display()
        ),
    )
    .expect("write");
    let c_args = args(&[
        "--prefix",
        &pc,
        "--allow",
        allow,
        "--connect",
        &format!("tls/{ip_b2}:7447"),
        "--zenoh-config",
        &zfile.display().to_string(),
    ]);
    let mut c = spawn("bridge C (ns c, no certificate)", Some(&ns_c), &c_args);
    c.wait_for("bridge ready", Duration::from_secs(20));
    let ipc_c = Ipc::open(&pc, "test-stranger").expect("node C");
    let pub_c = ipc_c
        .publisher::<RawFrame>("glove0", Stream::Raw)
        .expect("publisher C");

    let ipc_a = Ipc::open(&pa, "test-publisher").expect("node A");
    let publisher = ipc_a
        .publisher::<RawFrame>("glove0", Stream::Raw)
        .expect("publisher A");
    let rx = Receiver::start(&pb, 1, Duration::from_secs(25));
    // The far side's logger, on the mirror the receiver waited for.
    let logged = dir.path().join("far.taxrec");
    let mut logger = Proc::start("far logger", {
        let mut cmd = Command::new(TAXEL);
        cmd.args([
            "logger", "--prefix", &pb, "record", "--sensor", "glove0", "--out",
        ])
        .arg(&logged)
        .env_remove("TAXEL_PREFIX");
        cmd
    });
    logger.wait_for("logger ready", Duration::from_secs(20));
    let first = warm_up(&publisher, &rx, Duration::from_secs(20), &mut || {
        a.pump();
        b.pump();
        format!("A:\n{}\nB:\n{}", a.seen.join("\n"), b.seen.join("\n"))
    });

    let impairment = "5 ms delay and 1 % loss each way (user-space link over TUN devices)";
    link.set_impairment(Impairment {
        delay: Duration::from_millis(5),
        loss: 0.01,
    });
    println!("link: {impairment}");

    let (mut cut_ns, mut restore_ns) = (0u64, 0u64);
    let sent_at = send_frames(&publisher, first, FRAMES, Duration::from_millis(1), |i| {
        if i == CUT_AT {
            cut_ns = now_ns();
            link.set_cut(true);
        }
        if i == CUT_AT + CUT_MS {
            restore_ns = now_ns();
            link.set_cut(false);
        }
        if i % 10 == 0 {
            let _ = pub_c.send(&frame(STRANGER_SEQ + i));
        }
    });
    std::thread::sleep(Duration::from_secs(2));
    let carried = link.stats();
    let arr = rx.finish();

    // Outside the cut: sent before it, or RECONNECT_ALLOWANCE_MS after the link returned.
    let allowance = restore_ns + RECONNECT_ALLOWANCE_MS * 1_000_000;
    let outside = |i: u64| sent_at[i as usize] < cut_ns || sent_at[i as usize] >= allowance;
    let ours: Vec<&Arrival> = arr
        .iter()
        .filter(|x| x.seq >= first && x.seq < first + FRAMES)
        .collect();
    let all = delivery(&arr, first, FRAMES);
    let n_outside = (0..FRAMES).filter(|&i| outside(i)).count() as u64;
    let got_outside = {
        let mut s: Vec<u64> = ours
            .iter()
            .filter(|x| outside(x.seq - first))
            .map(|x| x.seq)
            .collect();
        s.dedup();
        s.len() as u64
    };
    let mut ages: Vec<u64> = ours
        .iter()
        .filter(|x| outside(x.seq - first))
        .map(|x| x.age_ns)
        .collect();
    ages.sort_unstable();
    let reconnect_ms = ours
        .iter()
        .filter(|x| x.at_ns > restore_ns)
        .map(|x| x.at_ns)
        .min()
        .map(|t| (t - restore_ns) as f64 / 1e6);
    // Fresh data again: the first frame sent after the link returned, when it arrived.
    let fresh_ms = ours
        .iter()
        .filter(|x| sent_at[(x.seq - first) as usize] >= restore_ns)
        .map(|x| x.at_ns)
        .min()
        .map(|t| (t - restore_ns) as f64 / 1e6);
    let during: Vec<&Arrival> = ours
        .iter()
        .filter(|x| !outside(x.seq - first))
        .copied()
        .collect();
    let strangers = arr.iter().filter(|x| x.seq >= STRANGER_SEQ).count();

    drop(publisher);
    drop(ipc_a);
    drop(pub_c);
    drop(ipc_c);
    let (sl, sc, sa, sb) = (logger.stop(), c.stop(), a.stop(), b.stop());
    let file = logged_raw(&logged, first, FRAMES);

    println!(
        "two namespaces, TLS, 1 kHz for {} s ({impairment}), cut {} s at +{} s:",
        FRAMES / 1000,
        CUT_MS / 1000,
        CUT_AT / 1000
    );
    println!(
        "  outside the cut: {got_outside} of {n_outside} delivered ({:.2} %), age p50 {:.0} us, p99 {:.0} us, max {:.0} us",
        got_outside as f64 * 100.0 / n_outside as f64,
        percentile_us(&ages, 50.0),
        percentile_us(&ages, 99.0),
        percentile_us(&ages, 100.0),
    );
    println!(
        "  sent during the cut and the {RECONNECT_ALLOWANCE_MS} ms after: {} of {} delivered",
        during.len(),
        FRAMES - n_outside
    );
    println!(
        "  overall: received {} of {FRAMES}, out of order {}, duplicates {}, gaps {:?}",
        all.received, all.out_of_order, all.duplicates, all.gaps
    );
    match (reconnect_ms, fresh_ms) {
        (Some(ms), Some(f)) => println!(
            "  reconnection: first frame {ms:.0} ms after the link returned, first frame sent after the return arrived at +{f:.0} ms"
        ),
        _ => println!("  reconnection: nothing arrived after the link returned"),
    }
    let sessions = a
        .seen
        .iter()
        .filter(|l| l.contains("zenoh peers connected"))
        .count();
    println!("  bridge A logged {sessions} change(s) of its peer count (3: the session closed after the lease and was opened again; 1: it survived the cut)");
    let b_in = b.last_line("in taxel/glove0/raw");
    println!("  bridge B: {}", b_in.trim());
    println!("  bridge A: {}", a.last_line("out taxel/glove0/raw").trim());
    println!(
        "  link: {} packets carried, {} dropped at random, {} dropped in the cut",
        carried.carried, carried.dropped_at_random, carried.dropped_in_cut
    );
    let holes: Vec<u64> = file
        .windows(2)
        .filter(|w| w[1].0 != w[0].0 + 1)
        .map(|w| w[1].0)
        .collect();
    let marked: Vec<u64> = file.iter().skip(1).filter(|x| x.1).map(|x| x.0).collect();
    println!(
        "  far logger: {} frames of the run recorded, {} hole(s), {} marked GAP_BEFORE",
        file.len(),
        holes.len(),
        marked.len()
    );
    // Each session's start and end (with Zenoh's reason: a lease that expired, a closed peer,
    // a TLS error), then the first warnings (bridge C's refusals).
    let logged = |what: &dyn Fn(&str) -> bool, most: usize| {
        for (who, l) in a
            .seen
            .iter()
            .map(|l| ("A", l))
            .chain(b.seen.iter().map(|l| ("B", l)))
            .filter(|(_, l)| what(l))
            .take(most)
        {
            // Zenoh's reason comes last, after the link's whole configuration.
            let l: Vec<char> = l.trim().chars().collect();
            let l: String = if l.len() > 240 {
                let (head, tail) = (&l[..80], &l[l.len() - 150..]);
                format!(
                    "{} ... {}",
                    String::from_iter(head),
                    String::from_iter(tail)
                )
            } else {
                l.into_iter().collect()
            };
            println!("  log {who}: {l}");
        }
    };
    logged(
        &|l| l.contains("peers connected") || l.contains("task failed"),
        24,
    );
    logged(&|l| l.contains("WARN"), 4);

    assert!(sl.success(), "far logger: {sl}\n{}", logger.seen.join("\n"));
    assert!(sa.success(), "bridge A: {sa}\n{}", a.seen.join("\n"));
    assert!(sb.success(), "bridge B: {sb}\n{}", b.seen.join("\n"));
    assert!(sc.success(), "bridge C: {sc}\n{}", c.seen.join("\n"));
    assert!(
        got_outside * 100 >= n_outside * 99,
        "delivered {got_outside} of {n_outside} outside the cut (< 99 %)"
    );
    assert_eq!(all.out_of_order, 0, "frames out of order");
    assert_eq!(all.duplicates, 0, "frames repeated");
    assert!(
        reconnect_ms.is_some() && fresh_ms.is_some(),
        "nothing arrived after the link returned"
    );
    if !all.gaps.is_empty() {
        // The far bridge flags the hole: its report counts lost frames from seq gaps.
        let lost: u64 = b_in
            .split("lost ")
            .nth(1)
            .and_then(|r| r.split(',').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or(0);
        assert!(
            lost > 0,
            "frames missing but bridge B reports no loss: {b_in}"
        );
    }
    // The far logger's file: in order, and no silent hole.
    assert!(
        file.windows(2).all(|w| w[1].0 > w[0].0),
        "the far logger's frames are out of order"
    );
    assert_eq!(
        holes, marked,
        "holes in the far logger's file without GAP_BEFORE"
    );
    assert!(
        file.len() as u64 >= got_outside / 2,
        "the far logger recorded only {} frames",
        file.len()
    );
    assert!(
        carried.dropped_at_random > 0 && carried.dropped_in_cut > 0,
        "the link was not impaired: {carried:?}"
    );
    assert_eq!(
        strangers, 0,
        "frames of the bridge without a certificate arrived"
    );
    assert!(
        !c.seen
            .iter()
            .any(|l| l.contains("zenoh peers connected: 1")),
        "C got connected:\n{}",
        c.seen.join("\n")
    );
    assert!(
        b.seen
            .iter()
            .any(|l| l.contains("refused a peer") && l.contains("no certificates")),
        "B did not log refusing C:\n{}",
        b.seen.join("\n")
    );

    // The cost of TLS on this link: plain TCP, then TLS, each a fresh pair of bridges, the
    // same frames over the same impaired link (no cut), in this run.
    let tcp_listen = format!("tcp/0.0.0.0:{COMPARE_PORT}");
    let tcp_connect = format!("tcp/{ip_b}:{COMPARE_PORT}");
    let tcp = compare_run(
        "TCP",
        [&ns_a, &ns_b],
        &format!("{tag}p"),
        args(&["--listen", &tcp_listen, "--insecure-listen"]),
        args(&["--connect", &tcp_connect]),
    );
    let mut tls_listen = args(&["--listen", &format!("tls/0.0.0.0:{COMPARE_PORT}")]);
    tls_listen.extend(tls_args(&certs, "server", &ca));
    let mut tls_connect = args(&["--connect", &format!("tls/{ip_b}:{COMPARE_PORT}")]);
    tls_connect.extend(tls_args(&certs, "client", &ca));
    let tls = compare_run(
        "TLS",
        [&ns_a, &ns_b],
        &format!("{tag}s"),
        tls_listen,
        tls_connect,
    );
    println!(
        "  TLS / TCP on this link: age p50 {:.2}, p99 {:.2}",
        tls.p50_us / tcp.p50_us,
        tls.p99_us / tcp.p99_us
    );
    for (kind, m) in [("TCP", &tcp), ("TLS", &tls)] {
        assert!(
            m.received * 100 >= COMPARE_FRAMES * 99,
            "{kind}: {} of {COMPARE_FRAMES} delivered",
            m.received
        );
        assert_eq!(m.out_of_order, 0, "{kind}: frames out of order");
    }
}

/// Frames and the port of the TCP / TLS comparison.
const COMPARE_FRAMES: u64 = 3_000;
const COMPARE_PORT: u16 = 7448;

struct Compared {
    received: u64,
    out_of_order: u64,
    p50_us: f64,
    p99_us: f64,
}

/// Bridge B (listening in `ns[1]`) and bridge A (connecting from `ns[0]`) with these
/// arguments; COMPARE_FRAMES frames at 1 kHz from domain A to domain B; both bridges stopped.
fn compare_run(
    kind: &str,
    ns: [&str; 2],
    tag: &str,
    listen: Vec<String>,
    connect: Vec<String>,
) -> Compared {
    let _cleanup = Cleanup(vec![format!("{tag}a_"), format!("{tag}b_")]);
    let Relayed {
        delivery: d,
        ages,
        mut a,
        mut b,
    } = relay_pair(
        &bridge(),
        tag,
        [Some(ns[0]), Some(ns[1])],
        &listen,
        &connect,
        COMPARE_FRAMES,
    );
    let (sa, sb) = (a.stop(), b.stop());
    println!(
        "  {kind}: bridge A {}; bridge B {}; gaps {:?}",
        a.last_line("out taxel/glove0/raw").trim(),
        b.last_line("in taxel/glove0/raw").trim(),
        d.gaps
    );
    assert!(
        sa.success(),
        "bridge A ({kind}): {sa}\n{}",
        a.seen.join("\n")
    );
    assert!(
        sb.success(),
        "bridge B ({kind}): {sb}\n{}",
        b.seen.join("\n")
    );
    let m = Compared {
        received: d.received,
        out_of_order: d.out_of_order,
        p50_us: percentile_us(&ages, 50.0),
        p99_us: percentile_us(&ages, 99.0),
    };
    println!(
        "  {kind} over the same link: {} of {COMPARE_FRAMES} delivered, out of order {}, age p50 {:.0} us, p99 {:.0} us",
        m.received, m.out_of_order, m.p50_us, m.p99_us
    );
    m
}
