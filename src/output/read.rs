//! Reading exported fields back (for `lpm info`, comparisons and tests).

use super::export::{FieldInfo, LAYOUT};
use super::OutputError;
use std::fs;
use std::path::Path;

/// Reads and checks `<base>.json`: known dtype, endianness and layout, consistent components.
pub fn read_field_json(path: &Path) -> Result<FieldInfo, OutputError> {
    let bytes =
        fs::read(path).map_err(|source| OutputError::Io { path: path.to_path_buf(), action: "read", source })?;
    let info: FieldInfo =
        serde_json::from_slice(&bytes).map_err(|source| OutputError::Json { path: path.to_path_buf(), source })?;
    let invalid = |message: String| OutputError::Invalid { path: path.to_path_buf(), message };
    if info.dtype != "f32" || info.endianness != "little" || info.layout != LAYOUT {
        return Err(invalid(format!(
            "unsupported dtype {:?} / endianness {:?} / layout {:?} (expected \"f32\", \"little\", {LAYOUT:?})",
            info.dtype, info.endianness, info.layout
        )));
    }
    if info.components == 0 || info.component_names.len() != info.components as usize {
        return Err(invalid(format!(
            "{} components but {} component names",
            info.components,
            info.component_names.len()
        )));
    }
    if info.file.is_empty() || info.file.contains(['/', '\\']) {
        return Err(invalid(format!("data file {:?} must be a plain file name beside the json", info.file)));
    }
    Ok(info)
}

/// Reads `<dir>/<base>.json` and the raw file it names, checking the raw's size against it.
/// Loads the whole field: meant for volumes that fit in memory.
pub fn read_raw_field(dir: &Path, base: &str) -> Result<(FieldInfo, Vec<f32>), OutputError> {
    let info = read_field_json(&dir.join(format!("{base}.json")))?;
    let raw_path = dir.join(&info.file);
    let bytes =
        fs::read(&raw_path).map_err(|source| OutputError::Io { path: raw_path.clone(), action: "read", source })?;
    let expected = info.dims.iter().try_fold(info.components as u64 * 4, |acc, &d| acc.checked_mul(d as u64));
    if expected != Some(bytes.len() as u64) {
        return Err(OutputError::Invalid {
            path: raw_path,
            message: format!(
                "{} bytes, but {} component(s) over {:?} voxels need {} bytes",
                bytes.len(),
                info.components,
                info.dims,
                expected.map_or("more than 2^64".to_string(), |e| e.to_string())
            ),
        });
    }
    let values = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok((info, values))
}
