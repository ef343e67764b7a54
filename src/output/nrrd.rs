//! The detached NRRD header (format 4) describing an exported raw field: its grid placed in the
//! world by `space directions` (the voxel edges along x, y, z) and `space origin` (NRRD's origin is
//! the centre of the first sample: the volume's corner plus half a voxel).

use super::FieldInfo;
use std::fmt::Write;

/// Header text for `info`; the data file is named relative to the header (same directory).
pub(crate) fn header(info: &FieldInfo) -> String {
    let [nx, ny, nz] = info.dims;
    let h = info.voxel_size;
    let o = info.origin.map(|c| c + 0.5 * h);
    let directions = format!("({h},0,0) (0,{h},0) (0,0,{h})");
    let mut s = String::from("NRRD0004\n");
    // NRRD comments and fields are single lines: newlines in free text would break the header.
    let one_line = |t: &str| t.replace(['\n', '\r'], " ");
    let _ = writeln!(s, "# lpm field: {} ({})", one_line(&info.quantity), one_line(&info.units));
    if !info.description.is_empty() {
        let _ = writeln!(s, "# {}", one_line(&info.description));
    }
    let _ = writeln!(s, "# components: {}", one_line(&info.component_names.join(" ")));
    let _ = writeln!(s, "content: {}", one_line(&info.quantity));
    s.push_str("type: float\n");
    grid_fields(&mut s, info.components as usize, &[nx as u64, ny as u64, nz as u64], &directions, o, &info.file);
    s
}

/// The fields after `type` that place a raw grid of `sizes` samples (fastest first) in a 3D
/// world: `components` values per sample (a leading vector axis when more than one), each
/// domain axis's step in `directions`, the first sample's centre at `origin`, the data in
/// `data`. The exported fields and the faces' exitance maps (`super::faces`) share them.
pub(crate) fn grid_fields(
    s: &mut String,
    components: usize,
    sizes: &[u64],
    directions: &str,
    origin: [f64; 3],
    data: &str,
) {
    let each = |word: &str| vec![word; sizes.len()].join(" ");
    let vector = components > 1;
    let dimension = sizes.len() + usize::from(vector);
    let sizes = sizes.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(" ");
    let _ = writeln!(s, "dimension: {dimension}");
    if vector {
        let _ = writeln!(s, "sizes: {components} {sizes}");
    } else {
        let _ = writeln!(s, "sizes: {sizes}");
    }
    s.push_str("space dimension: 3\n");
    let (lead_direction, lead_kind, lead_center) = if vector { ("none ", "vector ", "??? ") } else { ("", "", "") };
    let _ = writeln!(s, "space directions: {lead_direction}{directions}");
    let _ = writeln!(s, "kinds: {lead_kind}{}", each("domain"));
    let _ = writeln!(s, "centers: {lead_center}{}", each("cell"));
    let _ = writeln!(s, "space origin: ({},{},{})", origin[0], origin[1], origin[2]);
    s.push_str("endian: little\n");
    s.push_str("encoding: raw\n");
    let _ = writeln!(s, "data file: {data}");
}
