//! Reading exported fields back (for `lpm info`, comparisons and tests).

use super::export::{FieldInfo, LAYOUT};
use super::OutputError;
use std::path::Path;

/// Reads and checks `<base>.json`: known dtype, endianness and layout, consistent components.
pub fn read_field_json(path: &Path) -> Result<FieldInfo, OutputError> {
    let bytes = crate::input::read_capped(path, crate::input::MAX_TEXT_BYTES, "a field description")?;
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
    let expected = info.dims.iter().try_fold(info.components as u64 * 4, |acc, &d| acc.checked_mul(d as u64));
    // Through the input checks (a FIFO or a device is refused before it is opened); the size is
    // checked before anything is read, and no more than it is read.
    let file = crate::input::open(&raw_path)?;
    let io = |action: &'static str| {
        let path = raw_path.clone();
        move |source| OutputError::Io { path, action, source }
    };
    let size = file.metadata().map_err(io("look at"))?.len();
    let wrong_size = |actual: u64| OutputError::Invalid {
        path: raw_path.clone(),
        message: format!(
            "{actual} bytes, but {} component(s) over {:?} voxels need {} bytes",
            info.components,
            info.dims,
            expected.map_or("more than 2^64".to_string(), |e| e.to_string())
        ),
    };
    let Some(expected) = expected.filter(|&e| e == size) else { return Err(wrong_size(size)) };
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut std::io::Read::take(file, expected), &mut bytes).map_err(io("read"))?;
    if bytes.len() as u64 != expected {
        return Err(wrong_size(bytes.len() as u64));
    }
    let values = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok((info, values))
}
