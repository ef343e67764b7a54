//! The NRRD header (format versions 1–5, <https://teem.sourceforge.net/nrrd/format.html>), for the
//! fields a density volume needs: `type`, `dimension` (3), `sizes`, `encoding` (raw, gzip),
//! `endian`, `data file` (detached `.nhdr`) or the data after the header (attached `.nrrd`),
//! `byte skip`, and the geometry: `spacings` or `space directions` (axis-aligned, uniform) and
//! `space origin` or `axis mins`. Other fields and `key:=value` pairs are ignored; comments too.

use std::path::{Path, PathBuf};

/// A sample type lpm reads (converted to f32 as is: an 8-bit 255 is density 255).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    U8,
    U16,
    F32,
    F64,
}

impl SampleType {
    pub fn size(self) -> usize {
        match self {
            SampleType::U8 => 1,
            SampleType::U16 => 2,
            SampleType::F32 => 4,
            SampleType::F64 => 8,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Raw,
    Gzip,
}

/// Where the samples are.
#[derive(Clone, Debug, PartialEq)]
pub enum DataSource {
    /// A separate file (absolute path, resolved against the header's directory).
    Detached(PathBuf),
    /// In the header's own file, from this byte offset.
    Attached(u64),
}

#[derive(Clone, Debug, PartialEq)]
pub struct NrrdHeader {
    pub sample: SampleType,
    pub dims: [u64; 3],
    pub encoding: Encoding,
    pub big_endian: bool,
    pub data: DataSource,
    /// Bytes to skip before the samples: in the file for raw, in the decompressed stream for gzip
    /// (as teem does).
    pub byte_skip: u64,
    /// World units per voxel edge, when the header gives one.
    pub voxel_size: Option<f64>,
    /// World position of the volume's low corner, when the header gives one.
    pub corner: Option<[f64; 3]>,
}

/// Parses the header text (`text` is the file's first bytes: the whole header for `.nhdr`, the
/// header and possibly data for `.nrrd`). `path` is the header file. Errors are (field, problem).
pub fn parse(path: &Path, bytes: &[u8]) -> Result<NrrdHeader, (String, String)> {
    let err = |field: &str, problem: String| Err((field.to_string(), problem));
    if !bytes.starts_with(b"NRRD000") || bytes.len() < 8 || !(b'1'..=b'5').contains(&bytes[7]) {
        return err("magic", "the file does not start with NRRD0001 to NRRD0005: not an NRRD file".into());
    }
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut pos = 0usize;
    let mut first = true;
    let mut data_at = None;
    while pos < bytes.len() {
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |i| pos + i);
        let line = &bytes[pos..end];
        let next = (end + 1).min(bytes.len());
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if first {
            first = false;
        } else if line.is_empty() {
            data_at = Some(next as u64);
            break;
        } else if !line.starts_with(b"#") {
            let Ok(text) = std::str::from_utf8(line) else {
                return err("header", format!("line at byte {pos} is not text"));
            };
            if text.contains(":=") {
                // key/value pair: not used
            } else if let Some((k, v)) = text.split_once(": ") {
                fields.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
            } else {
                return err("header", format!("line \"{text}\" is neither \"field: value\" nor a comment"));
            }
        }
        pos = next;
        if pos == bytes.len() {
            data_at = None;
        }
    }
    let get = |name: &str| fields.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str());
    let need = |name: &str| get(name).ok_or_else(|| (name.to_string(), "is required but missing".to_string()));

    let sample = match need("type")? {
        "float" => SampleType::F32,
        "double" => SampleType::F64,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => SampleType::U8,
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => SampleType::U16,
        other => {
            return err("type", format!("\"{other}\" is not supported: lpm reads float, double, uchar and ushort"))
        }
    };
    let dimension = need("dimension")?;
    if dimension != "3" {
        return err("dimension", format!("is {dimension}; a density volume has dimension 3"));
    }
    let sizes: Vec<u64> = need("sizes")?.split_whitespace().map(|s| s.parse::<u64>().unwrap_or(0)).collect();
    if sizes.len() != 3 || sizes.contains(&0) {
        return err("sizes", format!("\"{}\" is not 3 positive integers", need("sizes")?));
    }
    let dims = [sizes[0], sizes[1], sizes[2]];
    let encoding = match need("encoding")? {
        "raw" => Encoding::Raw,
        "gzip" | "gz" => Encoding::Gzip,
        other => return err("encoding", format!("\"{other}\" is not supported: lpm reads raw and gzip")),
    };
    let big_endian = match get("endian") {
        None if sample.size() == 1 => false,
        None => return err("endian", "is required for multi-byte samples".into()),
        Some("little") => false,
        Some("big") => true,
        Some(other) => return err("endian", format!("\"{other}\" is neither little nor big")),
    };
    let byte_skip = match get("byte skip") {
        None => 0,
        Some(v) => match v.parse::<u64>() {
            Ok(n) => n,
            Err(_) => return err("byte skip", format!("\"{v}\" is not a byte count ≥ 0 (-1 is not supported)")),
        },
    };
    if get("line skip").is_some_and(|v| v != "0") {
        return err("line skip", "is not supported".into());
    }
    let data = match get("data file").or(get("datafile")) {
        Some(name) if name.starts_with("LIST") || name.contains('%') => {
            return err("data file", format!("\"{name}\": multi-file data is not supported"))
        }
        Some(name) => {
            let base = path.parent().unwrap_or_else(|| Path::new(""));
            let joined = base.join(name);
            DataSource::Detached(std::path::absolute(&joined).unwrap_or(joined))
        }
        None => match data_at {
            Some(at) => DataSource::Attached(at),
            None => return err("data file", "is missing and no data follows the header".into()),
        },
    };

    // Geometry: a uniform, axis-aligned voxel size, and the corner of the first voxel.
    let centers_cell = get("centers").or(get("centerings")).is_none_or(|c| c.split_whitespace().all(|c| c == "cell"));
    let mut voxel_size = None;
    let mut set_size = |field: &str, h: [f64; 3]| -> Result<(), (String, String)> {
        if !h.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err((field.into(), format!("voxel edges {h:?} must be positive and finite")));
        }
        if (h[0] - h[1]).abs() > 1e-9 * h[0] || (h[0] - h[2]).abs() > 1e-9 * h[0] {
            return Err((field.into(), format!("voxel edges {h:?} differ; lpm's voxels are cubes")));
        }
        voxel_size = Some(h[0]);
        Ok(())
    };
    if let Some(v) = get("space directions") {
        // Exactly one vector per axis: more would index past the three edges below.
        let vecs = parse_vectors(v)
            .filter(|vecs| vecs.len() == 3)
            .ok_or_else(|| ("space directions".to_string(), format!("\"{v}\" is not 3 vectors")))?;
        let mut h = [0.0; 3];
        for (a, d) in vecs.iter().enumerate() {
            for (b, c) in d.iter().enumerate() {
                if a != b && *c != 0.0 {
                    return err(
                        "space directions",
                        format!("\"{v}\" is not axis-aligned; lpm needs axis-aligned voxels"),
                    );
                }
            }
            h[a] = d[a];
        }
        set_size("space directions", h)?;
    } else if let Some(v) = get("spacings") {
        let h: Vec<f64> = v.split_whitespace().map(|s| s.parse::<f64>().unwrap_or(f64::NAN)).collect();
        if h.len() != 3 {
            return err("spacings", format!("\"{v}\" is not 3 numbers"));
        }
        set_size("spacings", [h[0], h[1], h[2]])?;
    }
    let h = voxel_size.unwrap_or(1.0);
    let corner = if let Some(v) = get("space origin") {
        let o = parse_vectors(v)
            .filter(|o| o.len() == 1)
            .ok_or_else(|| ("space origin".to_string(), format!("\"{v}\" is not one vector")))?;
        // The space origin is the centre of the first sample.
        Some(o[0].map(|c| c - 0.5 * h))
    } else if let Some(v) = get("axis mins") {
        let m: Vec<f64> = v.split_whitespace().map(|s| s.parse::<f64>().unwrap_or(f64::NAN)).collect();
        if m.len() != 3 || !m.iter().all(|v| v.is_finite()) {
            return err("axis mins", format!("\"{v}\" is not 3 numbers"));
        }
        // Cell-centred: the min is the first cell's edge; node-centred: its centre.
        let shift = if centers_cell { 0.0 } else { 0.5 * h };
        Some([m[0] - shift, m[1] - shift, m[2] - shift])
    } else {
        None
    };
    if corner.is_some_and(|c| !c.iter().all(|v| v.is_finite())) {
        return err("space origin", "must be finite".into());
    }
    Ok(NrrdHeader { sample, dims, encoding, big_endian, data, byte_skip, voxel_size, corner })
}

/// Parses "(a,b,c) (d,e,f) …" into vectors of 3 numbers.
fn parse_vectors(v: &str) -> Option<Vec<[f64; 3]>> {
    let mut out = Vec::new();
    for part in v.split(')') {
        let part = part.trim();
        if part.is_empty() {
            continue;
        }
        let inner = part.strip_prefix('(')?;
        let c: Vec<f64> = inner.split(',').map(|s| s.trim().parse::<f64>()).collect::<Result<_, _>>().ok()?;
        if c.len() != 3 || !c.iter().all(|x| x.is_finite()) {
            return None;
        }
        out.push([c[0], c[1], c[2]]);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(directions: &str) -> Vec<u8> {
        format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nendian: little\nencoding: raw\n\
             data file: v.raw\nspace directions: {directions}\n"
        )
        .into_bytes()
    }

    #[test]
    fn space_directions_need_one_vector_per_axis() {
        let ok = parse(Path::new("a.nhdr"), &header("(2,0,0) (0,2,0) (0,0,2)")).unwrap();
        assert_eq!(ok.voxel_size, Some(2.0));
        // More vectors than dimensions once indexed past the three edges (a panic).
        for bad in ["(1,0,0) (0,1,0) (0,0,1) (1,0,0)", "(1,0,0) (0,1,0)", ""] {
            let (field, problem) = parse(Path::new("a.nhdr"), &header(bad)).unwrap_err();
            assert_eq!(field, "space directions", "{bad}: {problem}");
            assert!(problem.contains("is not 3 vectors"), "{bad}: {problem}");
        }
    }
}
