//! Turning a byte offset reported by the TOML parser into a line, a column and the dotted key
//! written there. `toml` reports the span of the offending key (unknown keys) or value (type
//! errors) but keeps its key path private, so the key is recovered from the text: the innermost
//! `[table]` / `[[array]]` header above the offset, then the `key =` the offset belongs to.
//! This is a best effort for messages only; it never affects what is accepted.

/// 1-based line and column (in characters) of `offset` in `text`.
pub(crate) fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let offset = floor_char_boundary(text, offset.min(text.len()));
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before[line_start..].chars().count() + 1;
    (line, column)
}

fn floor_char_boundary(text: &str, mut i: usize) -> usize {
    while i > 0 && !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// The dotted key at `offset`, e.g. `volume.dims`, `lights[1].direction`, or the table itself
/// (`lights[1]`) when the offset is on a header line. `None` when nothing sensible is found.
pub(crate) fn key_at(text: &str, offset: usize) -> Option<String> {
    let offset = floor_char_boundary(text, offset.min(text.len()));
    let lines: Vec<&str> = text.split('\n').collect();
    let (target_line, _) = line_column(text, offset);
    let target = target_line - 1;

    // Walk the headers down to the target line.
    let mut table: Option<String> = None;
    let mut header_line: Option<usize> = None;
    let mut array_counts: Vec<(String, usize)> = Vec::new();
    for (i, line) in lines.iter().enumerate().take(target + 1) {
        if let Some(h) = parse_header(line) {
            let name = match h {
                Header::Table(name) => name,
                Header::Array(name) => {
                    let n = match array_counts.iter_mut().find(|(k, _)| *k == name) {
                        Some((_, n)) => {
                            *n += 1;
                            *n
                        }
                        None => {
                            array_counts.push((name.clone(), 0));
                            0
                        }
                    };
                    format!("{name}[{n}]")
                }
            };
            table = Some(name);
            header_line = Some(i);
        }
    }
    if header_line == Some(target) {
        return table;
    }

    let qualify = |key: String| match &table {
        Some(t) => format!("{t}.{key}"),
        None => key,
    };
    // On the target line itself: its key, and inside an inline table (`medium = { sigma_t = 1,
    // albedo = "x" }`) the inner key the offset is in, rather than only the outer one.
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    if let Some(key) = parse_key(lines[target]) {
        let before = &text[line_start..offset];
        return Some(qualify(match inline_key(before) {
            Some(inner) => format!("{key}.{inner}"),
            None => key,
        }));
    }
    // A line that starts like `key = …` but whose key cannot be read is not a continuation of the
    // key above: name no key rather than the previous one.
    if looks_like_key_line(lines[target]) {
        return table;
    }
    // A continuation line (of a multi-line array): the nearest `key =` above, below the header.
    let first = header_line.map_or(0, |h| h + 1);
    for i in (first..target).rev() {
        if let Some(key) = parse_key(lines[i]) {
            return Some(qualify(key));
        }
    }
    table
}

/// The key of the innermost inline-table entry that `before` (the line up to the offset) ends in.
fn inline_key(before: &str) -> Option<String> {
    let eq = before.find('=')?;
    let open = before[eq..].rfind('{')? + eq;
    let start = before[open..].rfind(',').map_or(open + 1, |i| open + i + 1);
    parse_key(&before[start..])
}

/// True for a line whose text before its first `=` holds no value syntax (brackets, braces, commas):
/// a `key = value` line, even one whose key [`parse_key`] does not read.
fn looks_like_key_line(line: &str) -> bool {
    let t = line.trim_start();
    match t.find('=') {
        Some(eq) => {
            let key = t[..eq].trim();
            !key.is_empty() && !key.contains(['[', ']', '{', '}', ','])
        }
        None => false,
    }
}

enum Header {
    Table(String),
    Array(String),
}

fn parse_header(line: &str) -> Option<Header> {
    let t = line.trim_start();
    if let Some(rest) = t.strip_prefix("[[") {
        let end = rest.find("]]")?;
        Some(Header::Array(normalise_key(&rest[..end])))
    } else if let Some(rest) = t.strip_prefix('[') {
        let end = rest.find(']')?;
        Some(Header::Table(normalise_key(&rest[..end])))
    } else {
        None
    }
}

/// `key = ...` at the start of a line: the key, normalised; `None` for other lines.
fn parse_key(line: &str) -> Option<String> {
    let t = line.trim_start();
    let first = t.chars().next()?;
    if !(first.is_ascii_alphanumeric() || first == '_' || first == '-' || first == '"' || first == '\'') {
        return None;
    }
    let eq = t.find('=')?;
    let key = &t[..eq];
    let ok = key.chars().all(|c| c.is_ascii_alphanumeric() || "_-.\"' \t".contains(c));
    if !ok {
        return None;
    }
    Some(normalise_key(key))
}

fn normalise_key(key: &str) -> String {
    key.split('.').map(|part| part.trim().trim_matches(|c| c == '"' || c == '\'')).collect::<Vec<_>>().join(".")
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "top = 1\n[volume]\ndims = [1,\n  2, 3]\n[[lights]]\nkind = \"sky\"\n[[lights]]\n kind = \"sun\"\n \"dir\" = 3\n";

    fn offset_of(needle: &str, nth: usize) -> usize {
        TEXT.match_indices(needle).nth(nth).map(|(i, _)| i).unwrap_or(usize::MAX)
    }

    #[test]
    fn keys_and_tables() {
        assert_eq!(key_at(TEXT, 0).as_deref(), Some("top"));
        assert_eq!(key_at(TEXT, offset_of("[volume]", 0)).as_deref(), Some("volume"));
        assert_eq!(key_at(TEXT, offset_of("2, 3", 0)).as_deref(), Some("volume.dims"));
        assert_eq!(key_at(TEXT, offset_of("\"sky\"", 0)).as_deref(), Some("lights[0].kind"));
        assert_eq!(key_at(TEXT, offset_of("\"sun\"", 0)).as_deref(), Some("lights[1].kind"));
        assert_eq!(key_at(TEXT, offset_of("3\n", 1)).as_deref(), Some("lights[1].dir"));
    }

    /// Issue 13, item 11: a key the line parser cannot read (non-ASCII) was reported under the key
    /// above it; an error inside an inline table named only the outer key.
    #[test]
    fn unreadable_keys_and_inline_tables() {
        let text = "[medium]\nalbedo = 0.5\n\"σ\" = 1\n";
        let at = text.find("\"σ\"").unwrap();
        assert_eq!(key_at(text, at).as_deref(), Some("medium"));
        let text = "medium = { sigma_t = 1, albedo = \"x\" }\n";
        let at = text.find("\"x\"").unwrap();
        assert_eq!(key_at(text, at).as_deref(), Some("medium.albedo"));
        let at = text.find('1').unwrap();
        assert_eq!(key_at(text, at).as_deref(), Some("medium.sigma_t"));
    }

    #[test]
    fn lines_and_columns() {
        assert_eq!(line_column(TEXT, 0), (1, 1));
        assert_eq!(line_column(TEXT, offset_of("dims", 0) + 2), (3, 3));
        assert_eq!(line_column("é=1", 2), (1, 2));
    }
}
