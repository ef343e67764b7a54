//! The three ways OpenVDB stores a block of values (`io::readData`): plain bytes, a zlib chunk
//! (`COMPRESS_ZIP`), or a Blosc chunk (`COMPRESS_BLOSC`). A compressed chunk is an i64 byte count
//! then the bytes; a count ≤ 0 means |count| plain bytes follow (OpenVDB stores small or
//! incompressible blocks that way).
//!
//! Blosc is decoded here rather than through the C library (the `blosc-src` crate that `vdb-rs` binds
//! needs a C toolchain and trusts its input): OpenVDB writes Blosc 1 frames with LZ4 inside and byte
//! shuffling, and the format is small. We decode the Blosc 1 container (header, block starts,
//! split streams, memcpy frames, byte unshuffle), with LZ4 (`lz4_flex`) or zlib (`flate2`) inside;
//! other inner codecs (BloscLZ, Snappy, Zstd) and bit shuffling are reported as unsupported.

use super::error::{VdbError, R};
use super::stream::Stream;
use std::io::{Read, Seek};

/// Per-grid compression flags (`io::COMPRESS_*`).
pub const COMPRESS_ZIP: u32 = 0x1;
pub const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub const COMPRESS_BLOSC: u32 = 0x4;

/// Reads `out.len()` bytes of values stored with `compression` (`io::readData`).
pub(crate) fn read_data<S: Read + Seek>(s: &mut Stream<S>, compression: u32, out: &mut [u8]) -> R<()> {
    if compression & (COMPRESS_BLOSC | COMPRESS_ZIP) == 0 {
        return s.fill(out, "uncompressed values");
    }
    let (what, blosc) =
        if compression & COMPRESS_BLOSC != 0 { ("a Blosc chunk", true) } else { ("a zip chunk", false) };
    let at = s.pos();
    let count = s.i64(what)?;
    if count <= 0 {
        let n = count.unsigned_abs();
        if n != out.len() as u64 {
            return Err(s.malformed(what, at, format!("expected {} plain bytes, the chunk holds {n}", out.len())));
        }
        return s.fill(out, what);
    }
    // A chunk's count is believed only up to what an encoder can write for the bytes it decodes
    // to (Blosc stores an incompressible chunk as is, plus its 16-byte header; zlib's bound is a
    // few bytes per 16 KiB): a sparse file may claim any count, and it is allocated below.
    let limit = max_compressed(out.len() as u64);
    if count as u64 > limit {
        return Err(VdbError::Claimed {
            what,
            offset: at,
            claimed: count as u64,
            limit: format!("more than the {limit} bytes any encoder writes for the {} bytes it holds", out.len()),
        });
    }
    let data = s.bytes(count as u64, what)?;
    let result = if blosc { blosc_decompress(&data, out) } else { zlib_decompress(&data, out) };
    result.map_err(|message| s.malformed(what, at, message))
}

/// The most bytes a compressed chunk of `n` decoded bytes can take, with room to spare: Blosc's
/// bound is n + 16, zlib's n + n/4096 + n/16384 + 13.
fn max_compressed(n: u64) -> u64 {
    n + n / 8 + 1024
}

/// Inflates a zlib stream into exactly `out.len()` bytes.
pub fn zlib_decompress(data: &[u8], out: &mut [u8]) -> Result<(), String> {
    let mut d = flate2::read::ZlibDecoder::new(data);
    d.read_exact(out).map_err(|e| format!("zlib data does not inflate to {} bytes: {e}", out.len()))?;
    // Anything left means the chunk is not the size the node says.
    let mut extra = [0u8; 1];
    match d.read(&mut extra) {
        Ok(0) => Ok(()),
        Ok(_) => Err(format!("zlib data inflates to more than the expected {} bytes", out.len())),
        Err(e) => Err(format!("zlib data is corrupt: {e}")),
    }
}

const BLOSC_HEADER: usize = 16;
const BLOSC_DOSHUFFLE: u8 = 0x1;
const BLOSC_MEMCPYED: u8 = 0x2;
const BLOSC_DOBITSHUFFLE: u8 = 0x4;
const BLOSC_DONT_SPLIT: u8 = 0x10;
const BLOSC_MAX_SPLITS: usize = 16;
const BLOSC_MIN_BUFFERSIZE: usize = 128;
const BLOSC_LZ4: u8 = 1;
const BLOSC_ZLIB: u8 = 3;

/// Decodes a Blosc 1 frame into exactly `out.len()` bytes.
pub fn blosc_decompress(src: &[u8], out: &mut [u8]) -> Result<(), String> {
    if src.len() < BLOSC_HEADER {
        return Err(format!("a Blosc frame needs a 16-byte header, the chunk has {} bytes", src.len()));
    }
    let version = src[0];
    let flags = src[2];
    let typesize = src[3] as usize;
    let le = |i: usize| u32::from_le_bytes([src[i], src[i + 1], src[i + 2], src[i + 3]]) as usize;
    let (nbytes, blocksize, cbytes) = (le(4), le(8), le(12));
    if version == 0 || version > 2 {
        return Err(format!(
            "Blosc format version {version} is not supported (lpm reads Blosc 1 frames, versions 1 and 2)"
        ));
    }
    if nbytes != out.len() {
        return Err(format!("the Blosc frame holds {nbytes} bytes, expected {}", out.len()));
    }
    if cbytes != src.len() {
        return Err(format!("the Blosc header says {cbytes} compressed bytes, the chunk has {}", src.len()));
    }
    if flags & BLOSC_MEMCPYED != 0 {
        if src.len() != BLOSC_HEADER + nbytes {
            return Err("a stored (uncompressed) Blosc frame has the wrong length".into());
        }
        out.copy_from_slice(&src[BLOSC_HEADER..]);
        return Ok(());
    }
    if nbytes == 0 {
        return Ok(());
    }
    if blocksize == 0 || typesize == 0 {
        return Err("the Blosc header has a zero block size or type size".into());
    }
    if flags & BLOSC_DOBITSHUFFLE != 0 {
        return Err("Blosc bit shuffling is not supported (OpenVDB writes byte shuffling)".into());
    }
    let codec = flags >> 5;
    if codec != BLOSC_LZ4 && codec != BLOSC_ZLIB {
        let name = match codec {
            0 => "BloscLZ".to_string(),
            2 => "Snappy".to_string(),
            4 => "Zstd".to_string(),
            c => format!("code {c}"),
        };
        return Err(format!(
            "Blosc inner codec {name} is not supported (lpm reads LZ4 and zlib, which OpenVDB writes)"
        ));
    }
    let shuffle = flags & BLOSC_DOSHUFFLE != 0 && typesize > 1;
    let dont_split = flags & BLOSC_DONT_SPLIT != 0;
    let nblocks = nbytes.div_ceil(blocksize);
    let starts_end = BLOSC_HEADER + 4 * nblocks;
    if starts_end > src.len() {
        return Err(format!("the Blosc frame is too short for its {nblocks} block offsets"));
    }
    // Never allocate more than the frame decodes to, whatever the header's block size says.
    let mut tmp = vec![0u8; blocksize.min(nbytes)];
    for b in 0..nblocks {
        let bsize = if b + 1 == nblocks { nbytes - b * blocksize } else { blocksize };
        let leftover = bsize != blocksize;
        let mut at = le(BLOSC_HEADER + 4 * b);
        let nsplits =
            if !dont_split && typesize <= BLOSC_MAX_SPLITS && bsize / typesize >= BLOSC_MIN_BUFFERSIZE && !leftover {
                typesize
            } else {
                1
            };
        let neblock = bsize / nsplits;
        let dest = &mut tmp[..bsize];
        debug_assert!(bsize <= nbytes);
        for j in 0..nsplits {
            if at + 4 > src.len() {
                return Err(format!("Blosc block {b} starts past the end of the frame"));
            }
            let c = i32::from_le_bytes([src[at], src[at + 1], src[at + 2], src[at + 3]]);
            at += 4;
            let c = usize::try_from(c).map_err(|_| format!("Blosc block {b} has a negative stream size"))?;
            if at + c > src.len() {
                return Err(format!("Blosc block {b} runs past the end of the frame"));
            }
            let stream = &src[at..at + c];
            at += c;
            let part = &mut dest[j * neblock..(j + 1) * neblock];
            if c == neblock {
                part.copy_from_slice(stream);
            } else if codec == BLOSC_LZ4 {
                let n = lz4_flex::block::decompress_into(stream, part)
                    .map_err(|e| format!("LZ4 data in Blosc block {b} is corrupt: {e}"))?;
                if n != neblock {
                    return Err(format!("LZ4 data in Blosc block {b} decodes to {n} bytes, expected {neblock}"));
                }
            } else {
                zlib_decompress(stream, part).map_err(|e| format!("in Blosc block {b}: {e}"))?;
            }
        }
        let out_block = &mut out[b * blocksize..b * blocksize + bsize];
        if shuffle {
            unshuffle(typesize, dest, out_block);
        } else {
            out_block.copy_from_slice(dest);
        }
    }
    Ok(())
}

/// Blosc's byte unshuffle: byte j of element i sits at `j·n + i` in the shuffled block (n = the
/// number of whole elements); the bytes past the last whole element are stored as they are.
fn unshuffle(typesize: usize, src: &[u8], dest: &mut [u8]) {
    let n = src.len() / typesize;
    for i in 0..n {
        for j in 0..typesize {
            dest[i * typesize + j] = src[j * n + i];
        }
    }
    let whole = n * typesize;
    dest[whole..].copy_from_slice(&src[whole..]);
}

#[cfg(test)]
mod tests {
    //! The codec paths OpenVDB's Python module cannot be asked to write (it always writes Blosc
    //! with LZ4): zip chunks from an independent zlib encoder (flate2), plain chunks, and Blosc
    //! frames laid out by hand from the Blosc 1 format description with an independent LZ4 or
    //! zlib encoder inside (splits, shuffle, several blocks, a leftover block, memcpy frames).
    use super::*;
    use std::io::{Cursor, Write};

    fn values(n: usize) -> Vec<u8> {
        // Smooth f32s: compressible, and different in every byte lane.
        (0..n).flat_map(|i| ((i as f32 * 0.37).sin() * 0.5 + 0.5).to_le_bytes()).collect()
    }

    fn zlib(data: &[u8]) -> Vec<u8> {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    }

    fn chunk(payload: &[u8], count: i64) -> Vec<u8> {
        let mut v = count.to_le_bytes().to_vec();
        v.extend_from_slice(payload);
        v
    }

    fn read(bytes: Vec<u8>, compression: u32, n: usize) -> R<Vec<u8>> {
        let mut s = Stream::new(Cursor::new(bytes))?;
        let mut out = vec![0u8; n];
        read_data(&mut s, compression, &mut out)?;
        assert_eq!(s.remaining(), 0);
        Ok(out)
    }

    fn shuffle(typesize: usize, src: &[u8]) -> Vec<u8> {
        let n = src.len() / typesize;
        let mut d = src.to_vec();
        for i in 0..n {
            for j in 0..typesize {
                d[j * n + i] = src[i * typesize + j];
            }
        }
        d
    }

    /// A Blosc 1 frame: header, block starts, then per block its split streams (i32 size + data).
    fn blosc(data: &[u8], typesize: usize, blocksize: usize, codec: u8, split: bool, shuf: bool) -> Vec<u8> {
        let nblocks = data.len().div_ceil(blocksize);
        let mut body = Vec::new();
        let mut starts = Vec::new();
        let head = BLOSC_HEADER + 4 * nblocks;
        for b in 0..nblocks {
            let block = &data[b * blocksize..((b + 1) * blocksize).min(data.len())];
            let leftover = block.len() != blocksize;
            let block = if shuf { shuffle(typesize, block) } else { block.to_vec() };
            starts.push((head + body.len()) as u32);
            let nsplits =
                if split && !leftover && block.len() / typesize >= BLOSC_MIN_BUFFERSIZE { typesize } else { 1 };
            for part in block.chunks(block.len() / nsplits) {
                let c = if codec == BLOSC_LZ4 { lz4_flex::block::compress(part) } else { zlib(part) };
                let c = if c.len() >= part.len() { part.to_vec() } else { c };
                body.extend_from_slice(&(c.len() as i32).to_le_bytes());
                body.extend_from_slice(&c);
            }
        }
        let flags = (codec << 5) | if shuf { BLOSC_DOSHUFFLE } else { 0 } | if split { 0 } else { BLOSC_DONT_SPLIT };
        let total = head + body.len();
        let mut v = vec![2, 1, flags, typesize as u8];
        for x in [data.len(), blocksize, total] {
            v.extend_from_slice(&(x as u32).to_le_bytes());
        }
        for s in starts {
            v.extend_from_slice(&s.to_le_bytes());
        }
        v.extend_from_slice(&body);
        v
    }

    #[test]
    fn plain_values() {
        let data = values(512);
        assert_eq!(read(data.clone(), 0, data.len()).unwrap(), data);
        assert_eq!(read(data.clone(), COMPRESS_ACTIVE_MASK, data.len()).unwrap(), data);
    }

    #[test]
    fn zip_chunks_compressed_and_stored() {
        let data = values(512);
        let z = zlib(&data);
        assert!(z.len() < data.len());
        assert_eq!(read(chunk(&z, z.len() as i64), COMPRESS_ZIP, data.len()).unwrap(), data);
        assert_eq!(read(chunk(&data, -(data.len() as i64)), COMPRESS_ZIP, data.len()).unwrap(), data);
        // Wrong sizes are errors, not short or long reads.
        assert!(read(chunk(&z, z.len() as i64), COMPRESS_ZIP, data.len() + 4).is_err());
        assert!(read(chunk(&data, -(data.len() as i64)), COMPRESS_ZIP, data.len() - 4).is_err());
        assert!(matches!(
            read(chunk(&z[..z.len() / 2], z.len() as i64), COMPRESS_ZIP, data.len()),
            Err(crate::store::vdb::VdbError::Truncated { .. })
        ));
    }

    #[test]
    fn a_chunk_claiming_more_than_an_encoder_writes_is_refused_before_allocating() {
        // A sparse file of a terabyte whose one chunk claims all of it: before the check the
        // terabyte was allocated (an abort: "memory allocation failed").
        let mut file = tempfile::tempfile().unwrap();
        file.write_all(&chunk(&[], 1 << 40)).unwrap();
        file.set_len((1 << 40) + 8).unwrap();
        for compression in [COMPRESS_BLOSC, COMPRESS_ZIP] {
            let mut s = Stream::new(std::io::BufReader::new(file.try_clone().unwrap())).unwrap();
            let mut out = vec![0u8; 2048];
            let e = read_data(&mut s, compression, &mut out).unwrap_err();
            assert!(matches!(e, VdbError::Claimed { claimed: 1099511627776, offset: 0, .. }), "{e}");
            assert!(e.to_string().contains("any encoder writes for the 2048 bytes"), "{e}");
        }
        // The largest chunk an encoder can write is still read (and here found corrupt).
        let data = values(512);
        let e = read(chunk(&vec![0; 2048 + 16], 2048 + 16), COMPRESS_BLOSC, data.len()).unwrap_err();
        assert!(matches!(e, VdbError::Malformed { .. }), "{e}");
    }

    #[test]
    fn blosc_frames_lz4_and_zlib_split_shuffled_multi_block() {
        let data = values(512); // a leaf: 2048 bytes
        for codec in [BLOSC_LZ4, BLOSC_ZLIB] {
            for (blocksize, split, shuf) in
                [(2048, true, true), (2048, false, true), (2048, true, false), (768, true, true), (512, false, false)]
            {
                let f = blosc(&data, 4, blocksize, codec, split, shuf);
                let got = read(chunk(&f, f.len() as i64), COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK, data.len());
                assert_eq!(got.unwrap(), data, "codec {codec} block {blocksize} split {split} shuffle {shuf}");
            }
        }
        // Half values (2-byte lanes), as OpenVDB writes them with typesize 4.
        let half = values(256);
        let f = blosc(&half[..1024], 4, 1024, BLOSC_LZ4, true, true);
        assert_eq!(read(chunk(&f, f.len() as i64), COMPRESS_BLOSC, 1024).unwrap(), &half[..1024]);
        // A stored chunk (negative count), as OpenVDB writes incompressible or tiny blocks.
        assert_eq!(read(chunk(&data, -(data.len() as i64)), COMPRESS_BLOSC, data.len()).unwrap(), data);
    }

    #[test]
    fn blosc_memcpy_frame_and_corruptions() {
        let data = values(64);
        let mut f = vec![2, 1, BLOSC_MEMCPYED | BLOSC_DOSHUFFLE, 4];
        for x in [data.len(), data.len(), BLOSC_HEADER + data.len()] {
            f.extend_from_slice(&(x as u32).to_le_bytes());
        }
        f.extend_from_slice(&data);
        let mut out = vec![0u8; data.len()];
        blosc_decompress(&f, &mut out).unwrap();
        assert_eq!(out, data);

        let data = values(512);
        let good = blosc(&data, 4, 2048, BLOSC_LZ4, true, true);
        let mut out = vec![0u8; data.len()];
        // Every single-byte corruption decodes to an error or to some bytes, never a panic; a
        // corrupt header is always noticed.
        for at in 0..good.len() {
            let mut b = good.clone();
            b[at] ^= 0x5a;
            let r = blosc_decompress(&b, &mut out);
            if at < BLOSC_HEADER && at != 1 && at != 8 && at != 9 && at != 10 && at != 11 {
                assert!(r.is_err() || at == 2, "header byte {at} corrupted but accepted");
            }
        }
        for cut in 0..good.len() {
            assert!(blosc_decompress(&good[..cut], &mut out).is_err(), "frame cut at {cut} accepted");
        }
        // A header asking for a 4 GiB block does not allocate it.
        let mut b = good.clone();
        b[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(blosc_decompress(&b, &mut out).is_err());
    }
}
