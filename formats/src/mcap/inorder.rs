//! The fastest path of reading an MCAP message: the exact layout taxel's writer produces (every
//! field of the table, in the table's order, no whitespace: `{"sensor":"s0","seq":1,...}`) is
//! read in one pass, each key compared with the field it must be and each value parsed where
//! it stands, with nothing scanned twice and nothing looked up.
//!
//! It reads a strict subset of what [`super::flat`] reads, with the same number and string
//! rules (its values are parsed by the same functions), so for every message it reads, the
//! flat path (and so the general path) gives the same payload. Any other layout (whitespace,
//! another order, a missing or extra field, escapes) returns false and the caller takes the
//! flat path.

use taxel_msgs::{Field, Message, SensorIdBytes, Visitor};

use super::flat::{number_byte, number_prefix, to_f64, to_int};

struct InOrder<'a> {
    b: &'a [u8],
    /// The next unread byte.
    i: usize,
    /// No field read yet: the next key follows `{`, later ones `,`.
    first: bool,
    ok: bool,
}

impl InOrder<'_> {
    /// Reads `{"name":` (the first field) or `,"name":`; false (and the read gives up) when
    /// anything else is there.
    fn key(&mut self, f: &Field) -> bool {
        if !self.ok {
            return false;
        }
        let name = f.name.as_bytes();
        let open = if self.first { b'{' } else { b',' };
        self.first = false;
        let i = self.i;
        let end = i + name.len() + 4;
        // Names are short: a plain loop beats a call to memcmp.
        let found = self.b.len() >= end
            && self.b[i] == open
            && self.b[i + 1] == b'"'
            && self.b[i + 2..end - 2]
                .iter()
                .zip(name)
                .fold(true, |same, (a, b)| same & (a == b))
            && self.b[end - 2] == b'"'
            && self.b[end - 1] == b':';
        self.i = end;
        self.ok = found;
        found
    }

    /// The number at the read position (the whole run of number bytes, as the flat path
    /// delimits it), and its bytes.
    #[inline(always)]
    fn number(&mut self) -> Option<(super::flat::Number, &[u8])> {
        let start = self.i;
        let (n, len) = number_prefix(&self.b[start..])?;
        let end = start + len;
        if self.b.get(end).is_some_and(|&c| number_byte(c)) {
            return None;
        }
        self.i = end;
        Some((n, &self.b[start..end]))
    }

    /// A number or `null` (NaN).
    #[inline]
    fn float(&mut self) -> Option<f64> {
        if self.b[self.i..].starts_with(b"null") {
            self.i += 4;
            return Some(f64::NAN);
        }
        let (n, s) = self.number()?;
        to_f64(&n, s)
    }

    fn int<T: TryFrom<i128>>(&mut self, f: &Field, v: &mut T) {
        if !self.key(f) {
            return;
        }
        match self.number().and_then(|(n, _)| to_int(&n)) {
            Some(x) => match T::try_from(x) {
                Ok(x) => *v = x,
                Err(_) => self.ok = false,
            },
            None => self.ok = false,
        }
    }

    fn real(&mut self, f: &Field) -> Option<f64> {
        if !self.key(f) {
            return None;
        }
        let x = self.float();
        self.ok &= x.is_some();
        x
    }

    /// The entries of an array into `v`; `None` when it is not a list of numbers and nulls
    /// that fits.
    fn array(&mut self, v: &mut [f32]) -> Option<usize> {
        if self.b.get(self.i) != Some(&b'[') {
            return None;
        }
        self.i += 1;
        if self.b.get(self.i) == Some(&b']') {
            self.i += 1;
            return Some(0);
        }
        let mut n = 0;
        loop {
            let x = self.float()?;
            *v.get_mut(n)? = x as f32;
            n += 1;
            match self.b.get(self.i)? {
                b',' => self.i += 1,
                b']' => {
                    self.i += 1;
                    return Some(n);
                }
                _ => return None,
            }
        }
    }
}

impl Visitor for InOrder<'_> {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        if !self.key(f) {
            return;
        }
        // A plain string (no escapes, no control characters), shorter than the id.
        let rest = &self.b[self.i..];
        let len = match rest.first() {
            Some(b'"') => rest[1..]
                .iter()
                .position(|&c| c == b'"' || c == b'\\' || c < 0x20),
            _ => None,
        };
        match len {
            Some(len) if rest[1 + len] == b'"' && len < v.len() => {
                let s = &rest[1..1 + len];
                if !s.is_ascii() && std::str::from_utf8(s).is_err() {
                    self.ok = false;
                    return;
                }
                v[..len].copy_from_slice(s);
                self.i += len + 2;
            }
            _ => self.ok = false,
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
        if let Some(x) = self.real(f) {
            *v = x as f32;
        }
    }
    fn f64(&mut self, f: &Field, v: &mut f64) {
        if let Some(x) = self.real(f) {
            *v = x;
        }
    }
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        *len = 0;
        if !self.key(f) {
            return;
        }
        match self.array(v) {
            Some(n) => *len = n,
            None => self.ok = false,
        }
    }
    fn invalid(&mut self, _why: String) {
        self.ok = false;
    }
}

/// Fills a zero payload `m` from a message in the writer's exact layout; false when it is in
/// any other (then `m` holds anything).
pub(super) fn fill<M: Message>(b: &[u8], m: &mut M) -> bool {
    let mut r = InOrder {
        b,
        i: 0,
        first: true,
        ok: true,
    };
    m.visit(&mut r);
    r.ok && !r.first && r.i + 1 == b.len() && b[r.i] == b'}'
}
