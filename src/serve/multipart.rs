//! `multipart/form-data` request bodies (RFC 7578), read as a stream: `POST /v1/jobs` with the
//! scene and its volume file in one request.
//!
//! Why by hand: the maintained multipart crates are async (multer needs futures, bytes and http on
//! top of a runtime this server does not have), and the synchronous one is unmaintained. What a
//! job submission needs is small: find the boundary lines, read each part's `Content-Disposition`,
//! and stream each part's body to where it goes (a volume of gigabytes straight to a file) without
//! holding it in memory. Every limit is enforced while reading: the whole body, each part, the
//! part headers.

use std::io::{Read, Write};

/// Why a body was refused.
#[derive(Debug, thiserror::Error)]
pub enum MultipartError {
    #[error("multipart body: {0}")]
    Malformed(String),
    #[error("the request body is larger than the limit of {0} bytes")]
    TooLarge(u64),
    #[error("multipart part {name:?} is larger than its limit of {limit} bytes")]
    PartTooLarge { name: String, limit: u64 },
    #[error("cannot read the request body: {0}")]
    Read(std::io::Error),
    #[error("cannot store multipart part {name:?}: {source}")]
    Write { name: String, source: std::io::Error },
}

/// What a part's headers say.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Part {
    /// The form field's name (`Content-Disposition: form-data; name="…"`).
    pub name: String,
    /// The file name, for a file part.
    pub filename: Option<String>,
    pub content_type: Option<String>,
}

/// The boundary of a `multipart/form-data` Content-Type header value, if it is one.
pub fn boundary(content_type: &str) -> Option<String> {
    let mut pieces = content_type.split(';');
    if !pieces.next()?.trim().eq_ignore_ascii_case("multipart/form-data") {
        return None;
    }
    for piece in pieces {
        let (key, value) = piece.split_once('=')?;
        if key.trim().eq_ignore_ascii_case("boundary") {
            let b = value.trim().trim_matches('"');
            // RFC 2046: 1 to 70 characters.
            return (!b.is_empty() && b.len() <= 70).then(|| b.to_string());
        }
    }
    None
}

/// Most bytes of one part's headers.
const MAX_HEADERS: usize = 16 << 10;
/// Bytes read from the client at a time.
const CHUNK: usize = 64 << 10;

/// A multipart body being read part by part.
pub struct Multipart<R> {
    reader: R,
    /// `\r\n--BOUNDARY`: what ends a part (and, with the CRLF the reader starts with, what opens
    /// the first one).
    delimiter: Vec<u8>,
    buf: Vec<u8>,
    start: usize,
    /// Bytes read from `reader` so far, and the most allowed.
    read: u64,
    limit: u64,
    /// The current part's body is not read yet.
    in_body: bool,
    finished: bool,
}

impl<R: Read> Multipart<R> {
    /// Reads `reader` as a multipart body with `boundary`, refusing more than `limit` bytes.
    pub fn new(reader: R, boundary: &str, limit: u64) -> Self {
        // The body starts with `--BOUNDARY`; a virtual CRLF in front makes it the same delimiter as
        // the ones between parts.
        Multipart {
            reader,
            delimiter: format!("\r\n--{boundary}").into_bytes(),
            buf: b"\r\n".to_vec(),
            start: 0,
            read: 0,
            limit,
            in_body: true,
            finished: false,
        }
    }

    /// Reads more of the body into the buffer; false at its end.
    fn fill(&mut self) -> Result<bool, MultipartError> {
        if self.start > 0 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        let old = self.buf.len();
        self.buf.resize(old + CHUNK, 0);
        let n = loop {
            match self.reader.read(&mut self.buf[old..]) {
                Ok(n) => break n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    self.buf.truncate(old);
                    return Err(MultipartError::Read(e));
                }
            }
        };
        self.buf.truncate(old + n);
        self.read += n as u64;
        if self.read > self.limit {
            return Err(MultipartError::TooLarge(self.limit));
        }
        Ok(n > 0)
    }

    fn pending(&self) -> &[u8] {
        &self.buf[self.start..]
    }

    /// Copies the current part's body (up to its delimiter) into `sink`, at most `limit` bytes;
    /// returns how many.
    fn body_into(&mut self, sink: &mut dyn Write, name: &str, limit: u64) -> Result<u64, MultipartError> {
        let d = self.delimiter.len();
        let mut written = 0u64;
        let mut emit = |bytes: &[u8], written: &mut u64| -> Result<(), MultipartError> {
            *written += bytes.len() as u64;
            if *written > limit {
                return Err(MultipartError::PartTooLarge { name: name.to_string(), limit });
            }
            sink.write_all(bytes).map_err(|source| MultipartError::Write { name: name.to_string(), source })
        };
        loop {
            if let Some(at) = find(self.pending(), &self.delimiter) {
                let s = self.start;
                emit(&self.buf[s..s + at], &mut written)?;
                self.start += at + d;
                self.in_body = false;
                return Ok(written);
            }
            // Everything but a tail that may be the start of the delimiter is body.
            let safe = self.pending().len().saturating_sub(d - 1);
            let s = self.start;
            emit(&self.buf[s..s + safe], &mut written)?;
            self.start += safe;
            if !self.fill()? {
                return Err(MultipartError::Malformed("the body ended inside a part (no closing boundary)".into()));
            }
        }
    }

    /// Moves to the next part and returns its headers; `None` after the closing boundary.
    pub fn next_part(&mut self) -> Result<Option<Part>, MultipartError> {
        if self.finished {
            return Ok(None);
        }
        if self.in_body {
            // The preamble, or a part the caller did not read: skipped.
            self.body_into(&mut std::io::sink(), "", u64::MAX)?;
        }
        // After a delimiter: `--` ends the body, else optional blanks and CRLF open a part.
        while self.pending().len() < 2 {
            if !self.fill()? {
                return Err(MultipartError::Malformed("the body ended after a boundary".into()));
            }
        }
        if self.pending().starts_with(b"--") {
            self.finished = true;
            return Ok(None);
        }
        let headers = loop {
            if let Some(end) = find(self.pending(), b"\r\n\r\n") {
                let text = String::from_utf8_lossy(&self.pending()[..end]).into_owned();
                self.start += end + 4;
                break text;
            }
            if self.pending().len() > MAX_HEADERS {
                return Err(MultipartError::Malformed(format!("part headers longer than {MAX_HEADERS} bytes")));
            }
            if !self.fill()? {
                return Err(MultipartError::Malformed("the body ended inside part headers".into()));
            }
        };
        self.in_body = true;
        parse_headers(&headers).map(Some)
    }

    /// Streams the current part's body into `sink`, refusing more than `limit` bytes.
    pub fn read_part(&mut self, part: &Part, sink: &mut dyn Write, limit: u64) -> Result<u64, MultipartError> {
        if !self.in_body {
            return Err(MultipartError::Malformed(format!("part {:?} was already read", part.name)));
        }
        self.body_into(sink, &part.name, limit)
    }
}

/// Where `needle` first occurs in `hay`.
fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    let first = *needle.first()?;
    let mut from = 0;
    while let Some(i) = hay[from..].iter().position(|&b| b == first) {
        let at = from + i;
        if hay.len() - at < needle.len() {
            return None;
        }
        if &hay[at..at + needle.len()] == needle {
            return Some(at);
        }
        from = at + 1;
    }
    None
}

/// The part's headers: the first line (after the boundary's line end) through the blank line.
fn parse_headers(text: &str) -> Result<Part, MultipartError> {
    // What follows the boundary on its line (only blanks are allowed) ends with the first CRLF.
    let (rest_of_boundary_line, lines) = text.split_once("\r\n").unwrap_or((text, ""));
    if !rest_of_boundary_line.trim().is_empty() {
        return Err(MultipartError::Malformed("text after a boundary on its line".into()));
    }
    let mut part = Part { name: String::new(), filename: None, content_type: None };
    let mut disposition = false;
    for line in lines.split("\r\n").filter(|l| !l.is_empty()) {
        let Some((key, value)) = line.split_once(':') else {
            return Err(MultipartError::Malformed(format!("a part header without a colon: {line:?}")));
        };
        if key.trim().eq_ignore_ascii_case("content-disposition") {
            let params = parameters(value);
            if !params.first().is_some_and(|(k, _)| k.eq_ignore_ascii_case("form-data")) {
                return Err(MultipartError::Malformed(format!("Content-Disposition is not form-data: {value:?}")));
            }
            for (k, v) in &params[1..] {
                if k.eq_ignore_ascii_case("name") {
                    part.name = v.clone();
                } else if k.eq_ignore_ascii_case("filename") {
                    part.filename = Some(v.clone());
                }
            }
            disposition = true;
        } else if key.trim().eq_ignore_ascii_case("content-type") {
            part.content_type = Some(value.trim().to_string());
        }
    }
    if !disposition || part.name.is_empty() {
        return Err(MultipartError::Malformed("a part without a Content-Disposition naming its field".into()));
    }
    Ok(part)
}

/// `form-data; name="a"; filename="b c.raw"` → [("form-data", ""), ("name", "a"), ("filename", "b c.raw")].
fn parameters(value: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut chars = value.chars().peekable();
    loop {
        let mut key = String::new();
        while let Some(&c) = chars.peek() {
            if c == ';' || c == '=' {
                break;
            }
            key.push(c);
            chars.next();
        }
        let mut val = String::new();
        if chars.peek() == Some(&'=') {
            chars.next();
            while chars.peek().is_some_and(|c| c.is_whitespace()) {
                chars.next();
            }
            if chars.peek() == Some(&'"') {
                chars.next();
                while let Some(c) = chars.next() {
                    match c {
                        '"' => break,
                        '\\' => val.extend(chars.next()),
                        c => val.push(c),
                    }
                }
                while chars.peek().is_some_and(|&c| c != ';') {
                    chars.next();
                }
            } else {
                while let Some(&c) = chars.peek() {
                    if c == ';' {
                        break;
                    }
                    val.push(c);
                    chars.next();
                }
            }
        }
        if !key.trim().is_empty() {
            out.push((key.trim().to_string(), val.trim_end().to_string()));
        }
        if chars.next().is_none() {
            return out;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn body(boundary: &str, parts: &[(&str, Option<&str>, &[u8])]) -> Vec<u8> {
        let mut b = b"preamble, ignored\r\n".to_vec();
        for (name, filename, data) in parts {
            b.extend_from_slice(format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"").as_bytes());
            if let Some(f) = filename {
                b.extend_from_slice(format!("; filename=\"{f}\"\r\nContent-Type: application/octet-stream").as_bytes());
            }
            b.extend_from_slice(b"\r\n\r\n");
            b.extend_from_slice(data);
            b.extend_from_slice(b"\r\n");
        }
        b.extend_from_slice(format!("--{boundary}--\r\nepilogue").as_bytes());
        b
    }

    /// Reads every part, one byte at a time from the reader (boundaries split across reads).
    fn read_all(bytes: &[u8], boundary: &str, limit: u64) -> Result<Vec<(Part, Vec<u8>)>, MultipartError> {
        struct Trickle<'a>(&'a [u8]);
        impl Read for Trickle<'_> {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                let n = self.0.len().min(buf.len()).min(3);
                buf[..n].copy_from_slice(&self.0[..n]);
                self.0 = &self.0[n..];
                Ok(n)
            }
        }
        let mut m = Multipart::new(Trickle(bytes), boundary, limit);
        let mut out = Vec::new();
        while let Some(part) = m.next_part()? {
            let mut data = Vec::new();
            m.read_part(&part, &mut data, 1 << 20)?;
            out.push((part, data));
        }
        Ok(out)
    }

    #[test]
    fn parts_with_binary_bodies_split_anywhere() {
        let volume: Vec<u8> = (0..5000u32).flat_map(|i| (i as f32).to_le_bytes()).chain(*b"\r\n--xy\r\n").collect();
        let b = body("xyz", &[("scene", None, b"[volume]\nraw = \"c.raw\"\n"), ("volume", Some("c.raw"), &volume)]);
        let parts = read_all(&b, "xyz", 1 << 20).unwrap();
        assert_eq!(parts.len(), 2);
        assert_eq!(parts[0].0, Part { name: "scene".into(), filename: None, content_type: None });
        assert_eq!(parts[0].1, b"[volume]\nraw = \"c.raw\"\n");
        assert_eq!(parts[1].0.filename.as_deref(), Some("c.raw"));
        assert_eq!(parts[1].1, volume);
    }

    #[test]
    fn limits_and_malformed_bodies() {
        let b = body("b", &[("scene", None, b"x = 1")]);
        assert!(matches!(read_all(&b, "b", 10), Err(MultipartError::TooLarge(10))));
        let unterminated = b"--b\r\nContent-Disposition: form-data; name=\"a\"\r\n\r\nno end";
        assert!(matches!(read_all(unterminated, "b", 1000), Err(MultipartError::Malformed(_))));
        let no_name = b"--b\r\nContent-Type: text/plain\r\n\r\nx\r\n--b--";
        assert!(matches!(read_all(no_name, "b", 1000), Err(MultipartError::Malformed(_))));
        let one = body("b", &[("v", Some("f"), &[7u8; 100])]);
        let mut m = Multipart::new(&one[..], "b", 1 << 20);
        let part = m.next_part().unwrap().unwrap();
        assert!(matches!(m.read_part(&part, &mut Vec::new(), 99), Err(MultipartError::PartTooLarge { limit: 99, .. })));
    }

    #[test]
    fn content_type_boundary_and_quoted_parameters() {
        assert_eq!(boundary("multipart/form-data; boundary=abc"), Some("abc".into()));
        assert_eq!(boundary("Multipart/Form-Data; charset=utf-8; boundary=\"a b\""), Some("a b".into()));
        assert_eq!(boundary("application/toml"), None);
        assert_eq!(boundary("multipart/form-data"), None);
        let p = parameters(r#" form-data; name="a;b"; filename="q\"x.raw""#);
        assert_eq!(p[1], ("name".into(), "a;b".into()));
        assert_eq!(p[2], ("filename".into(), "q\"x.raw".into()));
    }
}
