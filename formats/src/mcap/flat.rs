//! The fast path of reading an MCAP message: taxel's own JSON messages are flat objects of
//! numbers, `null`, plain strings and arrays of numbers, so they are scanned in place (no
//! allocation, no map) and each field is parsed straight from its bytes into the payload.
//!
//! The scanner accepts a strict subset of JSON and the reader a strict subset of what the
//! general path ([`super::json`]) accepts. Anything else (escapes, nested values, a missing or
//! malformed field, an inconsistent array) returns `None`, and the caller decodes the message
//! with the general path, which either reads it the same way or names the error. So both paths
//! give the same payload for every input (except that the fast path's floats are correctly
//! rounded, where serde_json's may be one unit in the last place off), and the errors stay the
//! general path's.

use taxel_msgs::{Field, Message, SensorIdBytes, Visitor};

/// At most this many keys per object on the fast path (taxel's payloads have up to 16).
const MAX_KEYS: usize = 32;

/// A value as the scanner found it. Numbers and arrays are only delimited by the scan; they
/// are checked against the JSON grammar as they are parsed, or at the end when not read.
#[derive(Clone, Copy)]
enum Val<'a> {
    Null,
    /// The bytes of a number (a run of `0-9 + - . e E`).
    Num(&'a [u8]),
    /// A string without escapes, between its quotes.
    Str(&'a [u8]),
    /// The bytes between an array's brackets.
    Arr(&'a [u8]),
}

/// The keys and values of one flat JSON object, in file order.
pub(super) struct Flat<'a> {
    keys: [&'a [u8]; MAX_KEYS],
    vals: [Val<'a>; MAX_KEYS],
    n: usize,
}

fn ws(b: &[u8], mut i: usize) -> usize {
    while i < b.len() && matches!(b[i], b' ' | b'\t' | b'\n' | b'\r') {
        i += 1;
    }
    i
}

pub(super) fn number_byte(c: u8) -> bool {
    c.is_ascii_digit() || matches!(c, b'-' | b'+' | b'.' | b'e' | b'E')
}

/// A JSON number, as parsed: `mantissa` x 10^`exp10` with every digit kept when `exact`.
pub(super) struct Number {
    negative: bool,
    mantissa: u64,
    exp10: i32,
    /// No fraction and no exponent were written.
    integer: bool,
    /// The mantissa holds every digit (at most 19).
    exact: bool,
}

/// Parses `s` as exactly one JSON number (grammar of RFC 8259), or `None`.
fn number(s: &[u8]) -> Option<Number> {
    number_prefix(s).and_then(|(n, len)| (len == s.len()).then_some(n))
}

/// Parses the JSON number at the start of `s`: the number and how many bytes it takes, or
/// `None` when `s` does not start with one.
#[inline(always)]
pub(super) fn number_prefix(s: &[u8]) -> Option<(Number, usize)> {
    let negative = s.first() == Some(&b'-');
    let mut i = usize::from(negative);
    // Digits are accumulated with wrapping arithmetic: past 19 of them the mantissa is not
    // exact and is not used.
    let mut mantissa = 0u64;
    let mut kept = match s.get(i) {
        // A leading zero stands alone and is no digit of the mantissa.
        Some(b'0') => {
            i += 1;
            0
        }
        Some(b'1'..=b'9') => {
            let start = i;
            i = digits(s, i, &mut mantissa);
            i - start
        }
        _ => return None,
    };
    let (mut exp10, mut integer) = (0i32, true);
    if s.get(i) == Some(&b'.') {
        integer = false;
        let start = i + 1;
        i = digits(s, start, &mut mantissa);
        if i == start {
            return None;
        }
        kept += i - start;
        exp10 = i32::try_from(i - start).map_or(i32::MIN, |k| -k);
    }
    if matches!(s.get(i), Some(b'e' | b'E')) {
        integer = false;
        i += 1;
        let negative = match s.get(i) {
            Some(b'-') => (i += 1, true).1,
            Some(b'+') => (i += 1, false).1,
            _ => false,
        };
        let start = i;
        let mut e: i32 = 0;
        while let Some(&d @ b'0'..=b'9') = s.get(i) {
            e = e.saturating_mul(10).saturating_add(i32::from(d - b'0'));
            i += 1;
        }
        if i == start {
            return None;
        }
        exp10 = exp10.saturating_add(if negative { -e } else { e });
    }
    let n = Number {
        negative,
        mantissa,
        exp10,
        integer,
        exact: kept <= 19,
    };
    Some((n, i))
}

/// Reads decimal digits from `i` on into `m`; where they end.
#[inline]
fn digits(s: &[u8], mut i: usize, m: &mut u64) -> usize {
    while let Some(&c) = s.get(i) {
        let d = c.wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        *m = m.wrapping_mul(10).wrapping_add(u64::from(d));
        i += 1;
    }
    i
}

/// Powers of ten that a double holds exactly.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// The correctly rounded double of a number's bytes; `None` when not a number or too large.
fn float_of(s: &[u8]) -> Option<f64> {
    to_f64(&number(s)?, s)
}

/// The correctly rounded double of `n`, parsed from `s`; `None` when too large.
#[inline]
pub(super) fn to_f64(n: &Number, s: &[u8]) -> Option<f64> {
    // Clinger's fast path: an exact mantissa and power of ten give one correctly rounded
    // operation. Anything else goes to the standard library's parser.
    let x = if n.exact && n.mantissa < (1 << 53) && n.exp10.unsigned_abs() < 23 {
        let p = POW10[n.exp10.unsigned_abs() as usize];
        let m = n.mantissa as f64;
        let x = if n.exp10 < 0 { m / p } else { m * p };
        if n.negative {
            -x
        } else {
            x
        }
    } else {
        std::str::from_utf8(s).ok()?.parse::<f64>().ok()?
    };
    x.is_finite().then_some(x)
}

/// A number's bytes as an integer, when it is written as one that fits.
fn int_of(s: &[u8]) -> Option<i128> {
    to_int(&number(s)?)
}

/// `n` as an integer, when it is written as one that fits.
pub(super) fn to_int(n: &Number) -> Option<i128> {
    // The general path reads `-0` as a float, which no integer field takes.
    if !n.integer || !n.exact || (n.negative && n.mantissa == 0) {
        return None;
    }
    let x = i128::from(n.mantissa);
    Some(if n.negative { -x } else { x })
}

/// A scalar array entry as a float: `null` is NaN.
fn entry(s: &[u8]) -> Option<f64> {
    if s == b"null" {
        Some(f64::NAN)
    } else {
        float_of(s)
    }
}

/// Calls `f` on each entry of an array's inner bytes; `None` when they are not a list of
/// numbers and nulls.
fn entries(b: &[u8], mut f: impl FnMut(f64) -> Option<()>) -> Option<usize> {
    let mut i = ws(b, 0);
    if i == b.len() {
        return Some(0);
    }
    let mut n = 0;
    loop {
        let end = b[i..]
            .iter()
            .position(|&c| matches!(c, b',' | b' ' | b'\t' | b'\n' | b'\r'))
            .map_or(b.len(), |k| i + k);
        f(entry(&b[i..end])?)?;
        n += 1;
        i = ws(b, end);
        if i == b.len() {
            return Some(n);
        }
        if b[i] != b',' {
            return None;
        }
        i = ws(b, i + 1);
        if i == b.len() {
            return None;
        }
    }
}

/// A value left unread by the payload: is it JSON of the fast path's kinds?
fn valid(v: Val<'_>) -> bool {
    match v {
        Val::Null | Val::Str(_) => true,
        Val::Num(s) => number(s).is_some(),
        Val::Arr(b) => entries(b, |_| Some(())).is_some(),
    }
}

/// The end of a plain string starting at its opening quote `i`, and its contents.
fn string(b: &[u8], i: usize) -> Option<(usize, &[u8])> {
    if b.get(i) != Some(&b'"') {
        return None;
    }
    let rest = &b[i + 1..];
    let len = rest
        .iter()
        .position(|&c| c == b'"' || c == b'\\' || c < 0x20)?;
    if rest[len] != b'"' {
        return None;
    }
    let s = &rest[..len];
    if !s.is_ascii() {
        std::str::from_utf8(s).ok()?;
    }
    Some((i + 2 + len, s))
}

fn value(b: &[u8], i: usize) -> Option<(usize, Val<'_>)> {
    match b.get(i)? {
        b'"' => string(b, i).map(|(end, s)| (end, Val::Str(s))),
        b'[' => {
            let len = b[i + 1..].iter().position(|&c| c == b']')?;
            Some((i + 2 + len, Val::Arr(&b[i + 1..i + 1 + len])))
        }
        b'n' if b[i..].starts_with(b"null") => Some((i + 4, Val::Null)),
        _ => {
            let len = b[i..]
                .iter()
                .position(|&c| !number_byte(c))
                .unwrap_or(b.len() - i);
            (len > 0).then(|| (i + len, Val::Num(&b[i..i + len])))
        }
    }
}

impl<'a> Flat<'a> {
    /// Scans `b` as one flat object, or `None` when it is anything else.
    pub(super) fn scan(b: &'a [u8]) -> Option<Flat<'a>> {
        let mut f = Flat {
            keys: [&[]; MAX_KEYS],
            vals: [Val::Null; MAX_KEYS],
            n: 0,
        };
        let mut i = ws(b, 0);
        if b.get(i) != Some(&b'{') {
            return None;
        }
        i = ws(b, i + 1);
        if b.get(i) == Some(&b'}') {
            return (ws(b, i + 1) == b.len()).then_some(f);
        }
        loop {
            if f.n == MAX_KEYS {
                return None;
            }
            let (end, key) = string(b, i)?;
            i = ws(b, end);
            if b.get(i) != Some(&b':') {
                return None;
            }
            let (end, val) = value(b, ws(b, i + 1))?;
            (f.keys[f.n], f.vals[f.n]) = (key, val);
            f.n += 1;
            i = ws(b, end);
            match b.get(i)? {
                b',' => i = ws(b, i + 1),
                b'}' => return (ws(b, i + 1) == b.len()).then_some(f),
                _ => return None,
            }
        }
    }

    pub(super) fn has(&self, key: &str) -> bool {
        self.keys[..self.n].contains(&key.as_bytes())
    }

    /// Where `key` is; the last one when a key repeats, as in the general path.
    fn find(&self, key: &str) -> Option<usize> {
        self.keys[..self.n]
            .iter()
            .rposition(|k| *k == key.as_bytes())
    }
}

/// Fills a payload from a scanned object; gives up at the first doubt.
struct Reader<'a, 'b> {
    obj: &'b Flat<'a>,
    declared: Option<&'b [String]>,
    /// Bit `i`: entry `i` was read (and so checked).
    read: u32,
    ok: bool,
}

impl<'a> Reader<'a, '_> {
    /// The value of `f`; `None` when absent (the field stays zero, or the read gives up when
    /// the writer declared it).
    fn get(&mut self, f: &Field) -> Option<Val<'a>> {
        if !self.ok {
            return None;
        }
        match self.obj.find(f.name) {
            Some(i) => {
                self.read |= 1 << i;
                Some(self.obj.vals[i])
            }
            None => {
                self.ok &= self
                    .declared
                    .is_some_and(|d| !d.iter().any(|k| k == f.name));
                None
            }
        }
    }

    fn int<T: TryFrom<i128>>(&mut self, f: &Field, v: &mut T) {
        let Some(val) = self.get(f) else { return };
        match val {
            Val::Num(s) => match int_of(s).and_then(|x| T::try_from(x).ok()) {
                Some(x) => *v = x,
                None => self.ok = false,
            },
            _ => self.ok = false,
        }
    }

    fn float(&mut self, f: &Field) -> Option<f64> {
        let x = match self.get(f)? {
            Val::Null => Some(f64::NAN),
            Val::Num(s) => float_of(s),
            _ => None,
        };
        self.ok &= x.is_some();
        x
    }
}

impl Visitor for Reader<'_, '_> {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        match self.get(f) {
            None => {}
            Some(Val::Str(s)) if s.len() < v.len() => v[..s.len()].copy_from_slice(s),
            Some(_) => self.ok = false,
        }
    }
    fn u64(&mut self, f: &Field, v: &mut u64) {
        self.int(f, v);
    }
    fn u32(&mut self, f: &Field, v: &mut u32) {
        self.int(f, v);
    }
    fn u16(&mut self, f: &Field, v: &mut u16) {
        self.int(f, v);
    }
    fn i32(&mut self, f: &Field, v: &mut i32) {
        self.int(f, v);
    }
    fn f32(&mut self, f: &Field, v: &mut f32) {
        if let Some(x) = self.float(f) {
            *v = x as f32;
        }
    }
    fn f64(&mut self, f: &Field, v: &mut f64) {
        if let Some(x) = self.float(f) {
            *v = x;
        }
    }
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        *len = 0;
        let items = match self.get(f) {
            None => return,
            Some(Val::Arr(items)) => items,
            Some(_) => return self.ok = false,
        };
        let mut slots = v.iter_mut();
        let n = entries(items, |x| {
            *slots.next()? = x as f32;
            Some(())
        });
        match n {
            Some(n) => *len = n,
            None => self.ok = false,
        }
    }
    fn invalid(&mut self, _why: String) {
        self.ok = false;
    }
}

/// Fills a zero payload `m` from a scanned object; false when the general path must decide.
pub(super) fn fill<M: Message>(obj: &Flat<'_>, declared: Option<&[String]>, m: &mut M) -> bool {
    let mut r = Reader {
        obj,
        declared,
        read: 0,
        ok: true,
    };
    m.visit(&mut r);
    // Keys this build does not read must still be JSON.
    r.ok && (0..obj.n).all(|i| r.read & (1 << i) != 0 || valid(obj.vals[i]))
}
