//! The logger's record file: an 8-byte magic `TAXELREC`, a little-endian u16 format version, a
//! u16 reserved (0), then records, each framed as `u32 length | u32 CRC-32 of the payload |
//! payload` (little endian). Version 2 payloads are derived from the field tables of
//! taxel-msgs (`binary`); version 1 files, whose payloads are a bincode 2 (serde) enum written
//! out by hand, still read (`v1`). A file cut off by a crash reads cleanly up to its last
//! complete record: the reader reports where the incomplete tail starts instead of failing.

mod binary;
mod v1;

pub(crate) use v1::shape_of;

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use taxel_msgs::{
    sensor_id_str, CurvatureEstimate, ForceSample, Message, RawFrame, Reference, Stream, Visitor,
};

use crate::crc::crc32;

pub const MAGIC: &[u8; 8] = b"TAXELREC";
/// The format version this build writes.
pub const VERSION: u16 = 2;
/// The format versions this build reads.
pub const READS: [u16; 2] = [1, 2];
const HEADER_LEN: u64 = 12;
/// What a payload decoder says when the payload has bytes past its last field.
const TRAILING: &str = "trailing bytes";
/// Largest payload a record may have; a larger length field means corruption.
pub const MAX_RECORD: u32 = 1 << 20;

/// One logged message: a shared-memory payload of taxel-msgs as it was published (the large
/// ones boxed). Only the meaningful entries of its arrays are stored in files.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    Raw(Box<RawFrame>),
    Curvature(Box<CurvatureEstimate>),
    Force(ForceSample),
    Reference(Reference),
}

impl Record {
    /// The stream the payload travelled on.
    pub fn stream(&self) -> Stream {
        match self {
            Record::Raw(_) => Stream::Raw,
            Record::Curvature(_) => Stream::Curvature,
            Record::Force(_) => Stream::Force,
            Record::Reference(_) => Stream::Reference,
        }
    }

    /// The schema name of the payload (`taxel.ForceSample`).
    pub fn name(&self) -> &'static str {
        match self {
            Record::Raw(_) => RawFrame::NAME,
            Record::Curvature(_) => CurvatureEstimate::NAME,
            Record::Force(_) => ForceSample::NAME,
            Record::Reference(_) => Reference::NAME,
        }
    }

    pub fn sensor(&self) -> &str {
        sensor_id_str(match self {
            Record::Raw(m) => &m.sensor,
            Record::Curvature(m) => &m.sensor,
            Record::Force(m) => &m.sensor,
            Record::Reference(m) => &m.sensor,
        })
    }

    pub fn seq(&self) -> u64 {
        match self {
            Record::Raw(m) => m.seq,
            Record::Curvature(m) => m.seq,
            Record::Force(m) => m.seq,
            Record::Reference(m) => m.seq,
        }
    }

    pub fn t_capture_ns(&self) -> u64 {
        match self {
            Record::Raw(m) => m.t_capture_ns,
            Record::Curvature(m) => m.t_capture_ns,
            Record::Force(m) => m.t_capture_ns,
            Record::Reference(m) => m.t_capture_ns,
        }
    }

    /// Visits the payload's fields (taxel-msgs `Message::visit`).
    pub fn visit<V: Visitor>(&mut self, v: &mut V) {
        match self {
            Record::Raw(m) => m.visit(v),
            Record::Curvature(m) => m.visit(v),
            Record::Force(m) => m.visit(v),
            Record::Reference(m) => m.visit(v),
        }
    }
}

impl From<RawFrame> for Record {
    fn from(m: RawFrame) -> Record {
        Record::Raw(Box::new(m))
    }
}
impl From<CurvatureEstimate> for Record {
    fn from(m: CurvatureEstimate) -> Record {
        Record::Curvature(Box::new(m))
    }
}
impl From<ForceSample> for Record {
    fn from(m: ForceSample) -> Record {
        Record::Force(m)
    }
}
impl From<Reference> for Record {
    fn from(m: Reference) -> Record {
        Record::Reference(m)
    }
}

/// Why a record file could not be opened or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: not a taxel record file (bad magic at byte 0)")]
    BadMagic { path: PathBuf },
    #[error(
        "{path}: record file version {found} is not supported (this build reads versions 1 and 2)"
    )]
    Version { path: PathBuf, found: u16 },
    #[error("cannot encode record: {0}")]
    Encode(String),
}

/// Appends records to a file; records reach the OS on [`RecordFileWriter::flush`].
pub struct RecordFileWriter {
    out: BufWriter<File>,
    path: PathBuf,
    buf: Vec<u8>,
    /// Bytes handed to the OS and known complete.
    committed: u64,
    pending: u64,
}

impl RecordFileWriter {
    /// Creates (truncates) `path` and writes the header.
    pub fn create(path: &Path) -> Result<RecordFileWriter, RecordError> {
        let io = |source| RecordError::Io {
            path: path.to_path_buf(),
            error: source,
        };
        let file = File::create(path).map_err(io)?;
        let mut out = BufWriter::with_capacity(1 << 18, file);
        let mut header = [0u8; HEADER_LEN as usize];
        header[..8].copy_from_slice(MAGIC);
        header[8..10].copy_from_slice(&VERSION.to_le_bytes());
        out.write_all(&header).map_err(io)?;
        out.flush().map_err(io)?;
        Ok(RecordFileWriter {
            out,
            path: path.to_path_buf(),
            buf: Vec::with_capacity(8192),
            committed: HEADER_LEN,
            pending: 0,
        })
    }

    /// Encodes and buffers one record (no allocation once the buffer has grown).
    pub fn append(&mut self, rec: &Record) -> Result<(), RecordError> {
        match rec {
            Record::Raw(m) => self.append_message(&**m),
            Record::Curvature(m) => self.append_message(&**m),
            Record::Force(m) => self.append_message(m),
            Record::Reference(m) => self.append_message(m),
        }
    }

    /// Encodes and buffers one payload as a record (no allocation once the buffer has grown).
    pub fn append_message<M: Message>(&mut self, m: &M) -> Result<(), RecordError> {
        self.buf.clear();
        self.buf.extend_from_slice(&[0u8; 8]);
        binary::encode(m, &mut self.buf).map_err(RecordError::Encode)?;
        let len = (self.buf.len() - 8) as u32;
        let crc = crc32(&self.buf[8..]);
        self.buf[..4].copy_from_slice(&len.to_le_bytes());
        self.buf[4..8].copy_from_slice(&crc.to_le_bytes());
        self.out
            .write_all(&self.buf)
            .map_err(|source| RecordError::Io {
                path: self.path.clone(),
                error: source,
            })?;
        self.pending += self.buf.len() as u64;
        Ok(())
    }

    /// Hands buffered records to the OS. On error (e.g. disk full) the records buffered since
    /// the last successful flush may be lost; earlier ones stay intact.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.out.flush().map_err(|source| RecordError::Io {
            path: self.path.clone(),
            error: source,
        })?;
        self.committed += self.pending;
        self.pending = 0;
        Ok(())
    }

    /// Bytes known to be in the file.
    pub fn committed_bytes(&self) -> u64 {
        self.committed
    }

    /// Flushes and syncs to disk.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.flush()?;
        self.out
            .get_ref()
            .sync_all()
            .map_err(|source| RecordError::Io {
                path: self.path.clone(),
                error: source,
            })?;
        Ok(self.committed)
    }
}

/// How the file ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Tail {
    /// Every byte belonged to a complete record.
    Clean,
    /// The bytes from `offset` on do not form a complete, valid record (a crash cut the file,
    /// or it is damaged there); `reason` says which check failed.
    Incomplete { offset: u64, reason: String },
}

/// Reads records one by one, stopping at the first incomplete or damaged one.
pub struct RecordFileReader {
    input: BufReader<File>,
    path: PathBuf,
    version: u16,
    offset: u64,
    tail: Option<Tail>,
    buf: Vec<u8>,
    /// Complete records returned so far.
    records: u64,
    /// The reader stopped because the file ended (cut short), not at damaged bytes.
    cut: bool,
    /// The payloads [`RecordFileReader::next_view`] refills.
    slots: binary::Slots,
}

impl RecordFileReader {
    pub fn open(path: &Path) -> Result<RecordFileReader, RecordError> {
        let io = |source| RecordError::Io {
            path: path.to_path_buf(),
            error: source,
        };
        let file = File::open(path).map_err(io)?;
        let mut input = BufReader::with_capacity(1 << 18, file);
        let mut header = [0u8; HEADER_LEN as usize];
        input.read_exact(&mut header).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                RecordError::BadMagic {
                    path: path.to_path_buf(),
                }
            } else {
                io(e)
            }
        })?;
        if &header[..8] != MAGIC {
            return Err(RecordError::BadMagic {
                path: path.to_path_buf(),
            });
        }
        let found = u16::from_le_bytes([header[8], header[9]]);
        if !READS.contains(&found) {
            return Err(RecordError::Version {
                path: path.to_path_buf(),
                found,
            });
        }
        Ok(RecordFileReader {
            input,
            path: path.to_path_buf(),
            version: found,
            offset: HEADER_LEN,
            tail: None,
            buf: Vec::new(),
            records: 0,
            cut: false,
            slots: binary::Slots::default(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's format version.
    pub fn version(&self) -> u16 {
        self.version
    }

    /// How the file ended; `None` until the reader has reached the end.
    pub fn tail(&self) -> Option<&Tail> {
        self.tail.as_ref()
    }

    /// Complete records read so far (after an incomplete tail: the index of the record where
    /// reading stopped, counting from 0).
    pub fn records_read(&self) -> u64 {
        self.records
    }

    /// True when reading stopped at damaged bytes inside the file (a checksum mismatch, an
    /// implausible length, a record that does not decode) rather than at a tail cut short by
    /// the end of the file, which is what a crash of the writer leaves.
    pub fn damaged(&self) -> bool {
        matches!(self.tail, Some(Tail::Incomplete { .. })) && !self.cut
    }

    /// Where reading stopped, for messages: `record N at byte X (reason)`; None if the file
    /// ended cleanly or has not been read to its end.
    pub fn stop_position(&self) -> Option<String> {
        match &self.tail {
            Some(Tail::Incomplete { offset, reason }) => Some(format!(
                "record {} at byte {offset} ({reason})",
                self.records
            )),
            _ => None,
        }
    }

    /// Ends reading at the current record; always false (for `read_payload`).
    fn stop(&mut self, reason: String) -> bool {
        self.tail = Some(Tail::Incomplete {
            offset: self.offset,
            reason,
        });
        false
    }

    /// The next complete record, or `None` at the end (see [`RecordFileReader::tail`]).
    pub fn next_record(&mut self) -> Option<Record> {
        if !self.read_payload() {
            return None;
        }
        let decoded = match self.version {
            1 => v1::decode(&self.buf),
            _ => binary::decode(&self.buf),
        };
        match decoded {
            Ok(rec) => {
                self.advance();
                Some(rec)
            }
            Err(e) => self.refuse(e),
        }
    }

    /// Like [`RecordFileReader::next_record`], borrowed: the reader's own payload of the
    /// record's type, refilled by the next record of that type (no payload is made per
    /// record: the fastest way through a file).
    pub fn next_view(&mut self) -> Option<&mut Record> {
        if !self.read_payload() {
            return None;
        }
        if self.version == 1 {
            return match v1::decode(&self.buf) {
                Ok(rec) => {
                    self.advance();
                    Some(self.slots.put(rec))
                }
                Err(e) => self.refuse(e),
            };
        }
        match binary::decode_into(&self.buf, &mut self.slots) {
            Ok(_) => {
                self.advance();
                self.slots.last()
            }
            Err(e) => self.refuse(e),
        }
    }

    /// Counts the record just decoded.
    fn advance(&mut self) {
        self.offset += 8 + self.buf.len() as u64;
        self.records += 1;
    }

    fn refuse<T>(&mut self, e: String) -> Option<T> {
        let reason = if e == TRAILING {
            "record has trailing bytes".into()
        } else {
            format!("record does not decode: {e}")
        };
        self.stop(reason);
        None
    }

    /// Reads the next record's payload into `buf` and checks its checksum; false at the end of
    /// the file or at a record that cannot be read (the tail says which).
    fn read_payload(&mut self) -> bool {
        if self.tail.is_some() {
            return false;
        }
        let mut head = [0u8; 8];
        let mut got = 0;
        while got < 8 {
            match self.input.read(&mut head[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return self.stop(format!("read error: {e}")),
            }
        }
        if got == 0 {
            self.tail = Some(Tail::Clean);
            return false;
        }
        if got < 8 {
            self.cut = true;
            return self.stop(format!("record header cut after {got} of 8 bytes"));
        }
        let len = u32::from_le_bytes([head[0], head[1], head[2], head[3]]);
        let crc = u32::from_le_bytes([head[4], head[5], head[6], head[7]]);
        if len == 0 || len > MAX_RECORD {
            return self.stop(format!("implausible record length {len}"));
        }
        self.buf.resize(len as usize, 0);
        if let Err(e) = self.input.read_exact(&mut self.buf) {
            self.cut = e.kind() == std::io::ErrorKind::UnexpectedEof;
            return self.stop(format!("record of {len} bytes cut short ({e})"));
        }
        if crc32(&self.buf) != crc {
            return self.stop("record checksum mismatch".into());
        }
        true
    }
}

impl Iterator for RecordFileReader {
    type Item = Record;
    fn next(&mut self) -> Option<Record> {
        self.next_record()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(seq: u64) -> Record {
        let mut f = RawFrame::ZERO;
        f.sensor = taxel_msgs::sensor_id_bytes("s0").expect("id");
        (f.seq, f.t_capture_ns, f.rows, f.cols) = (seq, 1000 + seq, 2, 2);
        (f.source, f.full_scale) = (1, 1023.0);
        f.counts[..4].copy_from_slice(&[seq as f32, 1.0, 2.0, 3.0]);
        f.into()
    }

    #[test]
    fn round_trip_and_truncation_recovery() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("r.taxrec");
        let mut w = RecordFileWriter::create(&path).expect("create");
        let mut ends = Vec::new();
        for seq in 0..50 {
            w.append(&raw(seq)).expect("append");
            w.flush().expect("flush");
            ends.push(w.committed_bytes());
        }
        w.append(&Record::Reference(Reference {
            seq: 50,
            t_capture_ns: 7,
            sensor: taxel_msgs::sensor_id_bytes("s0").expect("id"),
            t_source_s: 0.1,
            force_n: 2.0,
            curvature_m1: 40.0,
            temp_c: 25.0,
            trial: 3,
        }))
        .expect("append");
        let total = w.finish().expect("finish");
        let all: Vec<Record> = RecordFileReader::open(&path).expect("open").collect();
        assert_eq!(all.len(), 51);
        assert_eq!(all[7], raw(7));

        // Every cut point reads back the complete records before it, and says where it stopped.
        let bytes = std::fs::read(&path).expect("read");
        assert_eq!(bytes.len() as u64, total);
        for cut in (HEADER_LEN as usize..bytes.len()).step_by(7) {
            std::fs::write(&path, &bytes[..cut]).expect("write");
            let mut r = RecordFileReader::open(&path).expect("open");
            let n = r.by_ref().count();
            let complete = ends.iter().filter(|&&e| e <= cut as u64).count();
            assert_eq!(n, complete, "cut at {cut}");
            let clean = cut as u64 == HEADER_LEN || ends.contains(&(cut as u64));
            assert_eq!(r.tail() == Some(&Tail::Clean), clean, "cut at {cut}");
        }
    }

    #[test]
    fn views_are_the_records() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("v.taxrec");
        let mut w = RecordFileWriter::create(&path).expect("create");
        for seq in 0..20 {
            let mut r = raw(seq);
            if let Record::Raw(f) = &mut r {
                // 2 x 2 and 1 x 3 frames in turn: the reused payload's tail must be cleared.
                if seq % 3 == 1 {
                    (f.rows, f.cols) = (1, 3);
                    f.counts[3] = 0.0;
                }
            }
            w.append(&r).expect("append");
            let mut reference = Reference::ZERO;
            (reference.seq, reference.force_n) = (seq, seq as f32 * 0.5);
            w.append(&Record::Reference(reference)).expect("append");
        }
        w.finish().expect("finish");
        let all: Vec<Record> = RecordFileReader::open(&path).expect("open").collect();
        let mut r = RecordFileReader::open(&path).expect("open");
        let mut views = Vec::new();
        while let Some(v) = r.next_view() {
            views.push(v.clone());
        }
        assert_eq!(views, all);
        assert_eq!(r.tail(), Some(&Tail::Clean));
        assert_eq!(r.records_read(), 40);
    }

    #[test]
    fn damaged_record_stops_reading_with_its_offset() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("d.taxrec");
        let mut w = RecordFileWriter::create(&path).expect("create");
        for seq in 0..3 {
            w.append(&raw(seq)).expect("append");
        }
        w.finish().expect("finish");
        let mut bytes = std::fs::read(&path).expect("read");
        let second = HEADER_LEN as usize + (bytes.len() - HEADER_LEN as usize) / 3;
        bytes[second + 12] ^= 0xFF;
        std::fs::write(&path, &bytes).expect("write");
        let mut r = RecordFileReader::open(&path).expect("open");
        assert_eq!(r.by_ref().count(), 1);
        match r.tail() {
            Some(Tail::Incomplete { offset, reason }) => {
                assert_eq!(*offset, second as u64);
                assert!(reason.contains("checksum"), "{reason}");
            }
            other => panic!("unexpected tail {other:?}"),
        }
    }

    #[test]
    fn foreign_files_are_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("x");
        std::fs::write(&path, b"t_s,n0\n0,1\n").expect("write");
        assert!(matches!(
            RecordFileReader::open(&path),
            Err(RecordError::BadMagic { .. })
        ));
        std::fs::write(&path, b"TAX").expect("write");
        assert!(RecordFileReader::open(&path).is_err());
        let mut v = MAGIC.to_vec();
        v.extend_from_slice(&[9, 0, 0, 0]);
        std::fs::write(&path, &v).expect("write");
        assert!(matches!(
            RecordFileReader::open(&path),
            Err(RecordError::Version { found: 9, .. })
        ));
    }
}
