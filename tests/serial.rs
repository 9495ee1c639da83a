//! The serial source against a board emulator on a pseudo-terminal pair: frames at 1 kHz with
//! line noise, a corrupted frame, a stall with a partial frame, and an unplug/replug (the port
//! path is a symlink re-pointed at a new pty). The publisher, a separate process, must deliver
//! every valid frame in order with the gap flag exactly where frames were lost.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::raw_flags;
use taxel_publisher::serial::protocol::encode_binary;
use taxel_testkit::pipeline;

/// How long the publisher may take to report what happened on the line.
const SEEN_WITHIN: Duration = Duration::from_secs(15);

fn counts(seq: u32) -> Vec<u16> {
    (0..16)
        .map(|k| ((seq * 7 + k * 13) % 1000) as u16)
        .collect()
}

#[derive(Clone, Copy, PartialEq)]
enum Wire {
    Binary,
    Ascii,
}

fn frame_bytes(wire: Wire, seq: u32) -> Vec<u8> {
    let c = counts(seq);
    match wire {
        Wire::Binary => {
            let mut v = Vec::new();
            encode_binary(seq, seq.wrapping_mul(1000), &c, &mut v);
            v
        }
        Wire::Ascii => {
            let list: Vec<String> = c.iter().map(|x| x.to_string()).collect();
            format!("{},{}\r\n", seq as u64 * 1000, list.join(",")).into_bytes()
        }
    }
}

fn noise(wire: Wire, i: u32) -> Vec<u8> {
    match wire {
        Wire::Binary => [0x00u8, 0x13, 0xFF, 0x55, 0x42][..(i % 5) as usize].to_vec(),
        Wire::Ascii => b"# board says hi\n\n".to_vec(),
    }
}

/// Writes frames `from..to` at 1 kHz, with noise before every seventh.
fn write_frames(m: &mut TTYPort, wire: Wire, from: u32, to: u32, sent: &mut Vec<u32>) {
    let t0 = Instant::now();
    for (i, seq) in (from..to).enumerate() {
        if seq % 7 == 0 {
            m.write_all(&noise(wire, seq)).expect("noise");
        }
        m.write_all(&frame_bytes(wire, seq)).expect("frame");
        sent.push(seq);
        let due = t0 + Duration::from_micros(1000 * (i as u64 + 1));
        if let Some(d) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
    }
}

/// A pty pair whose descriptors are not inherited by the processes the test spawns (otherwise
/// a child keeps the master open and an unplug never reaches the publisher).
fn pair() -> (TTYPort, TTYPort) {
    use std::os::fd::AsRawFd;
    let (m, s) = TTYPort::pair().expect("pty pair");
    for fd in [m.as_raw_fd(), s.as_raw_fd()] {
        // SAFETY: fcntl on descriptors we own.
        unsafe {
            libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC);
        }
    }
    (m, s)
}

fn repoint(link: &Path, target: &str) {
    let tmp = link.with_extension("tmp");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).expect("symlink");
    std::fs::rename(&tmp, link).expect("rename");
}

fn scenario(wire: Wire) {
    let mut p = pipeline!("s");
    let link = p.path("ttyTAXEL");
    let (mut master, slave) = pair();
    repoint(&link, &slave.name().expect("slave name"));
    let rec = p.path("serial.taxrec");
    let logger = p.logger("s0", &rec.display().to_string(), &[]);
    let format = if wire == Wire::Binary {
        "auto"
    } else {
        "ascii"
    };
    let publisher = p.publisher(
        "s0",
        &[
            "serial",
            "--port",
            &link.display().to_string(),
            "--format",
            format,
            "--stall-s",
            "0.3",
        ],
    );
    p[publisher].wait_count("serial port open", 1, SEEN_WITHIN);
    drop(slave);
    let mut sent = Vec::new();
    let mut lost_before = Vec::new();
    write_frames(&mut master, wire, 0, 300, &mut sent);
    // A corrupted frame (bad CRC / bad line).
    let mut bad = frame_bytes(wire, 300);
    let k = bad.len() / 2;
    bad[k] = if wire == Wire::Binary {
        bad[k] ^ 0x10
    } else {
        b'x'
    };
    master.write_all(&bad).expect("bad frame");
    lost_before.push(301);
    write_frames(&mut master, wire, 301, 600, &mut sent);
    // A partial frame, then the device stalls.
    let partial = frame_bytes(wire, 600);
    master
        .write_all(&partial[..partial.len() / 2])
        .expect("partial");
    p[publisher].wait_count("serial device stalled", 1, SEEN_WITHIN);
    lost_before.push(601);
    write_frames(&mut master, wire, 601, 900, &mut sent);
    // Unplug: the pty goes away; replug on a new one at the same path.
    std::thread::sleep(Duration::from_millis(100));
    drop(master);
    p[publisher].wait_count("serial device lost", 1, SEEN_WITHIN);
    let (mut master, slave) = pair();
    repoint(&link, &slave.name().expect("slave name"));
    p[publisher].wait_count("serial port open", 2, SEEN_WITHIN);
    drop(slave);
    lost_before.push(1000);
    write_frames(&mut master, wire, 1000, 1300, &mut sent);
    std::thread::sleep(Duration::from_millis(300));
    p.stop(&[publisher, logger]);
    let out = p[publisher].output();
    assert!(
        out.contains("serial format detected: Binary") || wire == Wire::Ascii,
        "{out}"
    );
    let frames: Vec<(u64, u32, Vec<f32>)> = RecordFileReader::open(&rec)
        .expect("recording")
        .filter_map(|r| match r {
            Record::Raw(f) => Some((f.seq, f.flags, f.nodes().to_vec())),
            _ => None,
        })
        .collect();
    assert_eq!(
        frames.len(),
        sent.len(),
        "every valid frame, no more:\n{out}"
    );
    let mut prev_seq = None;
    for ((seq, flags, c), dev) in frames.iter().zip(&sent) {
        let want: Vec<f32> = counts(*dev).iter().map(|&v| v as f32).collect();
        assert_eq!(
            c, &want,
            "frame of device seq {dev} out of order or altered"
        );
        let gap = flags & raw_flags::GAP_BEFORE != 0;
        assert_eq!(
            gap,
            lost_before.contains(dev),
            "gap flag at device seq {dev}"
        );
        if let Some(p) = prev_seq {
            assert!(*seq > p, "seq increases");
            if !gap {
                assert_eq!(*seq, p + 1, "consecutive without a gap");
            }
        }
        prev_seq = Some(*seq);
    }
}

#[test]
fn binary_board_through_noise_crc_stall_and_replug() {
    scenario(Wire::Binary);
}

#[test]
fn ascii_board_through_noise_bad_line_stall_and_replug() {
    scenario(Wire::Ascii);
}
