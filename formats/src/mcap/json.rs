//! The JSON side of the MCAP files, derived from the field tables of taxel-msgs: one JSON object
//! per message with the payload's fields in table order (field names carry units; arrays hold
//! the meaningful entries), and the JSON Schema of each payload. Non-finite floats are written
//! as `null` and read back as NaN.
//!
//! Reading follows the channel's own schema: a field this build knows and the writer's schema
//! lists must be present; one the writer did not have (an older version) reads as zero, and
//! keys this build does not know (a newer version) are ignored. Estimates written before they
//! carried `rows` and `cols` get the shape of their baseline (square, else one row).

use std::fmt::Write as _;

use serde_json::{Map, Value};
use taxel_msgs::{
    sensor_id_str, CurvatureEstimate, Field, ForceSample, Message, RawFrame, Reference,
    SensorIdBytes, Visitor,
};

use super::flat::{self, Flat};
use super::inorder;
use crate::records::{shape_of, Record};

/// Schema names (the message types of docs/messages.md).
pub const RAW_SCHEMA: &str = RawFrame::NAME;
pub const CURVATURE_SCHEMA: &str = CurvatureEstimate::NAME;
pub const FORCE_SCHEMA: &str = ForceSample::NAME;
pub const REFERENCE_SCHEMA: &str = Reference::NAME;

/// Writes a JSON object in table order.
struct Writer {
    out: String,
}

impl Writer {
    fn key(&mut self, f: &Field) {
        self.out.push(if self.out.is_empty() { '{' } else { ',' });
        let _ = write!(self.out, "\"{}\":", f.name);
    }
    fn number<T: serde::Serialize>(&mut self, v: T) {
        match serde_json::to_string(&v) {
            Ok(s) => self.out.push_str(&s),
            Err(_) => self.out.push_str("null"),
        }
    }
    fn float32(&mut self, v: f32) {
        if v.is_finite() {
            self.number(v);
        } else {
            self.out.push_str("null");
        }
    }
}

impl Visitor for Writer {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        self.key(f);
        self.number(sensor_id_str(v));
    }
    fn u64(&mut self, f: &Field, v: &mut u64) {
        self.key(f);
        let _ = write!(self.out, "{v}");
    }
    fn u32(&mut self, f: &Field, v: &mut u32) {
        self.key(f);
        let _ = write!(self.out, "{v}");
    }
    fn u16(&mut self, f: &Field, v: &mut u16) {
        self.key(f);
        let _ = write!(self.out, "{v}");
    }
    fn i32(&mut self, f: &Field, v: &mut i32) {
        self.key(f);
        let _ = write!(self.out, "{v}");
    }
    fn f32(&mut self, f: &Field, v: &mut f32) {
        self.key(f);
        self.float32(*v);
    }
    fn f64(&mut self, f: &Field, v: &mut f64) {
        self.key(f);
        if v.is_finite() {
            self.number(*v);
        } else {
            self.out.push_str("null");
        }
    }
    fn f32s(&mut self, f: &Field, v: &mut [f32], len: &mut usize) {
        self.key(f);
        self.out.push('[');
        for (i, x) in v[..(*len).min(v.len())].iter().enumerate() {
            if i > 0 {
                self.out.push(',');
            }
            self.float32(*x);
        }
        self.out.push(']');
    }
}

/// The JSON message of a record.
pub(super) fn encode(r: &Record) -> Vec<u8> {
    let mut w = Writer { out: String::new() };
    r.clone().visit(&mut w);
    w.out.push('}');
    w.out.into_bytes()
}

/// Collects the JSON Schema properties of a payload.
struct SchemaWriter {
    props: Vec<String>,
    required: Vec<String>,
}

impl SchemaWriter {
    fn prop(&mut self, f: &Field, ty: &str) {
        self.props.push(format!(
            r#""{}":{{{ty},"description":{}}}"#,
            f.name,
            serde_json::to_string(f.doc).unwrap_or_else(|_| "\"\"".into())
        ));
        self.required.push(format!(r#""{}""#, f.name));
    }
}

const INT: &str = r#""type":"integer""#;
const NUM: &str = r#""type":["number","null"]"#;

impl Visitor for SchemaWriter {
    fn sensor(&mut self, f: &Field, _: &mut SensorIdBytes) {
        self.prop(f, r#""type":"string""#);
    }
    fn u64(&mut self, f: &Field, _: &mut u64) {
        self.prop(f, INT);
    }
    fn u32(&mut self, f: &Field, _: &mut u32) {
        self.prop(f, INT);
    }
    fn u16(&mut self, f: &Field, _: &mut u16) {
        self.prop(f, INT);
    }
    fn i32(&mut self, f: &Field, _: &mut i32) {
        self.prop(f, INT);
    }
    fn f32(&mut self, f: &Field, _: &mut f32) {
        self.prop(f, NUM);
    }
    fn f64(&mut self, f: &Field, _: &mut f64) {
        self.prop(f, NUM);
    }
    fn f32s(&mut self, f: &Field, _: &mut [f32], _: &mut usize) {
        self.prop(f, r#""type":"array","items":{"type":["number","null"]}"#);
    }
}

fn schema_of<M: Message>() -> String {
    let mut s = SchemaWriter {
        props: Vec::new(),
        required: Vec::new(),
    };
    M::zero().visit(&mut s);
    format!(
        r#"{{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"{}","type":"object","properties":{{{}}},"required":[{}],"additionalProperties":false}}"#,
        M::NAME,
        s.props.join(","),
        s.required.join(",")
    )
}

/// The JSON Schema of each message type, by schema name.
pub fn json_schema(name: &str) -> Option<String> {
    Some(match name {
        RAW_SCHEMA => schema_of::<RawFrame>(),
        CURVATURE_SCHEMA => schema_of::<CurvatureEstimate>(),
        FORCE_SCHEMA => schema_of::<ForceSample>(),
        REFERENCE_SCHEMA => schema_of::<Reference>(),
        _ => return None,
    })
}

/// The fields a channel's writer declared (its schema's `required` list); `None` when the
/// schema does not say (then every field this build knows is required).
pub(super) fn declared_fields(schema: &[u8]) -> Option<Vec<String>> {
    let v: Value = serde_json::from_slice(schema).ok()?;
    v.get("required")?
        .as_array()?
        .iter()
        .map(|k| k.as_str().map(str::to_string))
        .collect()
}

/// Reads a JSON object into a payload.
struct Reader<'a> {
    obj: &'a Map<String, Value>,
    declared: Option<&'a [String]>,
    err: Option<String>,
}

impl Reader<'_> {
    /// The value of field `f`; `None` when it is absent and the writer did not have it (it
    /// stays zero), or after an error.
    fn get(&mut self, f: &Field) -> Option<&Value> {
        if self.err.is_some() {
            return None;
        }
        match self.obj.get(f.name) {
            Some(v) => Some(v),
            None => {
                let declared = self.declared.is_none_or(|d| d.iter().any(|k| k == f.name));
                if declared {
                    self.err = Some(format!("missing field `{}`", f.name));
                }
                None
            }
        }
    }

    fn fail(&mut self, f: &Field, what: &str) {
        self.err
            .get_or_insert(format!("field `{}`: expected {what}", f.name));
    }

    fn int<T: TryFrom<i128>>(&mut self, f: &Field, v: &mut T) {
        let got = self.get(f).map(|j| {
            j.as_u64()
                .map(i128::from)
                .or_else(|| j.as_i64().map(i128::from))
        });
        match got {
            None => {}
            Some(Some(x)) => match T::try_from(x) {
                Ok(x) => *v = x,
                Err(_) => self.fail(f, &format!("an integer in range, got {x}")),
            },
            Some(None) => self.fail(f, "an integer"),
        }
    }

    fn float(&mut self, f: &Field) -> Option<f64> {
        let j = self.get(f)?;
        if j.is_null() {
            return Some(f64::NAN);
        }
        let x = j.as_f64();
        if x.is_none() {
            self.fail(f, "a number or null");
        }
        x
    }
}

impl Visitor for Reader<'_> {
    fn sensor(&mut self, f: &Field, v: &mut SensorIdBytes) {
        let got = self.get(f).map(|j| j.as_str().map(str::to_string));
        match got {
            None => {}
            Some(Some(s)) if s.len() < v.len() => v[..s.len()].copy_from_slice(s.as_bytes()),
            Some(_) => self.fail(f, &format!("a string of at most {} bytes", v.len() - 1)),
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
        let got = self.get(f).map(|j| j.as_array().cloned());
        let items = match got {
            None => return,
            Some(Some(a)) if a.len() <= v.len() => a,
            Some(Some(a)) => {
                return self.fail(f, &format!("at most {} entries, got {}", v.len(), a.len()))
            }
            Some(None) => return self.fail(f, "an array"),
        };
        for (x, j) in v.iter_mut().zip(&items) {
            *x = match (j.is_null(), j.as_f64()) {
                (true, _) => f32::NAN,
                (false, Some(y)) => y as f32,
                (false, None) => return self.fail(f, "numbers or null"),
            };
        }
        *len = items.len();
    }
    fn invalid(&mut self, why: String) {
        self.err.get_or_insert(why);
    }
}

fn read<M: Message>(obj: &Map<String, Value>, declared: Option<&[String]>) -> Result<M, String> {
    let mut m = M::zero();
    let mut r = Reader {
        obj,
        declared,
        err: None,
    };
    m.visit(&mut r);
    r.err.map_or(Ok(m), Err)
}

/// Decodes a message of schema `schema` whose channel declared the fields `declared`, as
/// the readers do ([`Slots::decode`]).
#[cfg(test)]
pub(super) fn decode(
    schema: &str,
    declared: Option<&[String]>,
    data: &[u8],
) -> Result<Record, String> {
    Slots::default().decode(schema, declared, data).cloned()
}

/// One payload per message type, reused from message to message: decoding a message fills
/// the payload of its type in place (no allocation on the fast path).
pub(super) struct Slots {
    raw: Record,
    curvature: Record,
    force: Record,
    reference: Record,
}

impl Default for Slots {
    fn default() -> Slots {
        Slots {
            raw: RawFrame::ZERO.into(),
            curvature: CurvatureEstimate::ZERO.into(),
            force: ForceSample::ZERO.into(),
            reference: Reference::ZERO.into(),
        }
    }
}

impl Slots {
    /// Decodes a message of schema `schema` whose channel declared the fields `declared` into
    /// the payload of its type, and returns it (the fast path, else the general path, which
    /// names the error).
    pub(super) fn decode(
        &mut self,
        schema: &str,
        declared: Option<&[String]>,
        data: &[u8],
    ) -> Result<&mut Record, String> {
        let slot = match schema {
            RAW_SCHEMA => &mut self.raw,
            CURVATURE_SCHEMA => &mut self.curvature,
            FORCE_SCHEMA => &mut self.force,
            REFERENCE_SCHEMA => &mut self.reference,
            other => {
                return Err(match decode_general(other, declared, data) {
                    Err(e) => e,
                    Ok(_) => format!("unknown schema {other:?}"),
                })
            }
        };
        // The caller may have changed the payload it was handed.
        if slot.name() != schema {
            *slot = zero(schema).ok_or_else(|| format!("unknown schema {schema:?}"))?;
        }
        if !fill_flat(declared, data, slot) {
            *slot = decode_general(schema, declared, data)?;
        }
        Ok(slot)
    }
}

/// [`decode`] with serde_json: reads what the fast path leaves, and names every error.
pub(super) fn decode_general(
    schema: &str,
    declared: Option<&[String]>,
    data: &[u8],
) -> Result<Record, String> {
    let mut obj: Map<String, Value> = serde_json::from_slice(data).map_err(|e| e.to_string())?;
    Ok(match schema {
        RAW_SCHEMA => read::<RawFrame>(&obj, declared)?.into(),
        CURVATURE_SCHEMA => {
            // Written before estimates carried their shape: take it from the baseline.
            if !obj.contains_key("rows") && !obj.contains_key("cols") {
                let n = obj
                    .get("baseline")
                    .and_then(Value::as_array)
                    .map_or(0, Vec::len);
                let (rows, cols) = shape_of(n);
                obj.insert("rows".into(), rows.into());
                obj.insert("cols".into(), cols.into());
            }
            read::<CurvatureEstimate>(&obj, declared)?.into()
        }
        FORCE_SCHEMA => read::<ForceSample>(&obj, declared)?.into(),
        REFERENCE_SCHEMA => read::<Reference>(&obj, declared)?.into(),
        other => return Err(format!("unknown schema {other:?}")),
    })
}

/// An all-zero payload of schema `schema`.
fn zero(schema: &str) -> Option<Record> {
    Some(match schema {
        RAW_SCHEMA => RawFrame::ZERO.into(),
        CURVATURE_SCHEMA => CurvatureEstimate::ZERO.into(),
        FORCE_SCHEMA => ForceSample::ZERO.into(),
        REFERENCE_SCHEMA => Reference::ZERO.into(),
        _ => return None,
    })
}

/// [`decode`] on the fast path ([`flat`]); `None` when the general path must decide.
#[cfg(test)]
pub(super) fn decode_flat(
    schema: &str,
    declared: Option<&[String]>,
    data: &[u8],
) -> Option<Record> {
    let mut r = zero(schema)?;
    fill_flat(declared, data, &mut r).then_some(r)
}

/// [`decode`] on the fastest path alone ([`inorder`]); `None` when another path must decide.
#[cfg(test)]
pub(super) fn decode_in_order(schema: &str, data: &[u8]) -> Option<Record> {
    let mut r = zero(schema)?;
    let ok = match &mut r {
        Record::Raw(m) => inorder::fill(data, &mut **m),
        Record::Curvature(m) => inorder::fill(data, &mut **m),
        Record::Force(m) => inorder::fill(data, m),
        Record::Reference(m) => inorder::fill(data, m),
    };
    ok.then_some(r)
}

/// Fills `slot` (overwriting it) from a message on the fast paths: the writer's exact layout
/// ([`inorder`]), else any flat object ([`flat`]); false when the general path must decide
/// (then `slot` holds anything).
fn fill_flat(declared: Option<&[String]>, data: &[u8], slot: &mut Record) -> bool {
    /// Tries the paths in turn, each from a zero payload. Estimates written before they
    /// carried their shape (`shaped`: neither `rows` nor `cols`) take the general path.
    fn fill<M: Message>(declared: Option<&[String]>, data: &[u8], m: &mut M, shaped: bool) -> bool {
        *m = M::zero();
        if inorder::fill(data, m) {
            return true;
        }
        let Some(obj) = Flat::scan(data) else {
            return false;
        };
        if shaped && !obj.has("rows") && !obj.has("cols") {
            return false;
        }
        *m = M::zero();
        flat::fill(&obj, declared, m)
    }
    match slot {
        Record::Raw(m) => fill(declared, data, &mut **m, false),
        Record::Curvature(m) => fill(declared, data, &mut **m, true),
        Record::Force(m) => fill(declared, data, m, false),
        Record::Reference(m) => fill(declared, data, m, false),
    }
}
