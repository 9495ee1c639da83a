//! A network link emulated in user space, for tests on kernels without `sch_netem` (the
//! development VM's has none): two TUN devices, each in its own network namespace, joined by a
//! thread that carries every IP packet from one to the other after a fixed delay, drops a
//! share of them at random, and drops everything while the link is cut. TCP over it sees what
//! it would see on an impaired cable: real delay, real loss (and its retransmissions), and a
//! black hole during a cut. With a fixed delay packets stay in order, as with netem's.
//!
//! Linux only; needs root (CAP_NET_ADMIN) and /dev/net/tun.

use std::collections::VecDeque;
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::AsRawFd;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// What the link does to each packet.
#[derive(Debug, Clone, Copy, Default)]
pub struct Impairment {
    /// Held this long in each direction.
    pub delay: Duration,
    /// Share of packets dropped (0..1), independently in each direction.
    pub loss: f64,
}

/// Packets the link carried and dropped, both directions together.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LinkStats {
    pub carried: u64,
    pub dropped_at_random: u64,
    pub dropped_in_cut: u64,
}

/// One end: a namespace, a TUN device in it, its address and its peer's.
#[derive(Debug, Clone)]
pub struct End<'a> {
    pub netns: &'a str,
    pub device: &'a str,
    pub address: &'a str,
}

/// A running emulated link; stopped (and its devices removed with their descriptors) on drop.
pub struct Link {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<()>>,
}

struct Shared {
    stop: AtomicBool,
    cut: AtomicBool,
    impairment: Mutex<Impairment>,
    carried: AtomicU64,
    random: AtomicU64,
    in_cut: AtomicU64,
}

const IFF_TUN: i16 = 0x0001;
const IFF_NO_PI: i16 = 0x1000;
const TUNSETIFF: libc::c_ulong = 0x4004_54ca;

/// `struct ifreq` as TUNSETIFF reads it: the name, then the flags (40 bytes in all).
#[repr(C)]
struct IfReq {
    name: [u8; 16],
    flags: i16,
    _pad: [u8; 22],
}

/// Opens a TUN device named `device` in namespace `netns`. The device belongs to the
/// namespace of the thread that opens /dev/net/tun, so a short-lived thread enters it first.
fn open_tun(netns: &str, device: &str) -> io::Result<File> {
    if device.len() >= 16 {
        return Err(io::Error::other(format!("device name {device:?} too long")));
    }
    let ns_path = format!("/run/netns/{netns}");
    let device = device.to_string();
    std::thread::spawn(move || -> io::Result<File> {
        let ns = File::open(&ns_path).map_err(|e| io::Error::other(format!("{ns_path}: {e}")))?;
        // SAFETY: setns(2) on this thread with a valid namespace descriptor.
        if unsafe { libc::setns(ns.as_raw_fd(), libc::CLONE_NEWNET) } != 0 {
            return Err(io::Error::last_os_error());
        }
        let tun = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open("/dev/net/tun")?;
        let mut req = IfReq {
            name: [0; 16],
            flags: IFF_TUN | IFF_NO_PI,
            _pad: [0; 22],
        };
        req.name[..device.len()].copy_from_slice(device.as_bytes());
        // SAFETY: TUNSETIFF reads an ifreq of the size above from a valid pointer.
        if unsafe { libc::ioctl(tun.as_raw_fd(), TUNSETIFF, &mut req) } != 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: fcntl(2) on a descriptor we own.
        unsafe {
            let fl = libc::fcntl(tun.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(tun.as_raw_fd(), libc::F_SETFL, fl | libc::O_NONBLOCK);
        }
        Ok(tun)
    })
    .join()
    .map_err(|_| io::Error::other("the thread opening the TUN device panicked"))?
}

fn ip(args: &[&str]) -> io::Result<()> {
    let out = Command::new("ip").args(args).output()?;
    if out.status.success() {
        Ok(())
    } else {
        Err(io::Error::other(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        )))
    }
}

impl Link {
    /// Creates the two TUN devices (point to point, each end's address with the other as its
    /// peer), brings them up and starts carrying packets with `impairment`; `seed` makes the
    /// random drops repeatable.
    pub fn start(a: End<'_>, b: End<'_>, impairment: Impairment, seed: u64) -> io::Result<Link> {
        let ta = open_tun(a.netns, a.device)?;
        let tb = open_tun(b.netns, b.device)?;
        for (me, peer) in [(&a, &b), (&b, &a)] {
            ip(&[
                "-n",
                me.netns,
                "addr",
                "add",
                me.address,
                "peer",
                peer.address,
                "dev",
                me.device,
            ])?;
            ip(&["-n", me.netns, "link", "set", me.device, "up"])?;
        }
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            cut: AtomicBool::new(false),
            impairment: Mutex::new(impairment),
            carried: AtomicU64::new(0),
            random: AtomicU64::new(0),
            in_cut: AtomicU64::new(0),
        });
        let s = shared.clone();
        let handle = std::thread::Builder::new()
            .name("netem".into())
            .spawn(move || carry(&s, ta, tb, seed))?;
        Ok(Link {
            shared,
            handle: Some(handle),
        })
    }

    /// Changes the delay and loss from now on (packets already held keep their due time).
    pub fn set_impairment(&self, i: Impairment) {
        if let Ok(mut m) = self.shared.impairment.lock() {
            *m = i;
        }
    }

    /// Cuts the link (every packet dropped, both ways) or restores it.
    pub fn set_cut(&self, cut: bool) {
        self.shared.cut.store(cut, Ordering::SeqCst);
    }

    pub fn stats(&self) -> LinkStats {
        LinkStats {
            carried: self.shared.carried.load(Ordering::Relaxed),
            dropped_at_random: self.shared.random.load(Ordering::Relaxed),
            dropped_in_cut: self.shared.in_cut.load(Ordering::Relaxed),
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// xorshift64*: repeatable drops without a dependency.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The carrier: reads what each device's stack sends, holds it, writes it to the other.
fn carry(s: &Shared, a: File, b: File, seed: u64) {
    let mut ends = [a, b];
    // Packets on their way to end k: (due, bytes).
    let mut queues: [VecDeque<(Instant, Vec<u8>)>; 2] = [VecDeque::new(), VecDeque::new()];
    let mut rng = Rng(seed | 1);
    let mut buf = vec![0u8; 65_536];
    while !s.stop.load(Ordering::SeqCst) {
        let now = Instant::now();
        let next_due = queues.iter().filter_map(|q| q.front()).map(|p| p.0).min();
        let wait = next_due
            .map(|d| d.saturating_duration_since(now))
            .unwrap_or(Duration::from_millis(50))
            .min(Duration::from_millis(50));
        let mut fds = [0, 1].map(|k| libc::pollfd {
            fd: ends[k].as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        });
        // Round up so a packet due in under a millisecond does not spin.
        let ms = wait.as_micros().div_ceil(1000) as libc::c_int;
        // SAFETY: poll(2) on two valid descriptors.
        unsafe { libc::poll(fds.as_mut_ptr(), 2, ms) };
        let imp = s.impairment.lock().map(|m| *m).unwrap_or_default();
        for k in 0..2 {
            // Packets read from end k go to the other end.
            while let Ok(n) = ends[k].read(&mut buf) {
                if s.cut.load(Ordering::SeqCst) {
                    s.in_cut.fetch_add(1, Ordering::Relaxed);
                } else if imp.loss > 0.0 && rng.unit() < imp.loss {
                    s.random.fetch_add(1, Ordering::Relaxed);
                } else {
                    queues[1 - k].push_back((Instant::now() + imp.delay, buf[..n].to_vec()));
                }
            }
        }
        let now = Instant::now();
        for k in 0..2 {
            while queues[k].front().is_some_and(|p| p.0 <= now) {
                if let Some((_, p)) = queues[k].pop_front() {
                    if s.cut.load(Ordering::SeqCst) {
                        s.in_cut.fetch_add(1, Ordering::Relaxed);
                    } else if ends[k].write(&p).is_ok() {
                        s.carried.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }
    // The devices go with their last descriptors (`ends`, dropped here).
}
