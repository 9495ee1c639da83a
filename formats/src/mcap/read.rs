//! Reading the messages of an MCAP file in file order. One thread walks the file's records, two
//! decode the JSON messages in batches, and the caller's thread receives them in order, so a
//! long recording is read with both cores. Errors are the same, at the same message, as when
//! reading on one thread: the first one in file order ends the read.

use std::collections::HashMap;
use std::path::Path;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};

use super::json::{declared_fields, decode};
use super::{McapError, McapMessage};

/// Messages per batch handed to a decoder.
const BATCH: usize = 1024;
/// Decoding threads.
const DECODERS: usize = 2;
/// Batches in flight per decoder, each way.
const DEPTH: usize = 2;
/// Smaller files are read on the caller's thread (threads would cost more than they save).
const THREADED_FROM_BYTES: usize = 4 << 20;

/// What the walk of the file found: a message, or the error that ended the walk.
type Item<'a> = Result<::mcap::Message<'a>, ::mcap::McapError>;
/// A batch: the index of its first message, and its items.
type Batch<'a> = (usize, Vec<Item<'a>>);

/// Decodes every message of `bytes` (read from `path`) in file order and hands it to `f`.
pub(super) fn for_each_message(
    path: &Path,
    bytes: &[u8],
    f: impl FnMut(McapMessage) -> Result<(), McapError>,
) -> Result<(), McapError> {
    let threaded = bytes.len() >= THREADED_FROM_BYTES
        && std::thread::available_parallelism().is_ok_and(|n| n.get() > 1);
    for_each_message_on(path, bytes, threaded, f)
}

/// [`for_each_message`], on the caller's thread or not.
pub(super) fn for_each_message_on(
    path: &Path,
    bytes: &[u8],
    threaded: bool,
    mut f: impl FnMut(McapMessage) -> Result<(), McapError>,
) -> Result<(), McapError> {
    let stream = ::mcap::MessageStream::new(bytes).map_err(|error| McapError::Mcap {
        path: path.to_path_buf(),
        error,
    })?;
    if !threaded {
        let mut declared = HashMap::new();
        for (index, item) in stream.enumerate() {
            f(message(path, index, item, &mut declared)?)?;
        }
        return Ok(());
    }
    std::thread::scope(|s| {
        let mut inputs = Vec::with_capacity(DECODERS);
        let mut outputs = Vec::with_capacity(DECODERS);
        for _ in 0..DECODERS {
            let (to_decoder, from_walk) = sync_channel::<Batch<'_>>(DEPTH);
            let (to_caller, from_decoder) = sync_channel(DEPTH);
            s.spawn(move || decoder(path, from_walk, to_caller));
            inputs.push(to_decoder);
            outputs.push(from_decoder);
        }
        s.spawn(move || walk(stream, inputs));
        // Batches go to the decoders in turn, so they come back in file order the same way.
        // A decoder that hangs up has had its last batch; a caller that stops hangs up on all.
        for k in 0.. {
            let Ok(batch): Result<Vec<Result<McapMessage, McapError>>, _> =
                outputs[k % DECODERS].recv()
            else {
                return Ok(());
            };
            for m in batch {
                f(m?)?;
            }
        }
        Ok(())
    })
}

/// Walks the file's records and hands the messages to the decoders in turn, in batches; stops
/// after the first error, or when a decoder hangs up.
fn walk<'a>(stream: ::mcap::MessageStream<'a>, decoders: Vec<SyncSender<Batch<'a>>>) {
    let (mut first, mut sent) = (0, 0);
    let mut batch = Vec::with_capacity(BATCH);
    for (k, item) in stream.enumerate() {
        let failed = item.is_err();
        batch.push(item);
        if batch.len() == BATCH || failed {
            let full = std::mem::replace(&mut batch, Vec::with_capacity(BATCH));
            if decoders[sent % DECODERS].send((first, full)).is_err() || failed {
                return;
            }
            (first, sent) = (k + 1, sent + 1);
        }
    }
    if !batch.is_empty() {
        let _ = decoders[sent % DECODERS].send((first, batch));
    }
}

/// Decodes batches until the walk hangs up (or the caller does).
fn decoder(
    path: &Path,
    batches: Receiver<Batch<'_>>,
    out: SyncSender<Vec<Result<McapMessage, McapError>>>,
) {
    // The fields each channel's writer declared in its schema.
    let mut declared: HashMap<u16, Option<Vec<String>>> = HashMap::new();
    while let Ok((first, items)) = batches.recv() {
        let decoded = items
            .into_iter()
            .enumerate()
            .map(|(k, item)| message(path, first + k, item, &mut declared))
            .collect();
        if out.send(decoded).is_err() {
            return;
        }
    }
}

/// One message, decoded.
fn message(
    path: &Path,
    index: usize,
    item: Item<'_>,
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
