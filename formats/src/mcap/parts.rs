//! Reading an MCAP file on several threads. The file's summary section (written by taxel's
//! writer and by most others) lists every chunk's offset and repeats the schema and channel
//! records; the file is cut at chunk starts into contiguous parts, each walked by its own
//! walker ([`super::walk::walk_part`]) into its own consumer, so the consumers' outputs, taken
//! in order, hold the messages in file order.
//!
//! Anything unusual (no summary, compressed chunks, a summary whose offsets are not record
//! boundaries, any error in any part) sends the whole file through the one-thread reader
//! instead, with fresh consumers: the result, and every error, is then exactly that reader's.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use ::mcap::records::{op, Record as McapRecord};

use super::read::for_each_message;
use super::walk::walk_part;
use super::{McapError, McapView};

/// Bytes of the footer record (opcode, length, two offsets and a CRC) before the end magic.
const FOOTER: u64 = 1 + 8 + 8 + 8 + 4;

/// What the summary section tells: the chunks' offsets and the schema and channel records.
struct Summary {
    chunk_starts: Vec<u64>,
    /// (opcode, body, file offset) of each schema and channel record.
    defs: Vec<(u8, Vec<u8>, u64)>,
}

/// The summary section of the file, or `None` when it has none that can be read.
fn summary(file: &mut File, size: u64) -> Option<Summary> {
    let tail_at = size.checked_sub(FOOTER + 8)?;
    let mut tail = [0u8; (FOOTER + 8) as usize];
    file.seek(SeekFrom::Start(tail_at)).ok()?;
    file.read_exact(&mut tail).ok()?;
    let u64_at = |i: usize| u64::from_le_bytes(tail[i..i + 8].try_into().unwrap_or([0; 8]));
    if tail[0] != op::FOOTER || u64_at(1) != FOOTER - 9 || tail[FOOTER as usize..] != *::mcap::MAGIC
    {
        return None;
    }
    let (start, offsets, crc) = (
        u64_at(9),
        u64_at(17),
        u32::from_le_bytes([tail[25], tail[26], tail[27], tail[28]]),
    );
    if start == 0 || start >= tail_at || crc == 0 {
        return None;
    }
    // Everything from the summary on, up to the footer's checksum, which covers it (so a
    // damaged summary never places a cut or names a channel).
    let mut bytes = vec![0u8; usize::try_from(tail_at - start).ok()?];
    file.seek(SeekFrom::Start(start)).ok()?;
    file.read_exact(&mut bytes).ok()?;
    let mut hasher = crc32fast::Hasher::new();
    hasher.update(&bytes);
    hasher.update(&tail[..25]);
    if hasher.finalize() != crc {
        return None;
    }
    let end = if offsets != 0 { offsets } else { tail_at };
    let bytes = bytes.get(..usize::try_from(end.checked_sub(start)?).ok()?)?;
    let mut out = Summary {
        chunk_starts: Vec::new(),
        defs: Vec::new(),
    };
    let mut i = 0usize;
    while i < bytes.len() {
        let head = bytes.get(i..i + 9)?;
        let len = usize::try_from(u64::from_le_bytes(head[1..9].try_into().ok()?)).ok()?;
        let body = bytes.get(i + 9..(i + 9).checked_add(len)?)?;
        match head[0] {
            op::SCHEMA | op::CHANNEL => out.defs.push((head[0], body.to_vec(), start + i as u64)),
            op::CHUNK_INDEX => match ::mcap::parse_record(op::CHUNK_INDEX, body).ok()? {
                McapRecord::ChunkIndex(c) if c.compression.is_empty() => {
                    out.chunk_starts.push(c.chunk_start_offset)
                }
                // Compressed chunks are read on one thread.
                _ => return None,
            },
            _ => {}
        }
        i += 9 + len;
    }
    out.chunk_starts.sort_unstable();
    Some(out)
}

/// Where parts after the first start: for each of `parts - 1` even cuts of the file, the first
/// chunk start at or after it (each later than the one before).
fn cuts(chunk_starts: &[u64], size: u64, parts: usize) -> Vec<u64> {
    let mut out: Vec<u64> = Vec::new();
    for k in 1..parts as u64 {
        let even = size / parts as u64 * k;
        let after = out.last().copied().unwrap_or(0);
        if let Some(&c) = chunk_starts.iter().find(|&&c| c >= even && c > after) {
            out.push(c);
        }
    }
    out
}

/// Hands every message of the file at `path` to `f` with the consumer of its part, reading the
/// file on up to `parts` threads; returns the consumers in file order (one when the file is
/// read on one thread). `make` makes a fresh consumer. When a part fails, the file is read
/// again on one thread into a fresh consumer: `f` should touch nothing but its consumer, as
/// the parts' consumers (and what `f` gave them) are then dropped.
pub fn for_each_view_parts<C: Send>(
    path: &Path,
    parts: usize,
    make: impl Fn() -> C + Sync,
    f: impl Fn(&mut C, McapView<'_>) + Sync,
) -> Result<Vec<C>, McapError> {
    if let Some(out) = split(path, parts, &make, &f) {
        return Ok(out);
    }
    let mut c = make();
    for_each_message(path, |m| {
        f(&mut c, m);
        Ok(())
    })?;
    Ok(vec![c])
}

/// The file read in parts on threads; `None` when it cannot be, or anything went wrong.
fn split<C: Send>(
    path: &Path,
    parts: usize,
    make: &(impl Fn() -> C + Sync),
    f: &(impl Fn(&mut C, McapView<'_>) + Sync),
) -> Option<Vec<C>> {
    if parts < 2 {
        return None;
    }
    let mut file = File::open(path).ok()?;
    let size = file.metadata().ok()?.len();
    let summary = summary(&mut file, size)?;
    let cuts = cuts(&summary.chunk_starts, size, parts);
    if cuts.is_empty() {
        return None;
    }
    let defs: Vec<(u8, &[u8], u64)> = summary
        .defs
        .iter()
        .map(|(o, b, at)| (*o, b.as_slice(), *at))
        .collect();
    let starts = std::iter::once(0).chain(cuts.iter().copied());
    let ends = cuts.iter().copied().map(Some).chain(std::iter::once(None));
    let spans: Vec<(u64, Option<u64>)> = starts.zip(ends).collect();
    let defs = &defs;
    let results: Vec<Option<C>> = std::thread::scope(|s| {
        let handles: Vec<_> = spans
            .iter()
            .map(|&span| {
                s.spawn(move || {
                    let mut c = make();
                    let walked = walk_part(path, size, span, defs, |m| {
                        f(&mut c, m);
                        Ok(())
                    });
                    matches!(walked, Ok(true)).then_some(c)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().ok().flatten())
            .collect()
    });
    results.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::super::walk::tests::{records, write};
    use super::super::{for_each_view, read_messages};
    use super::*;
    use crate::records::Record;

    /// The records of each part, in order.
    fn parts(path: &Path, n: usize) -> Result<Vec<Vec<Record>>, McapError> {
        for_each_view_parts(path, n, Vec::new, |c: &mut Vec<Record>, m| {
            c.push(m.record.clone())
        })
    }

    fn plain() -> ::mcap::WriteOptions {
        ::mcap::WriteOptions::new()
            .compression(None)
            .library("another writer")
    }

    #[test]
    fn parts_in_order_are_the_file() {
        let recs = records(900);
        let dir = tempfile::tempdir().expect("tempdir");
        let variants = [
            ("taxel", None, 1),
            ("small chunks", Some(plain().chunk_size(Some(3000))), 4),
            ("a chunk per message", Some(plain().chunk_size(Some(1))), 4),
            ("one chunk", Some(plain().chunk_size(None)), 1),
            ("no chunks", Some(plain().use_chunks(false)), 1),
            (
                "no summary",
                Some(
                    plain()
                        .chunk_size(Some(3000))
                        .emit_summary_records(false)
                        .emit_summary_offsets(false),
                ),
                1,
            ),
        ];
        for (name, options, want_parts) in variants {
            let p = dir.path().join(format!("{name}.mcap"));
            write(&p, options, &recs);
            // Debug text: NaN entries compare unequal as floats.
            let whole: Vec<String> = read_messages(&p)
                .expect(name)
                .iter()
                .map(|m| format!("{:?}", m.record))
                .collect();
            for n in [1, 2, 4] {
                let got = parts(&p, n).expect(name);
                assert_eq!(
                    got.len(),
                    if n == 1 { 1 } else { want_parts.min(n) },
                    "{name}, {n}"
                );
                assert!(
                    got.iter().all(|c| !c.is_empty()),
                    "{name}, {n}: an empty part"
                );
                let got: Vec<String> = got.concat().iter().map(|r| format!("{r:?}")).collect();
                assert!(got == whole, "{name}, {n} parts: not the file's messages");
            }
        }
    }

    #[test]
    fn damage_anywhere_gives_the_one_thread_readers_error() {
        let recs = records(400);
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("d.mcap");
        write(&p, Some(plain().chunk_size(Some(2000))), &recs);
        let bytes = std::fs::read(&p).expect("read");
        let flipped = dir.path().join("f.mcap");
        // Past the middle (the second part), and in the summary the cuts come from.
        for at in [bytes.len() * 3 / 4, bytes.len() - 200] {
            let mut b = bytes.clone();
            b[at] ^= 0x5a;
            std::fs::write(&flipped, &b).expect("write");
            let one = for_each_view(&flipped, |_| {}).err().map(|e| e.to_string());
            let two = parts(&flipped, 2).err().map(|e| e.to_string());
            eprintln!("flip at {at}: {one:?}");
            assert_eq!(two, one, "flip at {at}");
        }
    }
}
