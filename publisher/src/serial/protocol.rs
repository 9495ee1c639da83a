//! The readout board's wire formats and their streaming parsers (docs/serial-protocol.md).
//!
//! Binary frame, little endian: `0xAA 0x55 | u16 node count N | u32 device seq |
//! u32 device time (us) | N x u16 counts | u16 CRC-16/CCITT-FALSE` (the CRC covers everything
//! after the sync bytes). ASCII: one frame per line, integers separated by commas, spaces or
//! tabs, optionally led by the device time in microseconds; blank lines and `#` lines are
//! ignored. The parsers take bytes in any chunking, never panic, skip what is wrong (counted per
//! reason) and resynchronize on the next frame.

/// Sync bytes of a binary frame.
pub const SYNC: [u8; 2] = [0xAA, 0x55];
/// Bytes before the counts.
pub const HEADER_LEN: usize = 12;
/// Largest node count a frame may carry.
pub const MAX_FRAME_NODES: usize = 1024;

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Encodes a binary frame (used by the board emulator in tests and by tools).
pub fn encode_binary(seq: u32, time_us: u32, counts: &[u16], out: &mut Vec<u8>) {
    let start = out.len();
    out.extend_from_slice(&SYNC);
    out.extend_from_slice(&(counts.len() as u16).to_le_bytes());
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&time_us.to_le_bytes());
    for c in counts {
        out.extend_from_slice(&c.to_le_bytes());
    }
    let crc = crc16(&out[start + 2..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// A decoded frame, borrowed from the parser's buffer (no allocation per frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame<'a> {
    /// Device sequence number (binary only).
    pub seq: Option<u32>,
    /// Device time in microseconds (binary always; ASCII when a leading time is present).
    pub time_us: Option<u64>,
    pub counts: &'a [f32],
}

/// An owned copy of a [`Frame`] (tests and tools).
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceFrame {
    pub seq: Option<u32>,
    pub time_us: Option<u64>,
    pub counts: Vec<f32>,
}

impl Frame<'_> {
    pub fn to_owned_frame(&self) -> DeviceFrame {
        DeviceFrame {
            seq: self.seq,
            time_us: self.time_us,
            counts: self.counts.to_vec(),
        }
    }
}

/// Why bytes or lines were skipped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SkipCounts {
    /// Bytes that were not part of any frame (line noise, partial frames).
    pub garbage_bytes: u64,
    pub bad_crc: u64,
    pub wrong_node_count: u64,
    pub out_of_range: u64,
    /// ASCII lines that are not a list of integers.
    pub bad_line: u64,
}

impl SkipCounts {
    pub fn frames_skipped(&self) -> u64 {
        self.bad_crc + self.wrong_node_count + self.out_of_range + self.bad_line
    }
}

/// Streaming parser of the binary format.
#[derive(Debug, Clone)]
pub struct BinaryParser {
    nodes: usize,
    max_count: u16,
    buf: Vec<u8>,
    pos: usize,
    counts: Vec<f32>,
    pub skipped: SkipCounts,
}

impl BinaryParser {
    /// Frames must have `nodes` counts, each at most `max_count` (1023 for a 10-bit ADC).
    pub fn new(nodes: usize, max_count: u16) -> BinaryParser {
        BinaryParser {
            nodes,
            max_count,
            buf: Vec::with_capacity(4096),
            pos: 0,
            counts: vec![0.0; nodes],
            skipped: SkipCounts::default(),
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos * 2 >= self.buf.len() {
            self.buf.drain(..self.pos);
            self.pos = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete, valid frame in the buffered bytes.
    pub fn next_frame(&mut self) -> Option<Frame<'_>> {
        loop {
            let avail = &self.buf[self.pos..];
            // Find the sync bytes.
            let Some(at) = avail.windows(2).position(|w| w == SYNC) else {
                // Keep a trailing 0xAA: it may be the first sync byte.
                let keep = usize::from(avail.last() == Some(&SYNC[0]));
                let drop = avail.len() - keep;
                self.skipped.garbage_bytes += drop as u64;
                self.pos += drop;
                return None;
            };
            self.skipped.garbage_bytes += at as u64;
            self.pos += at;
            let avail = &self.buf[self.pos..];
            if avail.len() < 4 {
                return None;
            }
            let n = u16::from_le_bytes([avail[2], avail[3]]) as usize;
            if n == 0 || n > MAX_FRAME_NODES {
                // Not a real header: this 0xAA 0x55 was noise.
                self.skipped.garbage_bytes += 1;
                self.pos += 1;
                continue;
            }
            let len = HEADER_LEN + 2 * n + 2;
            if avail.len() < len {
                return None;
            }
            let frame = &avail[..len];
            let crc = u16::from_le_bytes([frame[len - 2], frame[len - 1]]);
            if crc16(&frame[2..len - 2]) != crc {
                self.skipped.bad_crc += 1;
                // Resynchronize from the next byte: the frame may have been cut by noise.
                self.pos += 1;
                continue;
            }
            self.pos += len;
            if n != self.nodes {
                self.skipped.wrong_node_count += 1;
                continue;
            }
            let seq = u32::from_le_bytes([frame[4], frame[5], frame[6], frame[7]]);
            let time = u32::from_le_bytes([frame[8], frame[9], frame[10], frame[11]]);
            let mut ok = true;
            for (k, c) in self.counts.iter_mut().enumerate() {
                let v = u16::from_le_bytes([frame[12 + 2 * k], frame[13 + 2 * k]]);
                ok &= v <= self.max_count;
                *c = v as f32;
            }
            if !ok {
                self.skipped.out_of_range += 1;
                continue;
            }
            return Some(Frame {
                seq: Some(seq),
                time_us: Some(time as u64),
                counts: &self.counts,
            });
        }
    }

    /// Bytes held that have not formed a frame yet.
    pub fn pending(&self) -> usize {
        self.buf.len() - self.pos
    }
}

/// Streaming parser of the ASCII format: lines are parsed when asked for, into reused
/// buffers.
#[derive(Debug, Clone)]
pub struct AsciiParser {
    nodes: usize,
    max_count: f64,
    buf: Vec<u8>,
    pos: usize,
    values: Vec<i64>,
    counts: Vec<f32>,
    pub skipped: SkipCounts,
}

/// Longest line accepted (a binary stream read as ASCII has no newlines).
const MAX_LINE: usize = 64 * 1024;

impl AsciiParser {
    pub fn new(nodes: usize, max_count: u16) -> AsciiParser {
        AsciiParser {
            nodes,
            max_count: max_count as f64,
            buf: Vec::with_capacity(4096),
            pos: 0,
            values: Vec::with_capacity(nodes + 2),
            counts: vec![0.0; nodes],
            skipped: SkipCounts::default(),
        }
    }

    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos * 2 >= self.buf.len() {
            self.buf.drain(..self.pos);
            self.pos = 0;
        }
        self.buf.extend_from_slice(bytes);
        // A line that never ends is not a frame: keep only its last MAX_LINE bytes.
        let pending = self.buf.len() - self.pos;
        if pending > MAX_LINE && !self.buf[self.pos..].contains(&b'\n') {
            let drop = pending - MAX_LINE;
            self.skipped.garbage_bytes += drop as u64;
            self.pos += drop;
        }
    }

    /// Parses one line into `values`; false if it is not a list of integers.
    fn parse_line(values: &mut Vec<i64>, raw: &[u8]) -> Option<bool> {
        let text = std::str::from_utf8(raw).ok()?.trim();
        if text.is_empty() || text.starts_with('#') {
            return Some(false);
        }
        values.clear();
        for field in text.split([',', ' ', '\t']).filter(|f| !f.is_empty()) {
            values.push(field.parse::<i64>().ok()?);
        }
        Some(true)
    }

    pub fn next_frame(&mut self) -> Option<Frame<'_>> {
        loop {
            let rest = &self.buf[self.pos..];
            let end = rest.iter().position(|&b| b == b'\n' || b == b'\r')?;
            let line_start = self.pos;
            self.pos += end + 1;
            match Self::parse_line(&mut self.values, &self.buf[line_start..line_start + end]) {
                None => {
                    self.skipped.bad_line += 1;
                    continue;
                }
                Some(false) => continue,
                Some(true) => {}
            }
            let (time, first) = if self.values.len() == self.nodes {
                (None, 0)
            } else if self.values.len() == self.nodes + 1 {
                (Some(self.values[0]), 1)
            } else {
                self.skipped.wrong_node_count += 1;
                continue;
            };
            let counts = &self.values[first..];
            if counts.iter().any(|&c| c < 0 || c as f64 > self.max_count)
                || time.is_some_and(|t| t < 0)
            {
                self.skipped.out_of_range += 1;
                continue;
            }
            for (d, v) in self.counts.iter_mut().zip(counts) {
                *d = *v as f32;
            }
            return Some(Frame {
                seq: None,
                time_us: time.map(|t| t as u64),
                counts: &self.counts,
            });
        }
    }
}

/// Which format a device speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Auto,
    Ascii,
    Binary,
}

/// Decides the format from the first bytes: two valid binary frames, or two valid ASCII
/// lines, whichever appears first. `None`: not enough evidence yet.
pub fn detect(bytes: &[u8], nodes: usize, max_count: u16) -> Option<Format> {
    let mut b = BinaryParser::new(nodes, max_count);
    b.push(bytes);
    let mut nb = 0;
    while b.next_frame().is_some() {
        nb += 1;
    }
    if nb >= 2 {
        return Some(Format::Binary);
    }
    let mut a = AsciiParser::new(nodes, max_count);
    a.push(bytes);
    let mut na = 0;
    while a.next_frame().is_some() {
        na += 1;
    }
    if na >= 2 {
        return Some(Format::Ascii);
    }
    None
}

/// Either parser.
#[derive(Debug, Clone)]
pub enum Parser {
    Ascii(AsciiParser),
    Binary(BinaryParser),
}

impl Parser {
    pub fn new(format: Format, nodes: usize, max_count: u16) -> Parser {
        match format {
            Format::Ascii => Parser::Ascii(AsciiParser::new(nodes, max_count)),
            _ => Parser::Binary(BinaryParser::new(nodes, max_count)),
        }
    }
    pub fn push(&mut self, bytes: &[u8]) {
        match self {
            Parser::Ascii(p) => p.push(bytes),
            Parser::Binary(p) => p.push(bytes),
        }
    }
    pub fn next_frame(&mut self) -> Option<Frame<'_>> {
        match self {
            Parser::Ascii(p) => p.next_frame(),
            Parser::Binary(p) => p.next_frame(),
        }
    }
    pub fn skipped(&self) -> SkipCounts {
        match self {
            Parser::Ascii(p) => p.skipped,
            Parser::Binary(p) => p.skipped,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use taxel_sim::rng::Rng;

    #[test]
    fn crc_check_value() {
        // CRC-16/CCITT-FALSE of "123456789".
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }

    /// The vectors in firmware/test_vectors.txt (shared with the firmware and the docs).
    #[test]
    fn shared_test_vectors_decode() {
        let text = include_str!("../../../firmware/test_vectors.txt");
        let mut n = 0;
        for line in text.lines().filter(|l| l.starts_with("frame ")) {
            // frame <seq> <time_us> <counts,...> <hex bytes>
            let parts: Vec<&str> = line.split_whitespace().collect();
            let seq: u32 = parts[1].parse().expect("seq");
            let time: u32 = parts[2].parse().expect("time");
            let counts: Vec<u16> = parts[3]
                .split(',')
                .map(|c| c.parse().expect("count"))
                .collect();
            let hex: String = parts[4..].concat();
            let bytes: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
                .collect();
            let mut enc = Vec::new();
            encode_binary(seq, time, &counts, &mut enc);
            assert_eq!(enc, bytes, "encoding of {line}");
            let mut p = BinaryParser::new(counts.len(), 1023);
            p.push(&bytes);
            let f = p.next_frame().expect("decodes");
            assert_eq!((f.seq, f.time_us), (Some(seq), Some(time as u64)));
            n += 1;
        }
        assert!(n >= 3);
    }

    fn stream(rng: &mut Rng, frames: usize, nodes: usize) -> (Vec<u8>, Vec<DeviceFrame>) {
        let mut bytes = Vec::new();
        let mut good = Vec::new();
        for i in 0..frames {
            // Line noise between frames, sometimes containing a fake sync.
            for _ in 0..(rng.next_u64() % 4) {
                bytes.push((rng.next_u64() & 0xFF) as u8);
            }
            if rng.next_u64().is_multiple_of(13) {
                bytes.extend_from_slice(&SYNC);
            }
            let counts: Vec<u16> = (0..nodes).map(|_| (rng.next_u64() % 1024) as u16).collect();
            let mut f = Vec::new();
            encode_binary(i as u32, i as u32 * 1000, &counts, &mut f);
            let kind = rng.next_u64() % 10;
            if kind == 0 {
                // Corrupt one byte: must be skipped (bad CRC).
                let k = 2 + (rng.next_u64() as usize % (f.len() - 2));
                f[k] ^= 0x40;
            } else if kind == 1 {
                // Cut the frame short: a partial frame.
                f.truncate(f.len() / 2);
            } else {
                good.push(DeviceFrame {
                    seq: Some(i as u32),
                    time_us: Some(i as u64 * 1000),
                    counts: counts.iter().map(|&c| c as f32).collect(),
                });
            }
            bytes.extend_from_slice(&f);
        }
        (bytes, good)
    }

    #[test]
    fn any_chunking_gives_the_same_frames_and_every_good_frame() {
        let mut rng = Rng::new(42, 1);
        for trial in 0..40 {
            let (bytes, good) = stream(&mut rng, 200, 16);
            let mut reference = None;
            for chunking in 0..4 {
                let mut p = BinaryParser::new(16, 1023);
                let mut got = Vec::new();
                let mut i = 0;
                while i < bytes.len() {
                    let step = match chunking {
                        0 => bytes.len(),
                        1 => 1,
                        _ => 1 + (rng.next_u64() as usize % 97),
                    };
                    let end = (i + step).min(bytes.len());
                    p.push(&bytes[i..end]);
                    while let Some(f) = p.next_frame() {
                        got.push(f.to_owned_frame());
                    }
                    i = end;
                }
                match &reference {
                    None => reference = Some(got.clone()),
                    Some(r) => assert_eq!(r, &got, "trial {trial} chunking {chunking}"),
                }
                // Every intact frame is recovered, in order; a corrupted frame can only cost
                // itself (and noise can hide at most the frame right after a cut).
                let seqs: Vec<u32> = got.iter().filter_map(|f| f.seq).collect();
                assert!(seqs.windows(2).all(|w| w[0] < w[1]));
                let want: Vec<u32> = good.iter().filter_map(|f| f.seq).collect();
                let missing = want.iter().filter(|s| !seqs.contains(s)).count();
                assert!(
                    missing * 20 <= want.len(),
                    "trial {trial}: lost {missing} of {}",
                    want.len()
                );
                for f in &got {
                    assert!(good.contains(f), "only intact frames are delivered");
                }
            }
        }
    }

    #[test]
    fn random_bytes_never_panic_and_rarely_pass() {
        let mut rng = Rng::new(7, 2);
        let mut passed = 0;
        for _ in 0..200 {
            let bytes: Vec<u8> = (0..2000).map(|_| (rng.next_u64() & 0xFF) as u8).collect();
            let mut b = BinaryParser::new(16, 1023);
            let mut a = AsciiParser::new(16, 1023);
            for c in bytes.chunks(37) {
                b.push(c);
                a.push(c);
                while b.next_frame().is_some() {
                    passed += 1;
                }
                while a.next_frame().is_some() {
                    passed += 1;
                }
            }
        }
        assert!(passed <= 1, "{passed} frames out of noise");
    }

    #[test]
    fn ascii_lines_with_and_without_time() {
        let mut a = AsciiParser::new(4, 1023);
        a.push(b"# board v1\n\n1,2,3,4\r\n1000\t5 6 7 8\nx,1,2,3\n1,2,3\n1,2,3,4000\n");
        let f1 = a.next_frame().expect("plain").to_owned_frame();
        assert_eq!((f1.time_us, f1.counts), (None, vec![1.0, 2.0, 3.0, 4.0]));
        let f2 = a.next_frame().expect("timed").to_owned_frame();
        assert_eq!((f2.time_us, f2.counts[0]), (Some(1000), 5.0));
        assert!(a.next_frame().is_none());
        assert_eq!(a.skipped.bad_line, 1);
        assert_eq!(a.skipped.wrong_node_count, 1);
        assert_eq!(a.skipped.out_of_range, 1);
    }

    #[test]
    fn wrong_node_count_and_out_of_range_are_skipped_and_counted() {
        let mut bytes = Vec::new();
        encode_binary(1, 0, &[1, 2, 3], &mut bytes);
        encode_binary(2, 0, &[1, 2, 3, 4000], &mut bytes);
        encode_binary(3, 0, &[1, 2, 3, 4], &mut bytes);
        let mut p = BinaryParser::new(4, 1023);
        p.push(&bytes);
        assert_eq!(p.next_frame().and_then(|f| f.seq), Some(3));
        assert_eq!((p.skipped.wrong_node_count, p.skipped.out_of_range), (1, 1));
    }

    #[test]
    fn format_detection() {
        let mut bin = Vec::new();
        for i in 0..3 {
            encode_binary(i, i * 1000, &[5; 16], &mut bin);
        }
        assert_eq!(detect(&bin, 16, 1023), Some(Format::Binary));
        let ascii = "1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16\n".repeat(3);
        assert_eq!(detect(ascii.as_bytes(), 16, 1023), Some(Format::Ascii));
        assert_eq!(detect(b"hello", 16, 1023), None);
    }
}
