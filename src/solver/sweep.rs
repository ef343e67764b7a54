//! Sweep geometry shared by the CPU twin and the GPU driver.
//!
//! A face sweep marches the ray map of one cube face through the volume plane by plane along the
//! face's axis `a` (plane t = 0 is the entry plane). Ray (p, q) of a direction with lateral slope
//! δ = (ω_b, ω_c)/|ω_a| sits, in plane t, at lateral position p + ½ + δ_b·(t + ½) (mid-plane), i.e. in
//! voxel column p + o_b(t) with `o_b(t) = floor(½ + δ_b·(t + ½))`, taken modulo the lateral size: a ray
//! that leaves through a side re-enters from the opposite side as a new ray. Since every ray of a
//! direction shifts by the same o(t), the map from rays to voxels is a bijection in every plane: the
//! rays of one direction never touch the same voxel at the same step.
//!
//! The offsets are computed once on the host in f64 and handed to both backends as integer tables,
//! so the CPU twin and the GPU walk exactly the same voxels (a float `floor` on the GPU could land
//! on the other side of a tie).
//!
//! Energy bookkeeping: a ray carries radiance for a tube of cross-section h²·|ω_a| (one voxel face
//! projected) and solid angle Ω_i, so its power is L·h²·|ω_a|·Ω_i; the sweeps tally the radiance of
//! rays at birth and at exit and the solver turns those tallies into boundary power in and out.

use crate::quadrature::{Face, FACES};
use glam::DVec3;

/// Dimensions of the volume seen from one face: planes along the axis and the lateral sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaceSweep {
    pub face: usize,
    /// (N_a, N_b, N_c): voxels along the sweep axis and the two lateral axes.
    pub n: [u32; 3],
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
    pub fn new(face: usize, dims: [u32; 3]) -> Self {
        let f = FACES[face];
        FaceSweep { face, n: [dims[f.axis], dims[f.lateral[0]], dims[f.lateral[1]]] }
    }

    pub fn geometry(&self) -> Face {
        FACES[self.face]
    }

    /// Number of rays in the map (one per voxel of the face).
    pub fn rays(&self) -> usize {
        self.n[1] as usize * self.n[2] as usize
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

/// The lateral offsets o(t) = floor(½ + δ·(t + ½)) for t in 0..planes.
pub fn offsets(slope: [f64; 2], planes: u32) -> Vec<[i32; 2]> {
    (0..planes)
        .map(|t| {
            let m = t as f64 + 0.5;
            [(0.5 + slope[0] * m).floor() as i32, (0.5 + slope[1] * m).floor() as i32]
        })
        .collect()
}

/// Where ray `p` (of `n` lateral columns) lies with offset `o`: (column, wrap count).
#[inline]
pub fn column(p: u32, o: i32, n: u32) -> (u32, i32) {
    let unwrapped = p as i64 + o as i64;
    let n = n as i64;
    (unwrapped.rem_euclid(n) as u32, unwrapped.div_euclid(n) as i32)
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
    fn rays_of_a_direction_hit_distinct_voxels_in_every_plane() {
        let set = PropagationSet::new(3);
        let sweep = FaceSweep::new(4, [7, 5, 9]);
        for d in set.face(4) {
            let offs = offsets(lateral_slope(4, d.omega), sweep.n[0]);
            for o in &offs {
                let mut seen = vec![false; sweep.rays()];
                for q in 0..sweep.n[2] {
                    for p in 0..sweep.n[1] {
                        let (vb, _) = column(p, o[0], sweep.n[1]);
                        let (vc, _) = column(q, o[1], sweep.n[2]);
                        let i = (vc * sweep.n[1] + vb) as usize;
                        assert!(!seen[i]);
                        seen[i] = true;
                    }
                }
            }
            // Offsets never jump by more than one column per plane.
            for w in offs.windows(2) {
                assert!((w[1][0] - w[0][0]).abs() <= 1 && (w[1][1] - w[0][1]).abs() <= 1);
            }
        }
    }
}
