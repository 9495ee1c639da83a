//! Real-board test: `TAXEL_SERIAL_PORT=/dev/ttyACM0 cargo test -p taxel-publisher --features
//! hardware-tests --test hardware` (optional `TAXEL_SERIAL_BAUD`, default 115200). Reads the
//! board for 3 s and checks that it speaks a format taxel detects and that frames parse.

#![cfg(feature = "hardware-tests")]

use std::io::Read;
use std::time::{Duration, Instant};

use taxel_publisher::serial::protocol::{detect, Parser};

#[test]
fn the_board_streams_parseable_frames() {
    let port = std::env::var("TAXEL_SERIAL_PORT")
        .expect("set TAXEL_SERIAL_PORT to the board's serial device for hardware tests");
    let baud: u32 = std::env::var("TAXEL_SERIAL_BAUD")
        .ok()
        .and_then(|b| b.parse().ok())
        .unwrap_or(115_200);
    let mut dev = serialport::new(&port, baud)
        .timeout(Duration::from_millis(100))
        .open_native()
        .unwrap_or_else(|e| panic!("{port}: {e}"));
    let mut bytes = Vec::new();
    let mut buf = [0u8; 4096];
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(3) {
        if let Ok(n) = dev.read(&mut buf) {
            bytes.extend_from_slice(&buf[..n]);
        }
    }
    let format = detect(&bytes, 16, 1023).expect("no taxel frames in 3 s of data");
    let mut p = Parser::new(format, 16, 1023);
    p.push(&bytes);
    let mut frames = 0;
    while p.next_frame().is_some() {
        frames += 1;
    }
    eprintln!(
        "{port}: {format:?}, {frames} frames in 3 s, skipped {:?}",
        p.skipped()
    );
    assert!(frames >= 30, "only {frames} frames in 3 s");
}
