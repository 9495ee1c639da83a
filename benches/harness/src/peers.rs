//! Socket peers for the transport comparison: a sender writes RawFrame-sized messages
//! (4 160 bytes, stamped with CLOCK_MONOTONIC just before the write) at a fixed rate over a Unix
//! domain socket or TCP loopback; a receiver reads them blocking or spinning (non-blocking
//! reads in a loop) and reports the one-way latency like `taxel latency --json`. A relay
//! (blocking reads, forwarding each message to a second receiver) makes the two-hop baseline
//! for our two-hop force path.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::unix::net::{UnixListener, UnixStream};
use std::time::{Duration, Instant};

use taxel_consumers::age::{json_report, AgeHistogram};
use taxel_msgs::RawFrame;
use taxel_runtime::now_ns;
use taxel_runtime::stats::SeqTracker;

/// Bytes per message: the size of a RawFrame.
pub const MSG: usize = std::mem::size_of::<RawFrame>();

#[derive(Debug, clap::Args)]
pub struct PeerArgs {
    /// `uds` or `tcp`.
    #[arg(long)]
    pub transport: String,
    /// `send`, `recv-block`, `recv-spin` or `relay-block` (uds only).
    #[arg(long)]
    pub role: String,
    /// Socket path (uds) or port on 127.0.0.1 (tcp).
    #[arg(long)]
    pub addr: String,
    /// The relay's onward socket path (uds).
    #[arg(long)]
    pub to: Option<String>,
    /// Messages per second (sender).
    #[arg(long, default_value_t = 1000.0)]
    pub rate_hz: f64,
    /// How long to run (s).
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
}

trait Stream: Read + Write {
    fn nonblocking(&self, on: bool) -> std::io::Result<()>;
}
impl Stream for UnixStream {
    fn nonblocking(&self, on: bool) -> std::io::Result<()> {
        self.set_nonblocking(on)
    }
}
impl Stream for TcpStream {
    fn nonblocking(&self, on: bool) -> std::io::Result<()> {
        self.set_nonblocking(on)
    }
}

fn send(mut s: impl Stream, rate_hz: f64, seconds: f64) -> anyhow::Result<()> {
    let mut msg = vec![0u8; MSG];
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let start = Instant::now();
    let mut seq = 0u64;
    taxel_runtime::clock::fine_timer_slack();
    while start.elapsed().as_secs_f64() < seconds {
        let due = start + period * seq as u32;
        if let Some(d) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        msg[..8].copy_from_slice(&seq.to_le_bytes());
        msg[8..16].copy_from_slice(&now_ns().to_le_bytes());
        if s.write_all(&msg).is_err() {
            break;
        }
        seq += 1;
    }
    Ok(())
}

fn recv(mut s: impl Stream, spin: bool, seconds: f64) -> anyhow::Result<String> {
    s.nonblocking(spin)?;
    let mut msg = vec![0u8; MSG];
    let mut h = AgeHistogram::new();
    let mut seqs = SeqTracker::default();
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut got = 0usize;
    while Instant::now() < end {
        match s.read(&mut msg[got..]) {
            Ok(0) => break,
            Ok(n) => {
                got += n;
                if got == MSG {
                    let now = now_ns();
                    let seq = u64::from_le_bytes(msg[..8].try_into()?);
                    let t = u64::from_le_bytes(msg[8..16].try_into()?);
                    h.record_ns(now.saturating_sub(t));
                    seqs.observe(seq);
                    got = 0;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::hint::spin_loop(),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
    Ok(json_report(
        seqs.received,
        seqs.dropped,
        &h,
        &[("cpu_s", taxel_runtime::process::cpu_seconds())],
    ))
}

/// Forwards whole messages from `from` to `to` until either side closes; prints its CPU time
/// as JSON.
fn relay(mut from: UnixStream, mut to: UnixStream) -> anyhow::Result<()> {
    let mut msg = vec![0u8; MSG];
    while from.read_exact(&mut msg).is_ok() {
        if to.write_all(&msg).is_err() {
            break;
        }
    }
    println!("{{\"cpu_s\": {}}}", taxel_runtime::process::cpu_seconds());
    Ok(())
}

/// Runs one peer; a receiver prints its JSON report on stdout.
pub fn run(a: &PeerArgs) -> anyhow::Result<()> {
    let spin = a.role == "recv-spin";
    match (a.transport.as_str(), a.role.as_str()) {
        ("uds", "send") => {
            let s = connect_retry(|| UnixStream::connect(&a.addr))?;
            send(s, a.rate_hz, a.seconds)
        }
        ("uds", "relay-block") => {
            let to =
                a.to.as_deref()
                    .ok_or_else(|| anyhow::anyhow!("relay-block needs --to"))?;
            let _ = std::fs::remove_file(&a.addr);
            let l = UnixListener::bind(&a.addr)?;
            let out = connect_retry(|| UnixStream::connect(to))?;
            println!("ready");
            let (s, _) = l.accept()?;
            relay(s, out)
        }
        ("uds", "recv-block" | "recv-spin") => {
            let _ = std::fs::remove_file(&a.addr);
            let l = UnixListener::bind(&a.addr)?;
            println!("ready");
            let (s, _) = l.accept()?;
            println!("{}", recv(s, spin, a.seconds)?);
            Ok(())
        }
        ("tcp", "send") => {
            let s = connect_retry(|| {
                TcpStream::connect(("127.0.0.1", a.addr.parse::<u16>().unwrap_or(0)))
            })?;
            s.set_nodelay(true)?;
            send(s, a.rate_hz, a.seconds)
        }
        ("tcp", "recv-block" | "recv-spin") => {
            let l = TcpListener::bind(("127.0.0.1", a.addr.parse::<u16>()?))?;
            println!("ready");
            let (s, _) = l.accept()?;
            s.set_nodelay(true)?;
            println!("{}", recv(s, spin, a.seconds)?);
            Ok(())
        }
        (t, r) => Err(anyhow::anyhow!("unknown transport/role {t}/{r}")),
    }
}

fn connect_retry<S>(mut f: impl FnMut() -> std::io::Result<S>) -> anyhow::Result<S> {
    let t0 = Instant::now();
    loop {
        match f() {
            Ok(s) => return Ok(s),
            Err(e) if t0.elapsed() > Duration::from_secs(5) => return Err(e.into()),
            Err(_) => std::thread::sleep(Duration::from_millis(10)),
        }
    }
}
