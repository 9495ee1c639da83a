//! The one bincode (2.x, serde) encode/decode pair for whole-file blobs such as model files:
//! an 8-byte magic, a little-endian u16 format version, then the bincode body. Decoding rejects
//! another magic, another version and trailing bytes.

use serde::{de::DeserializeOwned, Serialize};

/// Why a blob was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum EnvelopeError {
    #[error("too short to be a {kind} file ({len} bytes)")]
    TooShort { kind: &'static str, len: usize },
    #[error("not a {kind} file (bad magic bytes at offset 0)")]
    BadMagic { kind: &'static str },
    #[error(
        "{kind} file format version {found} is not supported (this build reads version {expected})"
    )]
    Version {
        kind: &'static str,
        found: u16,
        expected: u16,
    },
    #[error("corrupt {kind} file: {reason} (body starts at byte 10)")]
    Corrupt { kind: &'static str, reason: String },
    #[error("corrupt {kind} file: {extra} trailing bytes after the body at byte {at}")]
    Trailing {
        kind: &'static str,
        extra: usize,
        at: usize,
    },
    #[error("cannot encode {kind}: {reason}")]
    Encode { kind: &'static str, reason: String },
}

const HEADER: usize = 10;

/// Encodes `value` behind the header.
pub fn encode<T: Serialize>(
    kind: &'static str,
    magic: &[u8; 8],
    version: u16,
    value: &T,
) -> Result<Vec<u8>, EnvelopeError> {
    let mut out = Vec::with_capacity(256);
    out.extend_from_slice(magic);
    out.extend_from_slice(&version.to_le_bytes());
    bincode::serde::encode_into_std_write(value, &mut out, bincode::config::standard()).map_err(
        |e| EnvelopeError::Encode {
            kind,
            reason: e.to_string(),
        },
    )?;
    Ok(out)
}

/// Decodes a blob written by [`encode`] with the same magic and version.
pub fn decode<T: DeserializeOwned>(
    kind: &'static str,
    magic: &[u8; 8],
    version: u16,
    bytes: &[u8],
) -> Result<T, EnvelopeError> {
    if bytes.len() < HEADER {
        return Err(EnvelopeError::TooShort {
            kind,
            len: bytes.len(),
        });
    }
    if &bytes[..8] != magic {
        return Err(EnvelopeError::BadMagic { kind });
    }
    let found = u16::from_le_bytes([bytes[8], bytes[9]]);
    if found != version {
        return Err(EnvelopeError::Version {
            kind,
            found,
            expected: version,
        });
    }
    let cfg = bincode::config::standard().with_limit::<{ 256 * 1024 * 1024 }>();
    let (value, used) =
        bincode::serde::decode_from_slice::<T, _>(&bytes[HEADER..], cfg).map_err(|e| {
            EnvelopeError::Corrupt {
                kind,
                reason: e.to_string(),
            }
        })?;
    let end = HEADER + used;
    if end != bytes.len() {
        return Err(EnvelopeError::Trailing {
            kind,
            extra: bytes.len() - end,
            at: end,
        });
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAGIC: &[u8; 8] = b"TAXTEST\0";

    #[test]
    fn round_trip_and_every_refusal() {
        let v = (3u32, vec![1.5f64, -2.0], "x".to_string());
        let bytes = encode("test", MAGIC, 2, &v).expect("encodes");
        let back: (u32, Vec<f64>, String) = decode("test", MAGIC, 2, &bytes).expect("decodes");
        assert_eq!(back, v);

        let mut trailing = bytes.clone();
        trailing.push(0);
        assert!(matches!(
            decode::<(u32, Vec<f64>, String)>("test", MAGIC, 2, &trailing),
            Err(EnvelopeError::Trailing { extra: 1, .. })
        ));
        assert!(matches!(
            decode::<(u32, Vec<f64>, String)>("test", MAGIC, 3, &bytes),
            Err(EnvelopeError::Version { found: 2, .. })
        ));
        assert!(matches!(
            decode::<(u32, Vec<f64>, String)>("test", b"OTHER\0\0\0", 2, &bytes),
            Err(EnvelopeError::BadMagic { .. })
        ));
        for cut in 0..bytes.len() {
            assert!(decode::<(u32, Vec<f64>, String)>("test", MAGIC, 2, &bytes[..cut]).is_err());
        }
    }
}
