//! Reading the messages of an MCAP file in file order, each decoded as it is read: by the
//! walker ([`super::walk`]), which reads taxel's files (and any file whose chunks are
//! uncompressed, `zstd` or `lz4`) without a copy per message, else from where the walker
//! stopped by the `mcap` crate's `MessageStream` (a chunk of another compression: this build
//! of the crate has no decompressor, so that is an error naming the compression). Both give the same messages and decode them
//! the same way. (Decoding on two threads was tried and was slower: the `mcap` crate copies
//! every record into new allocations, and freeing them on another thread contends on the
//! allocator; see docs/python.md.)

use std::collections::HashMap;
use std::path::Path;

use super::json::{declared_fields, Slots};
use super::walk::{walk, walk_from, Walked};
use super::{McapError, McapView};

/// Decodes every message of the file at `path` in file order and hands it to `f`; the first
/// error ends the read.
pub(super) fn for_each_message(
    path: &Path,
    mut f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<(), McapError> {
    match walk(path, &mut f)? {
        Walked::Done => Ok(()),
        Walked::Unusual { delivered } => {
            let bytes = std::fs::read(path).map_err(|error| McapError::Io {
                path: path.to_path_buf(),
                error,
            })?;
            stream(path, &bytes, delivered, f)
        }
    }
}

/// [`for_each_message`] on bytes read from `path`.
pub(super) fn for_each_in(
    path: &Path,
    bytes: &[u8],
    mut f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<(), McapError> {
    match walk_from(path, bytes, bytes.len() as u64, &mut f)? {
        Walked::Done => Ok(()),
        Walked::Unusual { delivered } => stream(path, bytes, delivered, f),
    }
}

/// Decodes the messages of `bytes` (read from `path`) with the `mcap` crate, from message
/// `skip` on, and hands them to `f`.
pub(super) fn stream(
    path: &Path,
    bytes: &[u8],
    skip: usize,
    mut f: impl FnMut(McapView<'_>) -> Result<(), McapError>,
) -> Result<(), McapError> {
    let stream = ::mcap::MessageStream::new(bytes).map_err(|error| McapError::Mcap {
        path: path.to_path_buf(),
        error,
    })?;
    // The fields each channel's writer declared in its schema.
    let mut declared = HashMap::new();
    let mut slots = Slots::default();
    for (index, item) in stream.enumerate() {
        let m = item.map_err(|error| McapError::Stream {
            path: path.to_path_buf(),
            index,
            error,
        })?;
        if index < skip {
            continue;
        }
        let schema = m.channel.schema.as_ref();
        let fields = declared
            .entry(m.channel.id)
            .or_insert_with(|| schema.and_then(|s| declared_fields(&s.data)));
        let record = match (m.channel.message_encoding.as_str(), schema) {
            ("json", Some(schema)) => slots.decode(&schema.name, fields.as_deref(), &m.data),
            (enc, _) => Err(format!("message encoding {enc:?} with no taxel schema")),
        }
        .map_err(|reason| McapError::Message {
            path: path.to_path_buf(),
            index,
            topic: m.channel.topic.clone(),
            reason,
        })?;
        f(McapView {
            topic: &m.channel.topic,
            log_time: m.log_time,
            publish_time: m.publish_time,
            sequence: m.sequence,
            record,
        })?;
    }
    Ok(())
}
