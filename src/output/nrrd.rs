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
    if info.components == 1 {
        s.push_str("dimension: 3\n");
        let _ = writeln!(s, "sizes: {nx} {ny} {nz}");
        s.push_str("space dimension: 3\n");
        let _ = writeln!(s, "space directions: {directions}");
        s.push_str("kinds: domain domain domain\n");
        s.push_str("centers: cell cell cell\n");
    } else {
        s.push_str("dimension: 4\n");
        let _ = writeln!(s, "sizes: {} {nx} {ny} {nz}", info.components);
        s.push_str("space dimension: 3\n");
        let _ = writeln!(s, "space directions: none {directions}");
        s.push_str("kinds: vector domain domain domain\n");
        s.push_str("centers: ??? cell cell cell\n");
    }
    let _ = writeln!(s, "space origin: ({},{},{})", o[0], o[1], o[2]);
    s.push_str("endian: little\n");
    s.push_str("encoding: raw\n");
    let _ = writeln!(s, "data file: {}", info.file);
    s
}
