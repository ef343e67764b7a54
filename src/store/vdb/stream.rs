//! A bounds-checked little-endian reader over a VDB file. Every length read from the file is checked
//! against what is left of it before anything is allocated, so a corrupt count is a typed error,
//! never a huge allocation or a panic; a file that ends early (or shrinks while being read) is a
//! [`VdbError::Truncated`] naming what was being read.

use super::error::{VdbError, R};
use std::io::{ErrorKind, Read, Seek, SeekFrom};

pub(crate) struct Stream<S> {
    inner: S,
    pos: u64,
    len: u64,
}

impl<S: Read + Seek> Stream<S> {
    pub fn new(mut inner: S) -> R<Self> {
        let len = inner.seek(SeekFrom::End(0)).map_err(VdbError::Io)?;
        inner.seek(SeekFrom::Start(0)).map_err(VdbError::Io)?;
        Ok(Stream { inner, pos: 0, len })
    }

    pub fn pos(&self) -> u64 {
        self.pos
    }

    pub fn remaining(&self) -> u64 {
        self.len.saturating_sub(self.pos)
    }

    pub fn truncated(&self, what: &'static str, offset: u64) -> VdbError {
        VdbError::Truncated { what, offset, len: self.len }
    }

    pub fn malformed(&self, what: &'static str, offset: u64, message: impl Into<String>) -> VdbError {
        VdbError::Malformed { what, offset, message: message.into() }
    }

    pub fn seek(&mut self, pos: u64, what: &'static str) -> R<()> {
        if pos > self.len {
            return Err(self.malformed(
                what,
                self.pos,
                format!("offset {pos} is past the end of the file ({} bytes)", self.len),
            ));
        }
        self.inner.seek(SeekFrom::Start(pos)).map_err(VdbError::Io)?;
        self.pos = pos;
        Ok(())
    }

    /// Fills `buf` from the file, or says that the file ends inside `what`.
    pub fn fill(&mut self, buf: &mut [u8], what: &'static str) -> R<()> {
        let start = self.pos;
        if (buf.len() as u64) > self.remaining() {
            return Err(self.truncated(what, start));
        }
        match self.inner.read_exact(buf) {
            Ok(()) => {
                self.pos += buf.len() as u64;
                Ok(())
            }
            // The file shrank after its length was taken.
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => Err(self.truncated(what, start)),
            Err(e) => Err(VdbError::Io(e)),
        }
    }

    /// Reads `n` bytes into a new vector; `n` is checked against the file's remaining length first.
    pub fn bytes(&mut self, n: u64, what: &'static str) -> R<Vec<u8>> {
        if n > self.remaining() {
            return Err(self.truncated(what, self.pos));
        }
        let mut v = vec![0u8; n as usize];
        self.fill(&mut v, what)?;
        Ok(v)
    }

    pub fn skip(&mut self, n: u64, what: &'static str) -> R<()> {
        if n > self.remaining() {
            return Err(self.truncated(what, self.pos));
        }
        self.seek(self.pos + n, what)
    }

    pub fn array<const N: usize>(&mut self, what: &'static str) -> R<[u8; N]> {
        let mut b = [0u8; N];
        self.fill(&mut b, what)?;
        Ok(b)
    }

    pub fn u8(&mut self, what: &'static str) -> R<u8> {
        Ok(self.array::<1>(what)?[0])
    }
    pub fn u32(&mut self, what: &'static str) -> R<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    pub fn i32(&mut self, what: &'static str) -> R<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    pub fn i64(&mut self, what: &'static str) -> R<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }
    pub fn f64(&mut self, what: &'static str) -> R<f64> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }
    pub fn vec3d(&mut self, what: &'static str) -> R<[f64; 3]> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }
    pub fn coord(&mut self, what: &'static str) -> R<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    /// A string as OpenVDB writes it: a u32 length, then that many bytes (not NUL-terminated).
    pub fn string(&mut self, what: &'static str) -> R<String> {
        let at = self.pos;
        let n = self.u32(what)?;
        let b = self.bytes(u64::from(n), what)?;
        String::from_utf8(b).map_err(|_| self.malformed(what, at, "the text is not valid UTF-8"))
    }

    /// A node mask of `words` u64 words (bit n = value n; OpenVDB's NodeMask::load).
    pub fn mask(&mut self, words: usize, what: &'static str) -> R<Vec<u64>> {
        let b = self.bytes(words as u64 * 8, what)?;
        Ok(b.chunks_exact(8).map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]])).collect())
    }
}
