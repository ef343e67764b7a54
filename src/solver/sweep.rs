//! Sweep geometry shared by the CPU twin and the GPU driver.
//!
//! A face sweep marches the ray map of one cube face through the volume plane by plane along the
//! face's axis `a` (plane t = 0 is the entry plane). All rays of a direction move together: with
//! lateral slope δ = (ω_b, ω_c)/|ω_a|, every ray is displaced by D(t) = δ·(t + ½) voxels at the
//! middle of plane t. Per lateral axis of n voxels the map holds **n + 1 rays** (slots), spaced one
//! voxel apart on a lattice that wraps with period n + 1: lattice column ℓ ∈ [0, n] lies between
//! the centres of voxel columns ℓ − 1 and ℓ (column −1 and n are outside: vacuum). Per plane a
//! direction has one integer offset o(t) and one fractional weight w(t) ([`lattice`]), shared by
//! all its rays: slot s sits at lattice column ℓ = (s + o + 1) mod (n + 1) ([`lattice_column`]) and
//! meets voxel column ℓ − 1 with weight 1 − w and column ℓ with weight w (bilinear in the plane).
//!
//! - `solver.spatial = "linear"`: o = ⌊D⌋, w = D − o: the ray's exact position. It gathers the
//!   medium and the source with these weights and deposits its segment average once; the collect
//!   step pulls each voxel's share from the two-by-two lattice columns around it with the same
//!   weights. Each voxel's weights sum to 1 and each ray's lost power goes exactly to the voxels it
//!   gathered from (columns outside the volume hold vacuum), so energy is exact. A ray leaving
//!   through a side drifts out continuously (its weight inside falls to 0) before its slot wraps
//!   and re-enters on the other side with weight rising from 0: light entering through a side
//!   starts where it really crosses it, not a whole plane away.
//! - `solver.spatial = "constant"`: o = ⌊½ + D⌋ − 1, w = 1: the one voxel under the ray's
//!   mid-plane position (nearest column), as the first-order scheme does. The slot outside the
//!   volume (ℓ = n) carries its radiance unchanged, so the fluence is the nearest-column scheme's.
//!
//! In every plane the slots of one direction occupy distinct lattice columns, so one GPU thread per
//! ray writes its own deposit cell: no atomics, bitwise reproducible. A slot whose lattice column
//! wraps is a ray that left; a new one enters in its place.
//!
//! The offsets and weights are computed once on the host in f64 and handed to both backends as
//! tables, so the CPU twin and the GPU walk exactly the same lattice (a float `floor` on the GPU
//! could land on the other side of a tie).
//!
//! Energy bookkeeping: a ray carries radiance for a tube of cross-section h²·|ω_a| (one voxel face
//! projected) and solid angle Ω_i, so its power is L·h²·|ω_a|·Ω_i; the sweeps tally the radiance of
//! rays at birth and at exit and the solver turns those tallies into boundary power in and out
//! (rays within half a voxel of a side count whole: their weight outside meets only vacuum).
//! Which face of the volume a ray crosses is [`FaceRoles`]: born on the near face at plane 0,
//! leaving through the far face after the last plane, or through a lateral side when its slot
//! wraps (the + side when the column passes n, the − side below 0; offsets are monotonic in t,
//! so every ray of a direction wraps the same way) while the ray born in its slot enters through
//! the opposite side. A slot wrapping in both lateral axes in one plane is a ray crossing an edge:
//! its power counts half to each side. The births per side depend on the offsets alone
//! ([`side_births`]), so the GPU tallies only what rays carry out.

use crate::quadrature::{Face, FACES};
use crate::scene::SpatialScheme;
use glam::DVec3;

/// Dimensions of the volume seen from one face: planes along the axis and the lateral sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaceSweep {
    pub face: usize,
    /// (N_a, N_b, N_c): voxels along the sweep axis and the two lateral axes.
    pub n: [u32; 3],
    /// Whether the sweep axis and the two lateral axes (a, b, c) are periodic
    /// ([`super::periodic`]): a periodic lateral axis has n slots of period n, and its rays wrap
    /// without leaving.
    pub periodic: [bool; 3],
    /// Per axis (a, b, c): whether the volume's low and high faces across it are mirrors
    /// ([`super::mirror`]).
    pub mirror: [[bool; 2]; 3],
}

/// The planes of one slice (or sub-slice) of bricks, in sweep order: t0..t1, the brick coordinate
/// along the axis, and the slab of the bricks' local planes it covers.
///
/// A whole slice covers all 16 local planes of its bricks (`slab_lo = 0`, `slab_planes = 16`, even
/// where the volume ends inside the bricks). A sub-slice covers local planes
/// `slab_lo .. slab_lo + slab_planes` along the axis (in increasing coordinate, whatever the sweep's
/// sense) and only the real planes among them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceRange {
    pub brick_a: u32,
    pub t0: u32,
    pub t1: u32,
    pub slab_lo: u32,
    pub slab_planes: u32,
}

impl FaceSweep {
    /// The sweep of `face` through a volume of `dims` whose faces are all open.
    pub fn new(face: usize, dims: [u32; 3]) -> Self {
        Self::with_periodic(face, dims, [false; 3])
    }

    /// The sweep of `face` through a volume of `dims` periodic along the axes (x, y, z) marked
    /// in `periodic`.
    pub fn with_periodic(face: usize, dims: [u32; 3], periodic: [bool; 3]) -> Self {
        Self::with_boundary(face, dims, periodic, [[false; 2]; 3])
    }

    /// The sweep of `face` through a volume of `dims` with periodic axes and mirror faces (per
    /// axis x, y, z: low, high).
    pub fn with_boundary(face: usize, dims: [u32; 3], periodic: [bool; 3], mirror: [[bool; 2]; 3]) -> Self {
        let f = FACES[face];
        let abc = [f.axis, f.lateral[0], f.lateral[1]];
        FaceSweep { face, n: abc.map(|x| dims[x]), periodic: abc.map(|x| periodic[x]), mirror: abc.map(|x| mirror[x]) }
    }

    /// The sweep of `face` through the plan's volume and boundaries.
    pub fn for_plan(face: usize, plan: &crate::solver::plan::Plan) -> Self {
        Self::with_boundary(face, plan.dims, plan.periodic, plan.reflective)
    }

    pub fn geometry(&self) -> Face {
        FACES[self.face]
    }

    /// Rays (slots) of the map per lateral axis: one more than the voxels (as many on a periodic
    /// axis).
    pub fn lattice(&self) -> [u32; 2] {
        [1, 2].map(|k| self.n[k] + !self.periodic[k] as u32)
    }

    /// Number of rays in the map, one per lattice column pair: (n_b + 1)·(n_c + 1) when open.
    pub fn rays(&self) -> usize {
        let [lb, lc] = self.lattice();
        lb as usize * lc as usize
    }

    /// Where slot `s` of lateral axis `k` (0: b, 1: c) lies with offset `o`: (lattice column,
    /// wrap count) on the axis's lattice ([`lattice_column`] when open).
    #[inline]
    pub fn column(&self, k: usize, s: u32, o: i32) -> (u32, i32) {
        wrapped_column(s, o, self.lattice()[k])
    }

    /// The voxel columns of lateral axis `k` a ray at lattice column `l` meets with weight `w`
    /// (column ℓ − 1 with 1 − w and column ℓ with w, leaving out those outside the volume and those
    /// of weight 0; on a periodic axis column −1 is column n − 1).
    #[inline]
    pub fn taps(&self, k: usize, l: u32, w: f64) -> impl Iterator<Item = (u32, f64)> {
        let (n, periodic) = (self.n[1 + k], self.periodic[1 + k]);
        let below = if periodic && l == 0 { n as i64 - 1 } else { l as i64 - 1 };
        [(below, 1.0 - w), (l as i64, w)]
            .into_iter()
            .filter(move |&(c, wt)| wt != 0.0 && c >= 0 && c < n as i64)
            .map(|(c, wt)| (c as u32, wt))
    }

    /// The coordinate along the axis of plane t.
    pub fn plane_coordinate(&self, t: u32) -> u32 {
        if self.geometry().sign > 0.0 {
            t
        } else {
            self.n[0] - 1 - t
        }
    }

    /// Volume coordinates (x, y, z) of the voxel in plane t at lateral column (vb, vc).
    pub fn voxel(&self, t: u32, vb: u32, vc: u32) -> [u32; 3] {
        let f = self.geometry();
        let mut v = [0; 3];
        v[f.axis] = self.plane_coordinate(t);
        v[f.lateral[0]] = vb;
        v[f.lateral[1]] = vc;
        v
    }

    /// The slices of bricks in sweep order, each cut into sub-slices of `slab` planes (`slab`
    /// divides `edge`; `slab == edge`: whole slices of 16 planes, fewer at the volume's far end).
    pub fn slices(&self, edge: u32, slab: u32) -> Vec<SliceRange> {
        let na = self.n[0] as i64;
        let (e, p) = (edge as i64, slab.clamp(1, edge) as i64);
        let positive = self.geometry().sign > 0.0;
        let bricks = (na + e - 1) / e;
        let mut out = Vec::new();
        for l in 0..bricks {
            let ba = if positive { l } else { bricks - 1 - l };
            // Local planes of the brick inside the volume: 0..real.
            let real = (na - ba * e).min(e);
            let slabs: Vec<i64> = (0..e / p).map(|k| k * p).filter(|&lo| lo < real).collect();
            let ordered: Box<dyn Iterator<Item = i64>> =
                if positive { Box::new(slabs.into_iter()) } else { Box::new(slabs.into_iter().rev()) };
            for lo in ordered {
                let hi = (lo + p).min(real);
                // Coordinate along the axis c = ba·e + local; t = c (positive) or na − 1 − c.
                let (t0, t1) = if positive { (ba * e + lo, ba * e + hi) } else { (na - ba * e - hi, na - ba * e - lo) };
                out.push(SliceRange {
                    brick_a: ba as u32,
                    t0: t0 as u32,
                    t1: t1 as u32,
                    slab_lo: lo as u32,
                    slab_planes: p as u32,
                });
            }
        }
        out
    }
}

/// The faces of the volume ([`crate::solver::energy::VOLUME_FACES`] indices) one direction's rays
/// cross.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaceRoles {
    /// Every ray is born here at plane 0.
    pub near: usize,
    /// The rays still inside after the last plane leave here.
    pub far: usize,
    /// Per lateral axis (b, c): the side a ray leaves through when its slot wraps and the side the
    /// ray born in its place enters through; `None` where the rays never wrap along that axis.
    pub sides: [Option<(usize, usize)>; 2],
}

impl FaceSweep {
    /// The faces crossed by the rays of a direction with per-plane lattice `offsets`.
    pub fn face_roles(&self, offsets: &[[i32; 2]]) -> FaceRoles {
        use crate::solver::energy::volume_face;
        let f = self.geometry();
        let forward = f.sign > 0.0;
        let mut sides = [None; 2];
        if let (Some(first), Some(last)) = (offsets.first(), offsets.last()) {
            // A periodic lateral axis has no side a ray leaves through.
            for k in (0..2).filter(|&k| !self.periodic[1 + k]) {
                let moved = last[k] - first[k];
                if moved != 0 {
                    let exit = volume_face(f.lateral[k], moved > 0);
                    sides[k] = Some((exit, volume_face(f.lateral[k], moved < 0)));
                }
            }
        }
        FaceRoles { near: volume_face(f.axis, !forward), far: volume_face(f.axis, forward), sides }
    }
}

/// Per lateral axis (b, c), the rays born through that side over a whole sweep with per-plane
/// lattice `offsets` on a lattice of `lattice` slots per axis: when the offset moves by one column
/// along b, one slot per row of the lattice wraps (and likewise along c); a slot wrapping along
/// both counts half to each (module docs). The rays born at plane 0 are not included. A
/// `periodic` lateral axis has no side (its rays wrap and go on): none are born there, and a slot
/// wrapping along it and an open axis at once is a plain birth on the open side.
pub fn side_births(offsets: &[[i32; 2]], lattice: [u32; 2], periodic: [bool; 2]) -> [f64; 2] {
    let [lb, lc] = lattice.map(f64::from);
    let mut births = [0.0; 2];
    for w in offsets.windows(2) {
        let (db, dc) = ((w[1][0] - w[0][0]).abs(), (w[1][1] - w[0][1]).abs());
        debug_assert!(db <= 1 && dc <= 1, "offsets move by at most one column per plane");
        let (db, dc) = (db as f64 * !periodic[0] as u8 as f64, dc as f64 * !periodic[1] as u8 as f64);
        let both = db * dc;
        births[0] += db * lc - 0.5 * both;
        births[1] += dc * lb - 0.5 * both;
    }
    births
}

/// Lateral slope (δ_b, δ_c) of a direction of travel on its face: the lateral distance covered per
/// plane, in voxels (|δ| ≤ 1).
pub fn lateral_slope(face: usize, omega: DVec3) -> [f64; 2] {
    let f = FACES[face];
    let w = omega.to_array();
    let a = w[f.axis].abs();
    [w[f.lateral[0]] / a, w[f.lateral[1]] / a]
}

/// Path length through one plane of voxels of edge h: h/|ω_a|.
pub fn plane_path_length(face: usize, omega: DVec3, h: f64) -> f64 {
    h / omega.to_array()[FACES[face].axis].abs()
}

/// Per plane t in 0..planes, the lattice offsets o(t) and weights w(t) of a direction with lateral
/// slope `slope` (module docs): exact positions under [`SpatialScheme::Linear`], the nearest column
/// under [`SpatialScheme::Constant`].
pub fn lattice(slope: [f64; 2], planes: u32, scheme: SpatialScheme) -> (Vec<[i32; 2]>, Vec<[f64; 2]>) {
    let mut offsets = Vec::with_capacity(planes as usize);
    let mut weights = Vec::with_capacity(planes as usize);
    for t in 0..planes {
        let m = t as f64 + 0.5;
        let mut o = [0; 2];
        let mut w = [0.0; 2];
        for k in 0..2 {
            let d = slope[k] * m;
            match scheme {
                SpatialScheme::Linear => {
                    let f = d.floor();
                    o[k] = f as i32;
                    w[k] = d - f;
                }
                SpatialScheme::Constant => {
                    o[k] = nearest_column(d) - 1;
                    w[k] = 1.0;
                }
            }
        }
        offsets.push(o);
        weights.push(w);
    }
    (offsets, weights)
}

/// The nearest whole column to a lateral displacement `d`, halves rounded away from zero, so that
/// a direction and its mirror image (−d) take mirror-image columns in every plane
/// ([`super::mirror`]); for d > 0 this is ⌊½ + d⌋.
pub fn nearest_column(d: f64) -> i32 {
    (d.abs() + 0.5).floor().copysign(d) as i32
}

/// Where slot `s` (of `n + 1`) lies with offset `o`: (lattice column in 0..=n, wrap count).
#[inline]
pub fn lattice_column(s: u32, o: i32, n: u32) -> (u32, i32) {
    wrapped_column(s, o, n + 1)
}

/// Where slot `s` lies with offset `o` on a lattice of `period` slots: (column, wrap count).
#[inline]
fn wrapped_column(s: u32, o: i32, period: u32) -> (u32, i32) {
    let unwrapped = s as i64 + o as i64 + 1;
    let period = period as i64;
    (unwrapped.rem_euclid(period) as u32, unwrapped.div_euclid(period) as i32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::PropagationSet;

    #[test]
    fn slices_cover_every_plane_once_in_sweep_order() {
        for face in 0..6 {
            let sweep = FaceSweep::new(face, [37, 20, 53]);
            for slab in [16, 8, 4, 2, 1] {
                let slices = sweep.slices(16, slab);
                let mut t = 0;
                for s in &slices {
                    assert_eq!(s.t0, t);
                    assert!(s.t1 > s.t0 && s.t1 - s.t0 <= slab);
                    assert_eq!(s.slab_planes, slab);
                    // Every plane of a slice lies in the slice's brick, inside its slab.
                    for tt in s.t0..s.t1 {
                        let c = sweep.plane_coordinate(tt);
                        assert_eq!(c / 16, s.brick_a);
                        assert!((s.slab_lo..s.slab_lo + slab).contains(&(c % 16)));
                    }
                    t = s.t1;
                }
                assert_eq!(t, sweep.n[0]);
            }
        }
    }

    #[test]
    fn rays_of_a_direction_take_distinct_lattice_columns_and_cover_each_voxel_once() {
        let set = PropagationSet::new(3);
        let sweep = FaceSweep::new(4, [7, 5, 9]);
        let [lb, lc] = sweep.lattice();
        for scheme in [SpatialScheme::Linear, SpatialScheme::Constant] {
            for d in set.face(4) {
                let (offs, weights) = lattice(lateral_slope(4, d.omega), sweep.n[0], scheme);
                for (o, w) in offs.iter().zip(&weights) {
                    let mut seen = vec![false; sweep.rays()];
                    let mut cover = vec![0.0; (sweep.n[1] * sweep.n[2]) as usize];
                    for q in 0..lc {
                        for p in 0..lb {
                            let (cb, _) = lattice_column(p, o[0], sweep.n[1]);
                            let (cc, _) = lattice_column(q, o[1], sweep.n[2]);
                            let i = (cc * lb + cb) as usize;
                            assert!(!seen[i]);
                            seen[i] = true;
                            for (vb, wb) in sweep.taps(0, cb, w[0]) {
                                for (vc, wc) in sweep.taps(1, cc, w[1]) {
                                    cover[(vc * sweep.n[1] + vb) as usize] += wb * wc;
                                }
                            }
                        }
                    }
                    // Every voxel gets weight 1 in all from the rays of the direction.
                    for c in cover {
                        assert!((c - 1.0).abs() < 1e-12, "{c}");
                    }
                }
                // Offsets never jump by more than one column per plane.
                for win in offs.windows(2) {
                    assert!((win[1][0] - win[0][0]).abs() <= 1 && (win[1][1] - win[0][1]).abs() <= 1);
                }
            }
        }
    }

    #[test]
    fn constant_scheme_is_the_nearest_column() {
        for slope in [0.0, 0.3, -0.45, 0.999, -1.0, 0.5] {
            let (offs, weights) = lattice([slope, -slope], 40, SpatialScheme::Constant);
            for (t, (o, w)) in offs.iter().zip(&weights).enumerate() {
                // Halves away from zero (mirror-symmetric), else ⌊½ + d⌋.
                let d = slope * (t as f64 + 0.5);
                let nearest = if d < 0.0 { -(0.5 - d).floor() as i32 } else { (0.5 + d).floor() as i32 };
                // Slot s meets voxel column (s + o + 1) mod (n + 1) = s + nearest, weight 1.
                assert_eq!(o[0] + 1, nearest);
                assert_eq!(w[0], 1.0);
            }
        }
    }
}
