//! The fast way through an MCAP file: its records are read one after the other (opcode and
//! u64 length framing) into one buffer reused from record to record, the records of an
//! uncompressed chunk are walked in place in that buffer, and each message is decoded into a
//! payload reused from message to message ([`Slots`]). Reading allocates nothing per message
//! and holds no more of the file than its largest record.
//!
//! Schema and channel records go through the `mcap` crate's [`ChannelAccumulator`] and every
//! other record through its parser, so the walker checks what the crate's `MessageStream`
//! checks and reads the same messages in the same order (tested on files of several writers'
//! chunkings, on every cut of a file and on byte flips). A `zstd` or `lz4` chunk is
//! decompressed into a second reused buffer ([`super::unpack`]) and walked there; a chunk of
//! any other compression it leaves to the crate ([`Walked::Unusual`]), which names it. Damage
//! is an error naming the record and its byte offset.

use std::borrow::Cow;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use ::mcap::read::ChannelAccumulator;
use ::mcap::records::{op, Record as McapRecord};

use super::json::{declared_fields, Slots};
use super::unpack;
use super::{McapError, McapView};

/// Bytes of a record's opcode and length.
const FRAMING: usize = 1 + 8;
/// Bytes of a message record before its data.
const MESSAGE_HEADER: usize = 2 + 4 + 8 + 8;

/// How a walk ended.
pub(super) enum Walked {
    /// Every message of the file was handed over.
    Done,
    /// The rest is left to the `mcap` crate: `delivered` messages were handed over before it.
    Unusual { delivered: usize },
}

/// What a channel's messages need: where they go and how they decode.
struct Chan {
    topic: String,
    /// The schema's name, when the encoding is JSON and the channel has a schema.
    json_schema: Option<String>,
    encoding: String,
    /// The fields the channel's writer declared.
    declared: Option<Vec<String>>,
}

struct Walker<'a, R, F> {
    path: &'a Path,
    reader: R,
    /// The file's length, and where the next unread byte is.
    size: u64,
    pos: u64,
    /// The body of the record being read.
    buf: Vec<u8>,
    /// The records of a compressed chunk, decompressed.
    unpacked: Vec<u8>,
    acc: ChannelAccumulator<'static>,
    /// By channel id.
    chans: Vec<Option<Chan>>,
    slots: Slots,
    delivered: usize,
    past_data_end: bool,
    f: F,
}

/// The name of a record kind, for errors.
fn kind(opcode: u8) -> &'static str {
    match opcode {
        op::HEADER => "header record",
        op::FOOTER => "footer record",
        op::SCHEMA => "schema record",
        op::CHANNEL => "channel record",
        op::MESSAGE => "message record",
        op::CHUNK => "chunk record",
        op::MESSAGE_INDEX => "message index record",
        op::CHUNK_INDEX => "chunk index record",
        op::ATTACHMENT => "attachment record",
        op::ATTACHMENT_INDEX => "attachment index record",
        op::STATISTICS => "statistics record",
        op::METADATA => "metadata record",
        op::METADATA_INDEX => "metadata index record",
        op::SUMMARY_OFFSET => "summary offset record",
        op::DATA_END => "data end record",
        _ => "record",
    }
}

/// The record starting at `at` of `region`: its opcode and body, or `None` when the region
/// ends before it does.
fn framed(region: &[u8], at: usize) -> Option<(u8, &[u8])> {
    let head = region.get(at..at.checked_add(FRAMING)?)?;
    let len = u64::from_le_bytes(head[1..].try_into().ok()?);
    let start = at + FRAMING;
    let end = start.checked_add(usize::try_from(len).ok()?)?;
    Some((head[0], region.get(start..end)?))
}

fn le_u64(b: &[u8]) -> u64 {
    let mut x = [0u8; 8];
    x.copy_from_slice(&b[..8]);
    u64::from_le_bytes(x)
}

/// The error for a magic that is `got` instead of the MCAP magic.
fn magic_error(got: &[u8]) -> ::mcap::McapError {
    if got.len() < ::mcap::MAGIC.len() && ::mcap::MAGIC.starts_with(got) {
        ::mcap::McapError::UnexpectedEof
    } else {
        ::mcap::McapError::BadMagic
    }
}

impl<'a, R: Read, F: FnMut(McapView<'_>) -> Result<(), McapError>> Walker<'a, R, F> {
    /// A walker of `reader`, the `size` bytes of `path`, positioned at byte `pos`.
    fn new(path: &'a Path, reader: R, size: u64, pos: u64, f: F) -> Self {
        Walker {
            path,
            reader,
            size,
            pos,
            buf: Vec::new(),
            unpacked: Vec::new(),
            acc: ChannelAccumulator::default(),
            chans: Vec::new(),
            slots: Slots::default(),
            delivered: 0,
            past_data_end: false,
            f,
        }
    }

    fn error(&self, what: &'static str, at: u64, error: ::mcap::McapError) -> McapError {
        McapError::Record {
            path: self.path.to_path_buf(),
            index: self.delivered,
            what,
            at,
            error,
        }
    }

    /// Fills `out` from the file; the number of bytes read (fewer at the end of the file).
    fn read(&mut self, out: &mut [u8]) -> Result<usize, McapError> {
        let mut n = 0;
        while n < out.len() {
            match self.reader.read(&mut out[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(error) => {
                    return Err(McapError::Io {
                        path: self.path.to_path_buf(),
                        error,
                    })
                }
            }
        }
        self.pos += n as u64;
        Ok(n)
    }

    /// The file's records from the start magic to the end magic.
    fn file(&mut self) -> Result<Walked, McapError> {
        self.magic()?;
        match self.records(None)? {
            Some(w) => Ok(w),
            None => Ok(Walked::Done),
        }
    }

    /// Reads and checks the start magic.
    fn magic(&mut self) -> Result<(), McapError> {
        let mut magic = [0u8; 8];
        let n = self.read(&mut magic)?;
        if magic[..n] != *::mcap::MAGIC {
            return Err(self.error("start magic", 0, magic_error(&magic[..n])));
        }
        Ok(())
    }

    /// Walks file-level records until the walk ends (`Some`) or, given an `end`, the position
    /// reaches it (`None`).
    fn records(&mut self, end: Option<u64>) -> Result<Option<Walked>, McapError> {
        let mut body = std::mem::take(&mut self.buf);
        let walked = loop {
            if end.is_some_and(|end| self.pos >= end) {
                break Ok(None);
            }
            match self.next(&mut body) {
                Ok(None) => {}
                Ok(Some(w)) => break Ok(Some(w)),
                Err(e) => break Err(e),
            }
        };
        self.buf = body;
        walked
    }

    /// Reads and walks the next file-level record; `Some` when the walk ends.
    fn next(&mut self, body: &mut Vec<u8>) -> Result<Option<Walked>, McapError> {
        let at = self.pos;
        let mut head = [0u8; FRAMING];
        let n = self.read(&mut head)?;
        let opcode = head[0];
        let len = u64::from_le_bytes([
            head[1], head[2], head[3], head[4], head[5], head[6], head[7], head[8],
        ]);
        // A length past the end of the file is checked before anything is allocated for it.
        if n < FRAMING || len > self.size.saturating_sub(self.pos) {
            let what = if n == 0 {
                "footer record"
            } else {
                kind(opcode)
            };
            return Err(self.error(what, at, ::mcap::McapError::UnexpectedEof));
        }
        let len = len as usize;
        if body.len() < len {
            body.resize(len, 0);
        }
        let got = self.read(&mut body[..len])?;
        if got < len {
            return Err(self.error(kind(opcode), at, ::mcap::McapError::UnexpectedEof));
        }
        let body = &body[..len];
        match opcode {
            op::CHUNK => return self.chunk(body, at),
            op::FOOTER => {
                ::mcap::parse_record(opcode, body).map_err(|e| self.error(kind(opcode), at, e))?;
                let end = self.pos;
                let mut magic = [0u8; 8];
                let n = self.read(&mut magic)?;
                if magic[..n] != *::mcap::MAGIC {
                    return Err(self.error("end magic", end, magic_error(&magic[..n])));
                }
                return Ok(Some(Walked::Done));
            }
            op::DATA_END => {
                ::mcap::parse_record(opcode, body).map_err(|e| self.error(kind(opcode), at, e))?;
                // The summary repeats schemas and channels: they are parsed, not re-checked.
                self.past_data_end = true;
            }
            _ => self.record(opcode, body, at)?,
        }
        Ok(None)
    }

    /// A chunk record at `at`: its records, decompressed if need be; `Some` when it ends the
    /// walk (a compression this build cannot read). Errors inside a compressed chunk name the
    /// chunk's offset.
    fn chunk(&mut self, body: &[u8], at: u64) -> Result<Option<Walked>, McapError> {
        let (header, data) = match ::mcap::parse_record(op::CHUNK, body) {
            Ok(McapRecord::Chunk {
                header,
                data: Cow::Borrowed(data),
            }) => (header, data),
            Err(e) => return Err(self.error(kind(op::CHUNK), at, e)),
            // Not a borrowed chunk (the parser never gives one): left to the crate.
            Ok(_) => {
                return Ok(Some(Walked::Unusual {
                    delivered: self.delivered,
                }))
            }
        };
        if !unpack::supported(&header.compression) {
            return Ok(Some(Walked::Unusual {
                delivered: self.delivered,
            }));
        }
        if header.compression.is_empty() {
            // The file offset of the chunk's records.
            let base = at + (FRAMING + (body.len() - data.len())) as u64;
            return self.chunk_records(data, |i| base + i as u64).map(|()| None);
        }
        let mut unpacked = std::mem::take(&mut self.unpacked);
        let walked = unpack::unpack(
            &header.compression,
            data,
            header.uncompressed_size,
            header.uncompressed_crc,
            &mut unpacked,
        )
        .map_err(|e| self.error(kind(op::CHUNK), at, e))
        .and_then(|()| self.chunk_records(&unpacked, |_| at));
        self.unpacked = unpacked;
        walked.map(|()| None)
    }

    /// The records of a chunk; `offset` gives the file offset named in errors.
    fn chunk_records(
        &mut self,
        records: &[u8],
        offset: impl Fn(usize) -> u64,
    ) -> Result<(), McapError> {
        let mut i = 0;
        while i < records.len() {
            let inner_at = offset(i);
            let Some((opcode, inner)) = framed(records, i) else {
                let what = kind(records[i]);
                return Err(self.error(what, inner_at, ::mcap::McapError::UnexpectedEoc));
            };
            self.record(opcode, inner, inner_at)?;
            i += FRAMING + inner.len();
        }
        Ok(())
    }

    /// Any record but the file-level chunk, data end and footer records: messages, schemas
    /// and channels are read (before the data end), every other record is only parsed.
    fn record(&mut self, opcode: u8, body: &[u8], at: u64) -> Result<(), McapError> {
        if opcode == op::MESSAGE && body.len() >= MESSAGE_HEADER && !self.past_data_end {
            return self.message(body, at);
        }
        let record =
            ::mcap::parse_record(opcode, body).map_err(|e| self.error(kind(opcode), at, e))?;
        if self.past_data_end {
            return Ok(());
        }
        let linked = match record {
            McapRecord::Schema { header, data } => self.acc.add_schema_from_slice(header, &data),
            McapRecord::Channel(chan) => {
                let id = chan.id;
                self.acc.add_channel(chan).map(|()| self.link(id))
            }
            _ => Ok(()),
        };
        linked.map_err(|e| self.error(kind(opcode), at, e))
    }

    /// Keeps what the messages of channel `id` (just accepted) need.
    fn link(&mut self, id: u16) {
        let Some(c) = self.acc.get(id) else { return };
        let i = usize::from(id);
        if self.chans.len() <= i {
            self.chans.resize_with(i + 1, || None);
        }
        if self.chans[i].is_some() {
            return;
        }
        let schema = c.schema.as_ref();
        self.chans[i] = Some(Chan {
            topic: c.topic.clone(),
            json_schema: schema
                .filter(|_| c.message_encoding == "json")
                .map(|s| s.name.clone()),
            encoding: c.message_encoding.clone(),
            declared: schema.and_then(|s| declared_fields(&s.data)),
        });
    }

    /// A message record at `at` (at least its header long): decoded and handed over.
    fn message(&mut self, body: &[u8], at: u64) -> Result<(), McapError> {
        let id = u16::from_le_bytes([body[0], body[1]]);
        let sequence = u32::from_le_bytes([body[2], body[3], body[4], body[5]]);
        let (log_time, publish_time) = (le_u64(&body[6..]), le_u64(&body[14..]));
        let data = &body[MESSAGE_HEADER..];
        let index = self.delivered;
        let Some(chan) = self.chans.get(usize::from(id)).and_then(Option::as_ref) else {
            let error = ::mcap::McapError::UnknownChannel(sequence, id);
            return Err(self.error(kind(op::MESSAGE), at, error));
        };
        let record = match &chan.json_schema {
            Some(schema) => self.slots.decode(schema, chan.declared.as_deref(), data),
            None => Err(format!(
                "message encoding {:?} with no taxel schema",
                chan.encoding
            )),
        }
        .map_err(|reason| McapError::Message {
            path: self.path.to_path_buf(),
            index,
            topic: chan.topic.clone(),
            reason,
        })?;
        (self.f)(McapView {
            topic: &chan.topic,
            log_time,
            publish_time,
            sequence,
            record,
        })?;
        self.delivered += 1;
        Ok(())
    }
}

/// Walks the file at `path`, handing each message to `f` in file order.
pub(super) fn walk(
    path: &Path,
    f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<Walked, McapError> {
    let io = |error| McapError::Io {
        path: path.to_path_buf(),
        error,
    };
    let file = File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    walk_from(path, BufReader::with_capacity(1 << 16, file), size, f)
}

/// [`walk`] on the `size` bytes of `reader` (read from `path`).
pub(super) fn walk_from(
    path: &Path,
    reader: impl Read,
    size: u64,
    f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<Walked, McapError> {
    Walker::new(path, reader, size, 0, f).file()
}

/// Walks one part of the file at `path` (of `size` bytes): the file-level records from byte
/// `start` (0, or a record boundary after the start magic) to byte `end` (a record boundary),
/// or to the end of the file when `end` is `None`, handing each message to `f`. A part that
/// does not start at 0 first takes the `schemas_and_channels` records (opcode, body, file
/// offset; from the summary), since the records that define them come earlier in the file.
///
/// True when the part was walked whole and ended exactly at `end` (at the footer and end magic
/// for the last part); false, with no error, when it needs the whole file read in order (a
/// chunk of a compression it cannot read, a record across `end`). Errors name the message
/// index within the part.
pub(super) fn walk_part(
    path: &Path,
    size: u64,
    (start, end): (u64, Option<u64>),
    schemas_and_channels: &[(u8, &[u8], u64)],
    f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<bool, McapError> {
    use std::io::{Seek, SeekFrom};
    let io = |error| McapError::Io {
        path: path.to_path_buf(),
        error,
    };
    let mut file = File::open(path).map_err(io)?;
    file.seek(SeekFrom::Start(start)).map_err(io)?;
    let reader = BufReader::with_capacity(1 << 16, file);
    let mut w = Walker::new(path, reader, size, start, f);
    if start == 0 {
        w.magic()?;
    } else {
        for &(opcode, body, at) in schemas_and_channels {
            w.record(opcode, body, at)?;
        }
    }
    Ok(match (w.records(end)?, end) {
        (None, Some(end)) => w.pos == end,
        (Some(Walked::Done), None) => true,
        _ => false,
    })
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::{read, read_messages, McapMessage, McapRecordWriter};
    use super::*;
    use crate::records::Record;
    use taxel_msgs::{
        sensor_id_bytes, CurvatureEstimate, ForceSample, Message, RawFrame, Reference,
    };

    /// `n` frames' records of two sensors: raw frames whose geometry changes (so a reused
    /// payload must not keep the previous frame's entries), forces, references and estimates,
    /// with non-finite values.
    pub(in super::super) fn records(n: u64) -> Vec<Record> {
        let mut out = Vec::new();
        for i in 0..n {
            let sensor = sensor_id_bytes(if i % 3 == 0 { "s1" } else { "s0" }).expect("id");
            let t = 1_000_000_000 + i * 1_000_000;
            let mut raw = RawFrame::ZERO;
            (raw.sensor, raw.seq, raw.t_capture_ns) = (sensor, i, t);
            (raw.rows, raw.cols) = if i % 5 == 4 { (2, 3) } else { (4, 4) };
            raw.full_scale = 1023.0;
            let nodes = usize::from(raw.rows * raw.cols);
            for (k, c) in raw.counts[..nodes].iter_mut().enumerate() {
                *c = ((i * 7 + k as u64 * 13) % 1000) as f32 + 0.25;
            }
            if i % 7 == 0 {
                raw.counts[1] = f32::NAN;
            }
            let mut force = ForceSample::ZERO;
            (force.sensor, force.seq, force.t_capture_ns) = (sensor, i, t);
            force.t_publish_ns = t + 61_000;
            let blocks = 1 + (i % 2) as usize;
            force.n_blocks = blocks as u32;
            force.block_force_n[..blocks].copy_from_slice(&[i as f32 * 0.011, 0.5][..blocks]);
            force.block_reading[..blocks].copy_from_slice(&[i as f32 * 1.37, f32::NAN][..blocks]);
            force.total_force_n = i as f32 * 0.0113;
            let reference = Reference {
                sensor,
                seq: i,
                t_capture_ns: t,
                t_source_s: i as f64 * 0.001,
                force_n: (i % 97) as f32 * 0.0183,
                curvature_m1: f32::NAN,
                temp_c: 24.5,
                trial: i as i32 - 3,
            };
            out.extend([raw.into(), force.into(), reference.into()]);
            if i % 10 == 9 {
                let mut est = CurvatureEstimate::ZERO;
                (est.sensor, est.seq, est.t_capture_ns) = (sensor, i, t);
                (est.rows, est.cols, est.curvature_m1) = (4, 4, 29.75);
                est.baseline[..16].copy_from_slice(&[500.0; 16]);
                out.push(est.into());
            }
        }
        out
    }

    pub(in super::super) fn write(
        p: &Path,
        options: Option<::mcap::WriteOptions>,
        recs: &[Record],
    ) {
        let mut w = match options {
            Some(o) => McapRecordWriter::with_options(p, o),
            None => McapRecordWriter::create(p),
        }
        .expect("create");
        for r in recs {
            w.write(r).expect("write");
        }
        w.finish().expect("finish");
    }

    /// The messages of `p` through the `mcap` crate's `MessageStream`.
    fn through_the_crate(p: &Path) -> Result<Vec<McapMessage>, McapError> {
        let bytes = std::fs::read(p).expect("read");
        let mut out = Vec::new();
        read::stream(p, &bytes, 0, |m| {
            out.push(m.to_message());
            Ok(())
        })?;
        Ok(out)
    }

    #[test]
    fn every_chunking_reads_as_the_crate_reads_it() {
        let recs = records(600);
        let dir = tempfile::tempdir().expect("tempdir");
        let plain = || {
            ::mcap::WriteOptions::new()
                .compression(None)
                .library("another writer")
        };
        let variants = [
            ("taxel", None),
            ("a chunk per message", Some(plain().chunk_size(Some(1)))),
            ("small chunks", Some(plain().chunk_size(Some(3000)))),
            ("one chunk", Some(plain().chunk_size(None))),
            ("no chunks", Some(plain().use_chunks(false))),
            (
                "no summary, no indexes",
                Some(
                    plain()
                        .chunk_size(Some(5000))
                        .emit_summary_records(false)
                        .emit_summary_offsets(false)
                        .emit_message_indexes(false),
                ),
            ),
        ];
        for (name, options) in variants {
            let p = dir.path().join(format!("{name}.mcap"));
            write(&p, options, &recs);
            let walked = read_messages(&p).expect(name);
            let streamed = through_the_crate(&p).expect(name);
            assert_eq!(walked.len(), recs.len(), "{name}");
            assert_eq!(format!("{walked:?}"), format!("{streamed:?}"), "{name}");
            for (m, r) in walked.iter().zip(&recs) {
                assert_eq!(format!("{:?}", m.record), format!("{r:?}"), "{name}");
                let topic = format!("/taxel/{}/{}", r.sensor(), r.stream().suffix());
                assert_eq!((m.topic.as_str(), m.log_time), (&*topic, r.t_capture_ns()));
            }
        }
    }

    /// Builds MCAP files record by record.
    #[derive(Default)]
    struct Bytes(Vec<u8>);

    impl Bytes {
        fn u16(mut self, x: u16) -> Self {
            self.0.extend(x.to_le_bytes());
            self
        }
        fn u32(mut self, x: u32) -> Self {
            self.0.extend(x.to_le_bytes());
            self
        }
        fn u64(mut self, x: u64) -> Self {
            self.0.extend(x.to_le_bytes());
            self
        }
        fn raw(mut self, b: &[u8]) -> Self {
            self.0.extend(b);
            self
        }
        fn str(self, s: &str) -> Self {
            self.u32(s.len() as u32).raw(s.as_bytes())
        }
        fn record(self, opcode: u8, body: Bytes) -> Self {
            self.raw(&[opcode]).u64(body.0.len() as u64).raw(&body.0)
        }
    }

    fn schema(id: u16, name: &str) -> Bytes {
        Bytes::default()
            .u16(id)
            .str(name)
            .str("jsonschema")
            .u32(2)
            .raw(b"{}")
    }

    fn channel(id: u16, schema: u16, topic: &str, encoding: &str) -> Bytes {
        Bytes::default()
            .u16(id)
            .u16(schema)
            .str(topic)
            .str(encoding)
            .u32(0)
    }

    fn message(channel: u16, seq: u64) -> Bytes {
        let mut r = Reference::ZERO;
        (r.seq, r.t_capture_ns, r.force_n) = (seq, seq * 10, 1.5);
        let json = super::super::json::encode(&r.into());
        Bytes::default()
            .u16(channel)
            .u32(seq as u32)
            .u64(seq * 10)
            .u64(seq * 10)
            .raw(&json)
    }

    fn chunk(compression: &str, records: Bytes) -> Bytes {
        Bytes::default()
            .u64(0)
            .u64(0)
            .u64(records.0.len() as u64)
            .u32(0)
            .str(compression)
            .u64(records.0.len() as u64)
            .raw(&records.0)
    }

    /// A file of `data` records (a header first; the data end, footer and end magic after).
    fn file(data: Bytes) -> Vec<u8> {
        let header = Bytes::default().str("").str("hand");
        Bytes::default()
            .raw(::mcap::MAGIC)
            .record(op::HEADER, header)
            .raw(&data.0)
            .record(op::DATA_END, Bytes::default().u32(0))
            .record(op::FOOTER, Bytes::default().u64(0).u64(0).u32(0))
            .raw(::mcap::MAGIC)
            .0
    }

    fn defs() -> Bytes {
        let reference = Reference::NAME;
        Bytes::default()
            .record(op::SCHEMA, schema(1, reference))
            .record(op::CHANNEL, channel(1, 1, "/taxel/s0/reference", "json"))
    }

    /// Reads `bytes` as a file: the messages handed over, and how the read ended.
    fn read(bytes: &[u8]) -> (usize, Result<(), String>) {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("hand.mcap");
        std::fs::write(&p, bytes).expect("write");
        let mut n = 0;
        let end = super::super::for_each(&p, |_| n += 1);
        (n, end.map_err(|e| e.to_string()))
    }

    #[test]
    fn a_chunk_of_another_compression_goes_to_the_crate() {
        let first = defs()
            .record(op::MESSAGE, message(1, 1))
            .record(op::MESSAGE, message(1, 2));
        let second = Bytes::default().record(op::MESSAGE, message(1, 3));
        let bytes = file(
            Bytes::default()
                .record(op::CHUNK, chunk("", first))
                .record(op::CHUNK, chunk("brotli", second)),
        );
        let (n, end) = read(&bytes);
        assert_eq!(n, 2);
        let e = end.expect_err("this build has no brotli");
        assert!(
            e.ends_with("unreadable after 2 messages: Unsupported compression format `brotli`"),
            "{e}"
        );
    }

    #[test]
    fn messages_outside_chunks_and_unknown_records_read() {
        let data = defs()
            .record(op::MESSAGE, message(1, 1))
            .record(0x99, Bytes::default().raw(b"private"))
            .record(
                op::CHUNK,
                chunk("", Bytes::default().record(op::MESSAGE, message(1, 2))),
            )
            .record(op::MESSAGE, message(1, 3));
        assert_eq!(read(&file(data)), (3, Ok(())));
    }

    #[test]
    fn damage_is_an_error_naming_the_record_and_its_offset() {
        let unknown = defs().record(op::MESSAGE, message(7, 1));
        let (n, end) = read(&file(unknown));
        let e = end.expect_err("unknown channel");
        assert_eq!(n, 0);
        let at = 8 + 9 + 4 + 4 + 4 + 9 + schema(1, Reference::NAME).0.len();
        let at = at + 9 + channel(1, 1, "/taxel/s0/reference", "json").0.len();
        assert!(
            e.ends_with(&format!(
                "unreadable after 0 messages: message record at byte {at}: \
                 Message 1 referenced unknown channel 7"
            )),
            "{e}"
        );
        // A record longer than its chunk.
        let mut inner = defs().record(op::MESSAGE, message(1, 1)).0;
        let last = inner.len() - message(1, 1).0.len() - 8;
        inner[last] = inner[last].wrapping_add(1);
        let (n, end) = read(&file(
            Bytes::default().record(op::CHUNK, chunk("", Bytes(inner))),
        ));
        let e = end.expect_err("overlong");
        assert_eq!(n, 0);
        assert!(e.contains("message record at byte "), "{e}");
        assert!(e.ends_with("Chunk ended in the middle of a record"), "{e}");
        // A foreign schema and a foreign encoding: errors naming the topic.
        let foreign = Bytes::default()
            .record(op::SCHEMA, schema(1, "pkg/Other"))
            .record(op::CHANNEL, channel(1, 1, "/other", "json"))
            .record(op::MESSAGE, message(1, 1));
        let e = read(&file(foreign)).1.expect_err("foreign schema");
        assert!(
            e.ends_with("message 0 on /other: unknown schema \"pkg/Other\""),
            "{e}"
        );
        let cdr = Bytes::default()
            .record(op::SCHEMA, schema(1, Reference::NAME))
            .record(op::CHANNEL, channel(1, 1, "/cdr", "cdr"))
            .record(op::MESSAGE, message(1, 1));
        let e = read(&file(cdr)).1.expect_err("foreign encoding");
        assert!(
            e.ends_with("message encoding \"cdr\" with no taxel schema"),
            "{e}"
        );
    }
}
