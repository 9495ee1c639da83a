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
    let (&kind, rest) = payload.split_first().ok_or("empty record")?;
    let (&count, rest) = rest.split_first().ok_or("record without a field count")?;
    let mut d = Decoder {
        buf: rest,
        pos: 0,
        left: count as usize,
        err: None,
    };
    let rec = match kind {
        0 => Record::Raw(Box::new(d.message::<RawFrame>())),
        1 => Record::Curvature(Box::new(d.message::<CurvatureEstimate>())),
        2 => Record::Force(d.message::<ForceSample>()),
        3 => Record::Reference(d.message::<Reference>()),
        k => return Err(format!("unknown record kind {k}")),
    };
    if let Some(e) = d.err {
        return Err(e);
    }
    // Fields this build does not know (a newer writer's) are skipped; otherwise every byte
    // must have been used.
    if d.left == 0 && d.pos != d.buf.len() {
        return Err(super::TRAILING.into());
    }
    Ok(rec)
}

struct Decoder<'a> {
    buf: &'a [u8],
    pos: usize,
    /// Fields the record still holds.
    left: usize,
    err: Option<String>,
}

impl Decoder<'_> {
    fn message<M: Message>(&mut self) -> M {
        let mut m = M::zero();
        m.visit(self);
        m
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
        *len = 0;
        if !self.next() {
            return;
        }
        let Some(n) = self.take::<u64>(f) else {
            return;
        };
        if n > v.len() as u64 {
            self.err
                .get_or_insert(format!("{} has {n} entries (at most {})", f.name, v.len()));
            return;
        }
        for x in v.iter_mut().take(n as usize) {
            match self.take::<f32>(f) {
                Some(y) => *x = y,
                None => return,
            }
        }
        *len = n as usize;
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
}
