//! The payload of a version-2 record, derived from the field tables of taxel-msgs: a `u8`
//! record kind (0 raw, 1 curvature, 2 force, 3 reference), a `u8` field count, then the
//! payload's fields in table order, each with bincode 2's standard config (integers as
//! varints, floats as 4 or 8 little-endian bytes, the sensor id as a length-prefixed string,
//! an array as a length followed by its meaningful entries). A reader takes the first `count`
//! fields of its own table: a field an older writer did not have reads as zero, fields a newer
//! writer added after its own are skipped.

use bincode::config::{standard, Configuration};
use taxel_msgs::{
    sensor_id_str, CurvatureEstimate, Field, ForceSample, Message, RawFrame, Reference,
    SensorIdBytes, Stream, Visitor,
};

use super::v1::sensor_bytes;
use super::Record;

const CONFIG: Configuration = standard();

/// The kind byte of a stream's records (the variant index of version 1's enum).
pub(super) fn kind(stream: Stream) -> u8 {
    match stream {
        Stream::Raw => 0,
        Stream::Curvature => 1,
        Stream::Force => 2,
        Stream::Reference => 3,
    }
}

/// Appends the payload of `m` to `buf` (no allocation once `buf` has grown).
pub(super) fn encode<M: Message>(m: &M, buf: &mut Vec<u8>) -> Result<(), String> {
    buf.push(kind(M::STREAM));
    let at = buf.len();
    buf.push(0);
    let mut e = Encoder {
        buf,
        fields: 0,
        err: None,
    };
    let mut m = *m;
    m.visit(&mut e);
    let (fields, err) = (e.fields, e.err);
    if let Some(err) = err {
        return Err(err);
    }
    buf[at] = u8::try_from(fields).map_err(|_| format!("{fields} fields (at most 255)"))?;
    Ok(())
}

struct Encoder<'a> {
    buf: &'a mut Vec<u8>,
    fields: usize,
    err: Option<String>,
}

impl Encoder<'_> {
    fn put<T: bincode::Encode>(&mut self, v: T) {
        if let Err(e) = bincode::encode_into_std_write(v, self.buf, CONFIG) {
            self.err.get_or_insert(e.to_string());
        }
    }
}

impl Visitor for Encoder<'_> {
    fn sensor(&mut self, _: &Field, v: &mut SensorIdBytes) {
        self.fields += 1;
        self.put(sensor_id_str(v));
    }
    fn u64(&mut self, _: &Field, v: &mut u64) {
        self.fields += 1;
        self.put(*v);
    }
    fn u32(&mut self, _: &Field, v: &mut u32) {
        self.fields += 1;
        self.put(*v);
    }
    fn u16(&mut self, _: &Field, v: &mut u16) {
        self.fields += 1;
        self.put(*v);
    }
    fn i32(&mut self, _: &Field, v: &mut i32) {
        self.fields += 1;
        self.put(*v);
    }
    fn f32(&mut self, _: &Field, v: &mut f32) {
        self.fields += 1;
        self.put(*v);
    }
    fn f64(&mut self, _: &Field, v: &mut f64) {
        self.fields += 1;
        self.put(*v);
    }
    fn f32s(&mut self, _: &Field, v: &mut [f32], len: &mut usize) {
        self.fields += 1;
        let n = (*len).min(v.len());
        self.put(n as u64);
        for x in &v[..n] {
            self.put(*x);
        }
    }
}

/// Decodes one version-2 payload.
pub(super) fn decode(payload: &[u8]) -> Result<Record, String> {
    let (kind, count, rest) = split(payload)?;
    let mut d = Decoder::new(rest, count, None);
    let rec = match kind {
        0 => Record::Raw(Box::new(d.message::<RawFrame>())),
        1 => Record::Curvature(Box::new(d.message::<CurvatureEstimate>())),
        2 => Record::Force(d.message::<ForceSample>()),
        3 => Record::Reference(d.message::<Reference>()),
        k => return Err(format!("unknown record kind {k}")),
    };
    d.finish()?;
    Ok(rec)
}

/// The reader's own payload of each kind, refilled by [`decode_into`].
#[derive(Default)]
pub(super) struct Slots {
    recs: [Option<Record>; 4],
    /// Per kind: the longest array written into the payload so far (entries from there on
    /// are still zero).
    high: [usize; 4],
    /// Per kind: the number of fields of this build's table (0 until first needed).
    table: [usize; 4],
    /// The kind decoded last.
    last: usize,
}

impl Slots {
    /// The payload decoded last.
    pub(super) fn last(&mut self) -> Option<&mut Record> {
        self.recs.get_mut(self.last)?.as_mut()
    }

    /// Keeps a record decoded whole (a version-1 file) as the payload of its kind.
    pub(super) fn put(&mut self, rec: Record) -> &mut Record {
        let k = kind(rec.stream()) as usize;
        self.last = k;
        // Not refilled in place: its arrays' high-water mark is unknown.
        self.high[k] = usize::MAX;
        self.recs[k].insert(rec)
    }
}

/// Decodes one version-2 payload into `slots`' payload of its kind: the same value as
/// [`decode`] (fields the record lacks read as the empty payload's, array entries past its
/// length as zero), without a new payload, and a raw frame's 4 KiB reset, per record.
pub(super) fn decode_into<'s>(
    payload: &[u8],
    slots: &'s mut Slots,
) -> Result<&'s mut Record, String> {
    let (kind, count, rest) = split(payload)?;
    let k = kind as usize;
    slots.last = k;
    let slot = match slots.recs.get_mut(k) {
        Some(slot) => slot,
        None => return Err(format!("unknown record kind {kind}")),
    };
    let empty = || match kind {
        0 => Record::Raw(Box::new(RawFrame::ZERO)),
        1 => Record::Curvature(Box::new(CurvatureEstimate::ZERO)),
        2 => Record::Force(ForceSample::ZERO),
        _ => Record::Reference(Reference::ZERO),
    };
    let rec = slot.get_or_insert_with(empty);
    if slots.table[k] == 0 {
        slots.table[k] = match kind {
            0 => taxel_msgs::fields::names::<RawFrame>().len(),
            1 => taxel_msgs::fields::names::<CurvatureEstimate>().len(),
            2 => taxel_msgs::fields::names::<ForceSample>().len(),
            _ => taxel_msgs::fields::names::<Reference>().len(),
        };
    }
    if (count as usize) < slots.table[k] {
        // An older writer's record: the fields it lacks read as the empty payload's.
        *rec = empty();
        slots.high[k] = 0;
    }
    let mut d = Decoder::new(rest, count, Some(&mut slots.high[k]));
    match rec {
        Record::Raw(m) => m.visit(&mut d),
        Record::Curvature(m) => m.visit(&mut d),
        Record::Force(m) => m.visit(&mut d),
        Record::Reference(m) => m.visit(&mut d),
    }
    if let Err(e) = d.finish() {
        // A payload left half-written is not handed over, nor refilled.
        *slot = None;
        return Err(e);
    }
    slot.as_mut().ok_or_else(|| "record slot lost".to_string())
}

/// A payload's kind byte, field count and fields.
fn split(payload: &[u8]) -> Result<(u8, u8, &[u8]), String> {
    let (&kind, rest) = payload.split_first().ok_or("empty record")?;
    let (&count, rest) = rest.split_first().ok_or("record without a field count")?;
    Ok((kind, count, rest))
}

struct Decoder<'a> {
    buf: &'a [u8],
    pos: usize,
    /// Fields the record still holds.
    left: usize,
    err: Option<String>,
    /// Decoding into a reused payload: its longest array so far; array entries past the new
    /// length (up to this) are cleared.
    reuse: Option<&'a mut usize>,
}

impl<'a> Decoder<'a> {
    fn new(buf: &'a [u8], count: u8, reuse: Option<&'a mut usize>) -> Decoder<'a> {
        Decoder {
            buf,
            pos: 0,
            left: count as usize,
            err: None,
            reuse,
        }
    }

    fn message<M: Message>(&mut self) -> M {
        let mut m = M::zero();
        m.visit(self);
        m
    }

    /// The first error, or whether every byte was used. Fields this build does not know (a
    /// newer writer's) are skipped; otherwise every byte must have been used.
    fn finish(self) -> Result<(), String> {
        if let Some(e) = self.err {
            return Err(e);
        }
        if self.left == 0 && self.pos != self.buf.len() {
            return Err(super::TRAILING.into());
        }
        Ok(())
    }

    /// Whether the next field is in the record (and nothing failed so far).
    fn next(&mut self) -> bool {
        if self.err.is_some() || self.left == 0 {
            return false;
        }
        self.left -= 1;
        true
    }

    fn take<T: bincode::Decode<()>>(&mut self, f: &Field) -> Option<T> {
        match bincode::decode_from_slice::<T, _>(&self.buf[self.pos..], CONFIG) {
            Ok((v, used)) => {
                self.pos += used;
                Some(v)
            }
            Err(e) => {
                self.err.get_or_insert(format!("{}: {e}", f.name));
                None
            }
        }
    }

    fn set<T: bincode::Decode<()>>(&mut self, f: &Field, v: &mut T) {
        if self.next() {
            if let Some(x) = self.take(f) {
                *v = x;
            }
        }
    }

    /// Reads an array into `v`; the number of entries read (0 when the record lacks it or it
    /// does not decode).
    fn array(&mut self, f: &Field, v: &mut [f32]) -> usize {
        if !self.next() {
            return 0;
        }
        let Some(n) = self.take::<u64>(f) else {
            return 0;
        };
        if n > v.len() as u64 {
            self.err
                .get_or_insert(format!("{} has {n} entries (at most {})", f.name, v.len()));
            return 0;
        }
        let n = n as usize;
        // Floats are 4 little-endian bytes each in bincode's standard config.
        let Some(bytes) = self.buf.get(self.pos..self.pos + 4 * n) else {
            self.err.get_or_insert(format!("{}: cut short", f.name));
            return 0;
        };
        for (x, b) in v.iter_mut().zip(bytes.chunks_exact(4)) {
            *x = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        self.pos += 4 * n;
        n
    }
}

impl Visitor for Decoder<'_> {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        if !self.next() {
            return;
        }
        let Some(n) = self.take::<u64>(f) else {
            return;
        };
        let end = self.pos.saturating_add(n as usize);
        let Some(bytes) = self.buf.get(self.pos..end) else {
            self.err.get_or_insert(format!("{}: cut short", f.name));
            return;
        };
        match sensor_bytes(bytes) {
            Ok(b) => {
                *v = b;
                self.pos = end;
            }
            Err(e) => {
                self.err.get_or_insert(e);
            }
        }
    }
    fn u64(&mut self, f: &Field, v: &mut u64) {
        self.set(f, v);
    }
    fn u32(&mut self, f: &Field, v: &mut u32) {
        self.set(f, v);
    }
    fn u16(&mut self, f: &Field, v: &mut u16) {
        self.set(f, v);
    }
    fn i32(&mut self, f: &Field, v: &mut i32) {
        self.set(f, v);
    }
    fn f32(&mut self, f: &Field, v: &mut f32) {
        self.set(f, v);
    }
    fn f64(&mut self, f: &Field, v: &mut f64) {
        self.set(f, v);
    }
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        let n = self.array(f, v);
        *len = n;
        if let Some(high) = self.reuse.as_deref_mut() {
            let top = (*high).min(v.len());
            if n < top {
                v[n..top].fill(0.0);
            }
            *high = (*high).max(n);
        }
    }
    fn invalid(&mut self, why: String) {
        self.err.get_or_insert(why);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn force() -> ForceSample {
        let mut f = ForceSample::ZERO;
        f.sensor = taxel_msgs::sensor_id_bytes("s0").expect("id");
        (f.seq, f.t_capture_ns, f.t_publish_ns) = (42, 1_000, 1_200);
        (f.total_force_n, f.total_reading, f.curvature_m1) = (2.5, 310.0, 40.0);
        (f.cal_version, f.cal_generation, f.flags) = (3, 2, 0b100);
        f.n_blocks = 2;
        f.block_force_n[..2].copy_from_slice(&[1.0, f32::NAN]);
        f.block_reading[..2].copy_from_slice(&[100.0, 210.0]);
        f.curvature_model_version = 7;
        f.zero_age_s = 12.5;
        f
    }

    fn encoded(f: &ForceSample) -> Vec<u8> {
        let mut buf = Vec::new();
        encode(f, &mut buf).expect("encode");
        buf
    }

    fn same(a: &Record, b: &Record) -> bool {
        format!("{a:?}") == format!("{b:?}")
    }

    #[test]
    fn every_field_round_trips() {
        let f = force();
        let back = decode(&encoded(&f)).expect("decode");
        assert!(same(&back, &Record::Force(f)), "{back:?}");
        // A raw frame: only the meaningful readings are stored.
        let mut r = RawFrame::ZERO;
        (r.rows, r.cols, r.seq) = (2, 3, 9);
        r.counts[..6].copy_from_slice(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        r.counts[6] = 99.0;
        let mut buf = Vec::new();
        encode(&r, &mut buf).expect("encode");
        assert!(buf.len() < 60, "{} bytes", buf.len());
        let Ok(Record::Raw(back)) = decode(&buf) else {
            panic!("not a raw frame")
        };
        assert_eq!((back.nodes(), back.counts[6]), (&r.counts[..6], 0.0));
    }

    #[test]
    fn a_field_an_older_writer_lacked_reads_as_zero_and_a_newer_ones_are_skipped() {
        let f = force();
        let full = encoded(&f);
        // zero_age_s (an f32, 4 bytes) is the table's last field, after
        // curvature_model_version (7, one varint byte): a writer without either reads them as
        // the empty sample's (NaN: no zero known; 0).
        let mut older = full[..full.len() - 4].to_vec();
        older[1] -= 1;
        let mut want = f;
        want.zero_age_s = f32::NAN;
        assert!(same(&decode(&older).expect("older"), &Record::Force(want)));
        let mut oldest = full[..full.len() - 5].to_vec();
        oldest[1] -= 2;
        want.curvature_model_version = 0;
        assert!(same(
            &decode(&oldest).expect("oldest"),
            &Record::Force(want)
        ));
        // A newer writer's extra field after the known ones.
        let mut newer = full.clone();
        newer[1] += 1;
        newer.push(5);
        assert!(same(&decode(&newer).expect("newer"), &Record::Force(f)));
        // Bytes past the last field of the same table are damage.
        let mut trailing = full;
        trailing.push(5);
        assert_eq!(
            decode(&trailing).err().as_deref(),
            Some(super::super::TRAILING)
        );
    }

    #[test]
    fn inconsistent_sizes_are_refused() {
        let mut r = RawFrame::ZERO;
        (r.rows, r.cols) = (2, 2);
        let mut buf = Vec::new();
        encode(&r, &mut buf).expect("encode");
        // rows is the 4th field: sensor (1 byte: empty), seq, t_capture_ns (1 byte each).
        assert_eq!(buf[2..6], [0, 0, 0, 2]);
        buf[5] = 3;
        let e = decode(&buf).expect_err("3 x 2 with 4 counts");
        assert!(e.contains("counts has 4 entries for rows x cols 6"), "{e}");
    }

    #[test]
    fn decoding_into_a_reused_payload_gives_what_a_fresh_one_does() {
        let f = force();
        let full = encoded(&f);
        let mut older = full[..full.len() - 5].to_vec();
        older[1] -= 2;
        let mut fewer = f;
        fewer.n_blocks = 1;
        fewer.block_force_n[..2].copy_from_slice(&[3.0, 0.0]);
        fewer.block_reading[..2].copy_from_slice(&[4.0, 0.0]);
        fewer.zero_age_s = 1.0;
        let raw = |rows: u16, cols: u16| {
            let mut r = RawFrame::ZERO;
            (r.rows, r.cols, r.seq) = (rows, cols, rows as u64);
            for (i, c) in r.counts[..(rows * cols) as usize].iter_mut().enumerate() {
                *c = 1.0 + i as f32;
            }
            let mut buf = Vec::new();
            encode(&r, &mut buf).expect("encode");
            buf
        };
        // Arrays that shrink and grow again, and an older writer's record after a full one.
        let payloads = [
            full.clone(),
            raw(4, 4),
            encoded(&fewer),
            raw(2, 3),
            older,
            raw(4, 4),
            full,
            raw(1, 1),
        ];
        let mut slots = Slots::default();
        for (i, p) in payloads.iter().enumerate() {
            let want = decode(p).expect("decode");
            let got = decode_into(p, &mut slots).expect("decode_into");
            assert!(same(got, &want), "payload {i}: {got:?}");
            assert!(same(slots.last().expect("last"), &want), "payload {i}");
        }
        // A payload that fails is not handed over, and the next one decodes whole.
        let mut bad = raw(2, 2);
        bad[5] = 3;
        assert!(decode_into(&bad, &mut slots).is_err());
        let next = raw(1, 2);
        let got = decode_into(&next, &mut slots).expect("after an error");
        assert!(same(got, &decode(&next).expect("decode")));
        assert!(decode_into(&[9, 0], &mut slots).is_err());
    }
}
