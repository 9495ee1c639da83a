//! Compressed MCAP chunks: `zstd` and `lz4` (the LZ4 frame format), the two compressions MCAP
//! writers use (Foxglove's `mcap` CLI and libraries, rosbag2), decoded by pure-Rust decoders
//! (`ruzstd`, `lz4_flex`), so nothing but the Rust toolchain is needed to build them.

use std::io::Read;

/// Whether chunks compressed this way can be read.
pub(super) fn supported(compression: &str) -> bool {
    matches!(compression, "" | "zstd" | "lz4")
}

/// Decompresses a chunk's records into `out` (cleared first): at most `size` bytes, the
/// chunk header's uncompressed size, which they must be exactly, with the header's CRC-32
/// (when it is not 0). The error says what is wrong.
pub(super) fn unpack(
    compression: &str,
    data: &[u8],
    size: u64,
    crc: u32,
    out: &mut Vec<u8>,
) -> Result<(), ::mcap::McapError> {
    out.clear();
    // The header's size bounds the output (a damaged or hostile header cannot make it
    // allocate more than the stream decodes to), and the reservation is capped.
    out.reserve(size.min(1 << 28) as usize);
    let bad =
        |e: std::io::Error| ::mcap::McapError::DecompressionError(format!("{compression}: {e}"));
    match compression {
        "zstd" => ruzstd::decoding::StreamingDecoder::new(data)
            .map_err(|e| ::mcap::McapError::DecompressionError(format!("zstd: {e}")))?
            .take(size.saturating_add(1))
            .read_to_end(out)
            .map_err(bad)?,
        "lz4" => lz4_flex::frame::FrameDecoder::new(data)
            .take(size.saturating_add(1))
            .read_to_end(out)
            .map_err(bad)?,
        other => return Err(::mcap::McapError::UnsupportedCompression(other.to_string())),
    };
    if out.len() as u64 != size {
        return Err(::mcap::McapError::DecompressionError(format!(
            "{compression}: the chunk holds {}{} bytes, its header says {size}",
            if out.len() as u64 > size {
                "more than "
            } else {
                ""
            },
            out.len().min(size as usize)
        )));
    }
    let calculated = crc32fast::hash(out);
    if crc != 0 && calculated != crc {
        return Err(::mcap::McapError::BadChunkCrc {
            saved: crc,
            calculated,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::io::Write;
    use std::path::Path;

    use ::mcap::records::op;

    use super::super::read_messages;
    use super::super::walk::tests::{records, write};

    fn compress(compression: &str, data: &[u8]) -> Vec<u8> {
        match compression {
            "zstd" => {
                ruzstd::encoding::compress_to_vec(data, ruzstd::encoding::CompressionLevel::Fastest)
            }
            "lz4" => {
                let mut e = lz4_flex::frame::FrameEncoder::new(Vec::new());
                e.write_all(data).expect("lz4");
                e.finish().expect("lz4")
            }
            // Any other name: the records as they are (for the unknown-compression case).
            _ => data.to_vec(),
        }
    }

    fn u64_at(b: &[u8], i: usize) -> u64 {
        u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"))
    }

    /// The file at `from` (no summary, no indexes) with every chunk's records compressed;
    /// `size_delta` is added to each chunk header's uncompressed size.
    fn recompress(from: &Path, compression: &str, size_delta: i64) -> Vec<u8> {
        let b = std::fs::read(from).expect("read");
        let mut out = b[..8].to_vec();
        let mut i = 8;
        while i < b.len() - 8 {
            let (opcode, len) = (b[i], u64_at(&b, i + 1) as usize);
            let body = &b[i + 9..i + 9 + len];
            if opcode == op::CHUNK {
                // start, end, uncompressed size, crc, compression, records.
                let clen = u32::from_le_bytes(body[28..32].try_into().expect("4")) as usize;
                assert_eq!(clen, 0, "written uncompressed");
                let recs = &body[32 + 8..];
                let packed = compress(compression, recs);
                let mut nb = body[..16].to_vec();
                nb.extend((recs.len() as i64 + size_delta).to_le_bytes());
                nb.extend(crc32fast::hash(recs).to_le_bytes());
                nb.extend((compression.len() as u32).to_le_bytes());
                nb.extend(compression.as_bytes());
                nb.extend((packed.len() as u64).to_le_bytes());
                nb.extend(&packed);
                out.push(opcode);
                out.extend((nb.len() as u64).to_le_bytes());
                out.extend(nb);
            } else {
                out.extend(&b[i..i + 9 + len]);
            }
            i += 9 + len;
        }
        out.extend(&b[i..]);
        out
    }

    fn debug(path: &Path) -> Result<Vec<String>, String> {
        read_messages(path)
            .map(|m| m.iter().map(|m| format!("{:?}", m.record)).collect())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn zstd_and_lz4_chunks_read_as_the_uncompressed_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let plain = dir.path().join("plain.mcap");
        let options = ::mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(4000))
            .emit_summary_records(false)
            .emit_summary_offsets(false)
            .emit_message_indexes(false)
            .emit_chunk_indexes(false)
            .calculate_data_section_crc(false);
        write(&plain, Some(options), &records(300));
        let want = debug(&plain).expect("plain");
        assert_eq!(want.len(), 300 * 3 + 30);
        let packed = dir.path().join("packed.mcap");
        for compression in ["zstd", "lz4"] {
            let bytes = recompress(&plain, compression, 0);
            let plain_len = std::fs::metadata(&plain).expect("len").len() as usize;
            assert!(
                bytes.len() < plain_len / 2,
                "{compression}: {}",
                bytes.len()
            );
            std::fs::write(&packed, &bytes).expect("write");
            assert!(debug(&packed).expect(compression) == want, "{compression}");

            // A chunk header whose size is wrong, and damage in a compressed stream.
            std::fs::write(&packed, recompress(&plain, compression, -1)).expect("write");
            let e = debug(&packed).expect_err("short");
            assert!(
                e.contains("chunk record at byte") && e.contains("header says"),
                "{e}"
            );
            let mut flipped = bytes.clone();
            let at = bytes.len() / 2;
            flipped[at] ^= 0x5a;
            std::fs::write(&packed, &flipped).expect("write");
            let e = debug(&packed).expect_err("flipped");
            assert!(e.contains("packed.mcap"), "{e}");
        }
        std::fs::write(&packed, recompress(&plain, "brotli", 0)).expect("write");
        let e = debug(&packed).expect_err("brotli");
        assert!(e.contains("brotli"), "{e}");
    }
}
