//! Per-face exitance maps as files (`faces/<face>.exr`, `.raw` and `.nhdr`): the outgoing power
//! per boundary pixel of one face of the volume, per channel (`solver::exitance` computes them).
//!
//! - `<face>.exr`: one f32 channel per solve channel (`Y` grey, or `R`, `G`, `B`); image x is the
//!   map's u axis, image y its v axis **upwards** (row 0 is the last v), so that a viewer shows
//!   the face with both axes increasing the usual way;
//! - `<face>.raw`: little-endian f32, the channels of a pixel together, then u, then v (v = 0
//!   first), as the fields' raw files are laid out;
//! - `<face>.nhdr`: a detached NRRD header for the raw file, placing the map on its face in the
//!   world (`space directions` along u and v, `space origin` the centre of pixel (0, 0) on the
//!   face's plane), so ParaView or 3D Slicer show it where the light leaves.
//!
//! Every file is written atomically ([`write_atomic`]); the directory is one of the solve's
//! outputs, published with the others as a set.

use super::{write_atomic, OutputError};
use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::Path;

/// One face's map and where it lies.
#[derive(Clone, Debug)]
pub struct FaceMap<'a> {
    /// The face's name as `report.json` gives it (`-x` … `+z`): the files' base name.
    pub name: &'a str,
    /// The face's own axis (0 x, 1 y, 2 z) and side (true: the + side).
    pub axis: usize,
    pub positive: bool,
    /// The volume axes along the map's u and v, and its pixels along them.
    pub axes: [usize; 2],
    pub size: [u32; 2],
    /// Channel names (`Y`, or `R`, `G`, `B`).
    pub channels: &'a [&'a str],
    /// Per pixel `u + n_u·v`, the channels together.
    pub values: Vec<f32>,
}

/// Where the volume lies: its dims, voxel edge and world origin (the corner of voxel (0, 0, 0)).
#[derive(Clone, Copy, Debug)]
pub struct FacePlacement {
    pub dims: [u32; 3],
    pub voxel_size: f64,
    pub origin: [f64; 3],
}

/// Writes `map`'s three files into `dir` (which must exist); returns their names. `units` and
/// `description` go into the NRRD header's comments.
pub fn write_face_map(
    dir: &Path,
    map: &FaceMap,
    place: &FacePlacement,
    units: &str,
    description: &str,
) -> Result<[String; 3], OutputError> {
    let [nu, nv] = map.size.map(|n| n as usize);
    let c = map.channels.len();
    if nu == 0 || nv == 0 || c == 0 || map.values.len() != nu * nv * c {
        return Err(OutputError::Invalid {
            path: dir.join(format!("{}.raw", map.name)),
            message: format!("a {nu}×{nv} map of {c} channel(s) holds {} values", map.values.len()),
        });
    }
    let names = ["exr", "raw", "nhdr"].map(|ext| format!("{}.{ext}", map.name));
    write_exr(&dir.join(&names[0]), map)?;
    write_atomic(&dir.join(&names[1]), |w| {
        for v in &map.values {
            w.write_all(&v.to_le_bytes())?;
        }
        Ok(())
    })?;
    let header = nrrd_header(map, place, &names[1], units, description);
    write_atomic(&dir.join(&names[2]), |w| w.write_all(header.as_bytes()))?;
    Ok(names)
}

fn write_exr(path: &Path, map: &FaceMap) -> Result<(), OutputError> {
    use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec};
    use exr::prelude::{Text, WritableImage};
    let [nu, nv] = map.size.map(|n| n as usize);
    let c = map.channels.len();
    let channels: Vec<AnyChannel<FlatSamples>> = map
        .channels
        .iter()
        .enumerate()
        .map(|(ch, name)| {
            // Image row y holds v = n_v − 1 − y (v upwards).
            let samples = (0..nv).rev().flat_map(|v| (0..nu).map(move |u| map.values[(v * nu + u) * c + ch])).collect();
            AnyChannel::new(*name, FlatSamples::F32(samples))
        })
        .collect();
    let layer = Layer::new(
        (nu, nv),
        LayerAttributes::named(Text::from(map.name)),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let image = Image::from_layer(layer);
    // Written on this thread, in order, so the same map gives the same bytes (as the renderer's).
    write_atomic(path, |out| image.write().non_parallel().to_buffered(out).map_err(io::Error::other))
}

/// The detached NRRD header of `map`'s raw file `data`.
fn nrrd_header(map: &FaceMap, place: &FacePlacement, data: &str, units: &str, description: &str) -> String {
    let h = place.voxel_size;
    let one_line = |t: &str| t.replace(['\n', '\r'], " ");
    // The centre of pixel (0, 0): on the face's plane, half a voxel in along u and v.
    let mut o = place.origin;
    o[map.axis] += if map.positive { place.dims[map.axis] as f64 * h } else { 0.0 };
    for a in map.axes {
        o[a] += 0.5 * h;
    }
    let direction = |a: usize| {
        let mut d = [0.0; 3];
        d[a] = h;
        format!("({},{},{})", d[0], d[1], d[2])
    };
    let directions = format!("{} {}", direction(map.axes[0]), direction(map.axes[1]));
    let [nu, nv] = map.size;
    let mut s = String::from("NRRD0004\n");
    let _ = writeln!(s, "# lpm exitance map of face {}: {}", map.name, one_line(units));
    if !description.is_empty() {
        let _ = writeln!(s, "# {}", one_line(description));
    }
    let _ = writeln!(s, "# components: {}", map.channels.join(" "));
    let _ = writeln!(s, "content: exitance {}", map.name);
    s.push_str("type: float\n");
    super::nrrd::grid_fields(&mut s, map.channels.len(), &[nu as u64, nv as u64], &directions, o, data);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_files_hold_the_map_and_place_it_on_its_face() {
        let dir = tempfile::tempdir().expect("temp dir");
        let map = FaceMap {
            name: "+x",
            axis: 0,
            positive: true,
            axes: [1, 2],
            size: [3, 2],
            channels: &["Y"],
            values: vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
        };
        let place = FacePlacement { dims: [4, 3, 2], voxel_size: 0.5, origin: [1.0, 0.0, 0.0] };
        let names = write_face_map(dir.path(), &map, &place, "W", "test").expect("written");
        assert_eq!(names, ["+x.exr", "+x.raw", "+x.nhdr"]);
        let raw = std::fs::read(dir.path().join("+x.raw")).expect("raw");
        let values: Vec<f32> = raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        assert_eq!(values, map.values);
        let header = std::fs::read_to_string(dir.path().join("+x.nhdr")).expect("nhdr");
        assert!(header.contains("sizes: 3 2\n"), "{header}");
        assert!(header.contains("space origin: (3,0.25,0.25)\n"), "{header}");
        assert!(header.contains("space directions: (0,0.5,0) (0,0,0.5)\n"), "{header}");
        assert!(header.contains("data file: +x.raw\n"), "{header}");
        // The EXR: v upwards, so its first row is v = 1.
        let image = exr::prelude::read_first_flat_layer_from_file(dir.path().join("+x.exr")).expect("exr");
        let samples: Vec<f32> = image.layer_data.channel_data.list[0].sample_data.values_as_f32().collect();
        assert_eq!(samples, [3.0, 4.0, 5.0, 0.0, 1.0, 2.0]);
        let short = FaceMap { values: vec![0.0; 5], ..map };
        assert!(write_face_map(dir.path(), &short, &place, "W", "").is_err());
    }
}
