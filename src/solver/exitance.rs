//! Per-face exitance maps: where on each face of the volume the light leaves, per boundary pixel
//! and channel, summed over directions and orders (`faces/<face>.exr` and `.nhdr`, written by
//! [`crate::job`]).
//!
//! The energy books ([`super::energy`]) split the outgoing power by the six faces only as totals;
//! a picture of where the light leaves (the I3RC step cloud's reflectance per column, a cloud's
//! bright edge) needs the same tallies per pixel. A boundary pixel is one voxel face of the
//! boundary: the map of a face of axis `a` is `n_u × n_v` pixels over the two other axes in
//! increasing order (`-x`/`+x`: y, z; `-y`/`+y`: x, z; `-z`/`+z`: x, y), pixel `(u, v)` at index
//! `u + n_u·v` ([`ExitMaps::axes`]). A pixel holds power (the books' units: the ray power factors
//! applied), so a map's sum is its face's `power_out` in `report.json` to round-off (tested).
//!
//! Each exit the books count is placed where the ray leaves:
//! - **through the far face** (the ray state after a sweep's last plane): at the ray's lateral
//!   position in that plane, split over the two-by-two voxel columns it lies between with the
//!   plane's lattice weights, as the collect step splits its deposit ([`super::sweep`]);
//! - **through a side** (its slot wraps between planes t − 1 and t): at plane t − 1's coordinate
//!   along the sweep axis and the ray's position along the other lateral axis in that plane (the
//!   two columns it lies between, with their weights); across an edge half goes to each side, as
//!   in the books.
//!
//! Along a sweep's axis a side exit lands where the lattice moves its slot out, not where the
//! ray's centre crosses the side (up to ½/|δ| planes earlier for a lateral slope δ): the lattice
//! moves a direction's rays by whole columns at a few planes, so that direction's side exits come
//! in stripes at those planes. Summed over whole sweeps along the side's other axis the maps are
//! as the books; pixel by pixel they show that pattern: the I3RC step cloud (uniform along y,
//! periodic, 4 voxels in y, k = 3) has its top face's map vary by up to 22 % along y, most of it
//! from the periodic y sweeps, whose rays leave through the top in the step between two periods
//! (all placed at the last plane). Placing each exit at its crossing plane instead (a search back
//! along the offsets from the wrap) is the refinement to make if such pictures matter. It would
//! also make a mirror-symmetric scene's maps mirror-symmetric pixel by pixel whatever the
//! directions: where a direction's rays sit on whole columns (w = 0, as the slope-0 direction of
//! an odd k always does), its mirror image's slots wrap one plane later, so with k = 3 a ball
//! under a sky has its `-x` and `+x` maps equal in sum but ~15 % apart at a rim pixel (and 1 %
//! between mirror pixels of one face); with k = 2 (no such direction) they agree to round-off.
//!
//! The lattice holds one ray more than the voxels per open lateral axis: its column n (≡ −1, the
//! lattice wraps with period n + 1) is the vacuum beside the volume. The books count a ray whole
//! where it leaves, its weight on that column included (it meets only vacuum), so here that
//! weight goes half to each rim pixel it borders (0 and n − 1): the maps add up to the books,
//! and a scene symmetric under a mirror gives mirror-symmetric maps (the vacuum column of a
//! direction whose rays sit on whole columns lies on the − side of the lattice; put on the pixel
//! beside it, it made the maps lopsided). On a sky-lit face the rims therefore carry up to one
//! extra ray's power per row: the discretisation's, not the medium's.
//!
//! Periodic faces hold what the books count through them: the rays of the directions swept
//! along the periodic axis leaving through its far face (which the next order carries in through
//! the opposite face), and the rays of the other directions that leave through an open side in
//! the step between two periods ([`super::periodic::PeriodStep`]). Rays of a direction that
//! crosses a periodic face sideways wrap and go on, uncounted by the books (they never leave),
//! so they are not in the maps either. Mirror faces hold what the books count through them:
//! every ray that reaches the mirror, at the point it reaches it (what the mirror hands back
//! comes in through the same face and is counted in by the books, not here).
//!
//! The twin ([`super::cpu`]) fills the maps during its sweeps, bitwise the same at any thread
//! count: the rays of a row of slots record their side exits in that row's list, and the lists
//! are added in row order after the sweep, then the far face's exits in slot order. The GPU
//! backend's kernels record each side exit where it happens and the host places them, and the far
//! face's, with the same `record_exit` ([`super::gpu::face_maps`]); it makes none for mirror
//! faces (solved as the doubled volume), so no `faces/` is written then. A checkpoint keeps the
//! maps of the orders it holds (`exits_<orders>.f64`, [`ExitMaps::to_bytes`]), so a resumed solve
//! adds on to them and writes the same maps as an uninterrupted one, bit for bit; only a resume
//! from a checkpoint without maps (written under a budget too small for their records) writes
//! none.

use super::energy::VOLUME_FACES;
use super::sweep::FaceSweep;
use crate::output::{write_face_map, FaceMap, FacePlacement, OutputError};
use std::path::Path;

/// The directory of the maps' files in a solve's outputs.
pub const FACES_DIR: &str = "faces";

/// Outgoing power per boundary pixel and channel of the six faces ([`VOLUME_FACES`] order).
#[derive(Clone, Debug, PartialEq)]
pub struct ExitMaps {
    dims: [u32; 3],
    channels: usize,
    /// Per face: pixel `u + n_u·v`, then channel (`channels` values a pixel: a grey solve's
    /// maps are a third of a colour one's).
    maps: [Vec<f64>; 6],
}

/// One exit placed on a face: the voxel whose boundary face it crosses (its coordinate along the
/// face's axis is ignored) and the radiance it carries there, already multiplied by its share.
#[derive(Clone, Copy, Debug)]
pub(super) struct ExitEntry {
    face: u8,
    voxel: [u32; 3],
    radiance: [f64; 3],
}

/// Where a ray leaves in [`record_exit`]: through the far face, or a side of lateral axis k.
#[derive(Clone, Copy, Debug)]
pub(super) enum Exit {
    Far,
    Side(usize),
}

impl ExitMaps {
    /// Empty maps for a volume of `dims` solved with `channels` channels.
    pub fn new(dims: [u32; 3], channels: usize) -> Self {
        let maps = std::array::from_fn(|f| {
            let [u, v] = Self::axes(f);
            vec![0.0; dims[u] as usize * dims[v] as usize * channels]
        });
        ExitMaps { dims, channels, maps }
    }

    /// The volume axes (u, v) of face `face`'s map: the two other than its own, in increasing
    /// order; u runs fastest.
    pub const fn axes(face: usize) -> [usize; 2] {
        match face / 2 {
            0 => [1, 2],
            1 => [0, 2],
            _ => [0, 1],
        }
    }

    /// Pixels of face `face`'s map along (u, v).
    pub fn size(&self, face: usize) -> [u32; 2] {
        Self::axes(face).map(|a| self.dims[a])
    }

    /// Channels of the solve (1 grey, or 3).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// The name of face `face` as `report.json` gives it (`-x` … `+z`).
    pub fn name(face: usize) -> &'static str {
        VOLUME_FACES[face]
    }

    /// Face `face`'s map: per pixel `u + n_u·v`, the outgoing power of each of the
    /// [`ExitMaps::channels`] channels (`map[pixel·channels + ch]`).
    pub fn map(&self, face: usize) -> &[f64] {
        &self.maps[face]
    }

    /// The outgoing power of pixel `pixel` of face `face`, per channel (0 past the channels solved).
    pub fn pixel(&self, face: usize, pixel: usize) -> [f64; 3] {
        let c = self.channels;
        std::array::from_fn(|ch| if ch < c { self.maps[face][pixel * c + ch] } else { 0.0 })
    }

    /// Face `face`'s pixels in order, each's power per channel (0 past the channels solved).
    pub fn pixels(&self, face: usize) -> impl Iterator<Item = [f64; 3]> + '_ {
        (0..self.maps[face].len() / self.channels.max(1)).map(move |p| self.pixel(face, p))
    }

    /// The sum of face `face`'s map, per channel (0 past the channels solved), in pixel order.
    pub fn total(&self, face: usize) -> [f64; 3] {
        let mut sum = [0.0; 3];
        for p in self.maps[face].chunks_exact(self.channels.max(1)) {
            for (s, v) in sum.iter_mut().zip(p) {
                *s += v;
            }
        }
        sum
    }

    /// Writes every face's map into `dir` (created) as `<face>.exr`, `.raw` and `.nhdr`
    /// ([`crate::output::write_face_map`]), the volume's voxel (0, 0, 0) having its corner at
    /// `origin`, voxels of edge `voxel_size`.
    pub fn write(&self, dir: &Path, origin: [f64; 3], voxel_size: f64) -> Result<(), OutputError> {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::Io {
            path: dir.to_path_buf(),
            action: "create the directory",
            source,
        })?;
        let channels: &[&str] = if self.channels == 1 { &["Y"] } else { &["R", "G", "B"] };
        let place = FacePlacement { dims: self.dims, voxel_size, origin };
        for face in 0..6 {
            let map = FaceMap {
                name: Self::name(face),
                axis: face / 2,
                positive: face % 2 == 1,
                axes: Self::axes(face),
                size: self.size(face),
                channels,
                values: self.maps[face].iter().map(|&v| v as f32).collect(),
            };
            // A face of zero pixels cannot occur: the volume's dims are at least 1.
            write_face_map(
                dir,
                &map,
                &place,
                "power per boundary pixel (the energy books' units: W for radiance in W/m²/sr and lengths in m)",
                "outgoing power through each voxel face of this face of the volume, summed over directions and \
                 scattering orders; the map sums to report.json's energy.faces power_out",
            )?;
        }
        Ok(())
    }

    /// The maps as bytes for a checkpoint ([`super::fields`]): every face's pixels in order, each
    /// pixel's [`ExitMaps::channels`] values as f64 little-endian (the exact sums, so a resumed
    /// solve adds on to the same bits as an uninterrupted one): the maps' own layout.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(self.maps.iter().map(|m| m.len() * 8).sum());
        for v in self.maps.iter().flatten() {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes
    }

    /// Reads [`ExitMaps::to_bytes`] back for a volume of `dims` with `channels` channels; `None`
    /// when the bytes are not that size (another volume's maps, or a damaged file).
    pub fn from_bytes(dims: [u32; 3], channels: usize, bytes: &[u8]) -> Option<Self> {
        if channels == 0 || channels > 3 {
            return None;
        }
        let mut maps = Self::new(dims, channels);
        if bytes.len() != maps.maps.iter().map(|m| m.len() * 8).sum::<usize>() {
            return None;
        }
        for (v, x) in maps.maps.iter_mut().flatten().zip(bytes.chunks_exact(8)) {
            *v = f64::from_le_bytes(x.try_into().unwrap_or([0; 8]));
        }
        Some(maps)
    }

    /// Adds `entries` in order, each radiance times `power` (the sweep's power per radiance).
    pub(super) fn add(&mut self, entries: &[ExitEntry], power: f64) {
        for e in entries {
            let face = e.face as usize;
            let [u, v] = Self::axes(face);
            let pixel = e.voxel[u] as usize + self.dims[u] as usize * e.voxel[v] as usize;
            let c = self.channels;
            for (ch, cell) in self.maps[face][pixel * c..][..c].iter_mut().enumerate() {
                *cell += e.radiance[ch] * power;
            }
        }
    }
}

/// The voxel columns of one lateral axis (of `n`, `periodic` or not) a ray at lattice column `l`
/// with weight `w` is placed on: column ℓ − 1 with 1 − w and column ℓ with w (as the collect step
/// splits it, [`FaceSweep::taps`]); on a periodic axis column −1 is column n − 1; on an open axis
/// the weight on the vacuum column (−1 or n: the same column of the lattice, which wraps with
/// period n + 1) goes half to each rim pixel, 0 and n − 1 (module docs). Entries of weight 0 may
/// be among the four.
fn pixel_taps(l: u32, w: f64, n: u32, periodic: bool) -> [(u32, f64); 4] {
    let mut out = [(0, 0.0); 4];
    for (i, (column, weight)) in [(l as i64 - 1, 1.0 - w), (l as i64, w)].into_iter().enumerate() {
        if periodic {
            out[2 * i] = (column.rem_euclid(n as i64) as u32, weight);
        } else if (0..n as i64).contains(&column) {
            out[2 * i] = (column as u32, weight);
        } else {
            out[2 * i] = (0, 0.5 * weight);
            out[2 * i + 1] = (n - 1, 0.5 * weight);
        }
    }
    out
}

/// Records in `out` a ray of `sweep` still inside after its last plane `last` (lattice `columns`
/// and `weights` there), carrying `l` out: through the far face `far_face`, less the shares that
/// `sides` (a periodic sweep axis's [`super::periodic::PeriodStep::side_exits`] for the ray; none
/// otherwise) say leave by a side in the step into the next period, which are placed on those
/// sides. One placement for both backends (the twin's sweep, [`super::gpu::face_maps`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn record_far_exit(
    out: &mut Vec<ExitEntry>,
    sweep: &FaceSweep,
    far_face: usize,
    sides: [Option<(usize, f64)>; 2],
    columns: [u32; 2],
    weights: [f64; 2],
    last: u32,
    l: [f64; 3],
) {
    let mut far_share = 1.0;
    for (k, side) in sides.into_iter().enumerate() {
        if let Some((face, share)) = side {
            record_exit(out, sweep, face, Exit::Side(k), columns, weights, last, share, l);
            far_share -= share;
        }
    }
    record_exit(out, sweep, far_face, Exit::Far, columns, weights, last, far_share, l);
}

/// Records in `out` the exit of a ray of `sweep` carrying `l` (times `share`) through `face`:
/// `exit` says which way it left, `columns` and `weights` are its lattice columns (b, c) and the
/// lattice weights in plane `t`, the last plane it crossed.
#[allow(clippy::too_many_arguments)]
pub(super) fn record_exit(
    out: &mut Vec<ExitEntry>,
    sweep: &FaceSweep,
    face: usize,
    exit: Exit,
    columns: [u32; 2],
    weights: [f64; 2],
    t: u32,
    share: f64,
    l: [f64; 3],
) {
    let f = sweep.geometry();
    let taps = |k: usize| pixel_taps(columns[k], weights[k], sweep.n[1 + k], sweep.periodic[1 + k]);
    let mut push = |voxel: [u32; 3], wt: f64| {
        if wt != 0.0 {
            let s = share * wt;
            out.push(ExitEntry { face: face as u8, voxel, radiance: l.map(|v| v * s) });
        }
    };
    match exit {
        Exit::Far => {
            for (vc, wc) in taps(1) {
                for (vb, wb) in taps(0) {
                    let mut v = [0; 3];
                    v[f.lateral[0]] = vb;
                    v[f.lateral[1]] = vc;
                    push(v, wb * wc);
                }
            }
        }
        Exit::Side(k) => {
            let other = 1 - k;
            for (col, wt) in taps(other) {
                let mut v = [0; 3];
                v[f.axis] = sweep.plane_coordinate(t);
                v[f.lateral[other]] = col;
                push(v, wt);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taps_clamp_on_open_axes_and_wrap_on_periodic_ones() {
        assert_eq!(pixel_taps(0, 0.25, 4, false), [(0, 0.375), (3, 0.375), (0, 0.25), (0, 0.0)]);
        assert_eq!(pixel_taps(4, 0.25, 4, false), [(3, 0.75), (0, 0.0), (0, 0.125), (3, 0.125)]);
        assert_eq!(pixel_taps(2, 0.25, 4, false), [(1, 0.75), (0, 0.0), (2, 0.25), (0, 0.0)]);
        assert_eq!(pixel_taps(0, 0.25, 4, true), [(3, 0.75), (0, 0.0), (0, 0.25), (0, 0.0)]);
    }

    #[test]
    fn maps_read_back_from_their_bytes_exactly_and_refuse_another_volume() {
        let sweep = FaceSweep::new(4, [4, 3, 5]);
        let mut out = Vec::new();
        record_exit(&mut out, &sweep, 5, Exit::Far, [2, 1], [0.3, 0.7], 4, 1.0, [8.0, 1.0 / 3.0, 0.1]);
        let mut maps = ExitMaps::new([4, 3, 5], 3);
        maps.add(&out, 0.7);
        let bytes = maps.to_bytes();
        let back = ExitMaps::from_bytes([4, 3, 5], 3, &bytes).expect("the same volume");
        for face in 0..6 {
            assert_eq!(back.map(face), maps.map(face), "face {face}");
        }
        assert!(maps.total(5)[1] > 0.0);
        assert!(ExitMaps::from_bytes([4, 3, 6], 3, &bytes).is_none(), "another volume's maps");
        assert!(ExitMaps::from_bytes([4, 3, 5], 3, &bytes[..bytes.len() - 8]).is_none(), "a truncated file");
        // A grey solve's maps keep their one channel only.
        let mut grey = ExitMaps::new([4, 3, 5], 1);
        grey.add(&out, 0.7);
        let bytes = grey.to_bytes();
        assert_eq!(bytes.len(), 8 * (2 * 3 * 5 + 2 * 4 * 5 + 2 * 4 * 3));
        let back = ExitMaps::from_bytes([4, 3, 5], 1, &bytes).expect("the same volume");
        assert_eq!(back.map(5), grey.map(5));
        assert!(ExitMaps::from_bytes([4, 3, 5], 3, &bytes).is_none(), "another channel count");
    }

    #[test]
    fn a_far_exit_lands_on_the_far_face_split_by_the_lattice_weights() {
        // Sweep +z through 4 × 3 × 5: laterals x, y; the +z map is 4 × 3 over (x, y).
        let sweep = FaceSweep::new(4, [4, 3, 5]);
        let mut out = Vec::new();
        record_exit(&mut out, &sweep, 5, Exit::Far, [2, 1], [0.5, 0.0], 4, 1.0, [8.0, 0.0, 0.0]);
        let mut maps = ExitMaps::new([4, 3, 5], 1);
        maps.add(&out, 0.5);
        assert_eq!(maps.size(5), [4, 3]);
        // Column 2 of x lies between voxels 1 and 2 (weights ½, ½); column 1 of y at weight 0: voxel 0.
        assert_eq!(maps.pixel(5, 1)[0], 2.0);
        assert_eq!(maps.pixel(5, 2)[0], 2.0);
        assert_eq!(maps.total(5)[0], 4.0);
        // A side exit through +x at plane 3 (z = 3 on a +z sweep), y column 3 of 3: half on
        // voxel 2, half on the vacuum column, which borders both rims (y = 0 and y = 2).
        let mut out = Vec::new();
        record_exit(&mut out, &sweep, 1, Exit::Side(0), [4, 3], [0.0, 0.5], 3, 0.5, [2.0, 0.0, 0.0]);
        let mut maps = ExitMaps::new([4, 3, 5], 1);
        maps.add(&out, 1.0);
        // The +x map is over (y, z): 3 × 5; pixels (y = 2, z = 3) and (y = 0, z = 3).
        assert_eq!(maps.size(1), [3, 5]);
        assert_eq!(maps.pixel(1, 2 + 3 * 3)[0], 0.75);
        assert_eq!(maps.pixel(1, 3 * 3)[0], 0.25);
        assert_eq!(maps.total(1)[0], 1.0);
    }
}
