//! Reading the messages of an MCAP file in file order, each decoded as it is read. (Decoding
//! on two threads was tried and was slower: the `mcap` crate copies every record into new
//! allocations, and freeing them on another thread contends on the allocator; see
//! docs/python.md.)

use std::collections::HashMap;
use std::path::Path;

use super::json::{declared_fields, decode};
use super::{McapError, McapMessage};

/// Decodes every message of `bytes` (read from `path`) in file order and hands it to `f`;
/// the first error ends the read.
pub(super) fn for_each_message(
    path: &Path,
    bytes: &[u8],
    mut f: impl FnMut(McapMessage) -> Result<(), McapError>,
) -> Result<(), McapError> {
    let stream = ::mcap::MessageStream::new(bytes).map_err(|error| McapError::Mcap {
        path: path.to_path_buf(),
        error,
    })?;
    // The fields each channel's writer declared in its schema.
    let mut declared = HashMap::new();
    for (index, item) in stream.enumerate() {
        f(message(path, index, item, &mut declared)?)?;
    }
    Ok(())
}

/// One message, decoded.
fn message(
    path: &Path,
    index: usize,
    item: Result<::mcap::Message<'_>, ::mcap::McapError>,
    declared: &mut HashMap<u16, Option<Vec<String>>>,
) -> Result<McapMessage, McapError> {
    let m = item.map_err(|error| McapError::Stream {
        path: path.to_path_buf(),
        index,
        error,
    })?;
    let schema = m.channel.schema.as_ref();
    let fields = declared
        .entry(m.channel.id)
        .or_insert_with(|| schema.and_then(|s| declared_fields(&s.data)));
    let record = match (m.channel.message_encoding.as_str(), schema) {
        ("json", Some(schema)) => decode(&schema.name, fields.as_deref(), &m.data),
        (enc, _) => Err(format!("message encoding {enc:?} with no taxel schema")),
    }
    .map_err(|reason| McapError::Message {
        path: path.to_path_buf(),
        index,
        topic: m.channel.topic.clone(),
        reason,
    })?;
    Ok(McapMessage {
        topic: m.channel.topic.clone(),
        log_time: m.log_time,
        publish_time: m.publish_time,
        sequence: m.sequence,
        record,
    })
}
