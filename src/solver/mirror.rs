//! Reflective faces (`[boundary] x = "reflective"`, or `x = ["reflective", "open"]` for one face):
//! a mirror across the face, as across a plane of symmetry. What reaches a mirror face comes back
//! in the mirror-image direction, so the solution is that of the volume doubled by its mirror
//! image across the face (the method of images), without storing or sweeping the image.
//!
//! **Why it is exact on the nearest-column lattice.** Under `solver.spatial = "constant"` a ray
//! meets one voxel column per plane and the lattice column n (one past the last voxel, which is
//! also column −1: the lattice wraps) is vacuum ([`super::sweep`]). A direction and its mirror
//! image across a lateral axis have opposite slopes, and with halves rounded away from zero
//! ([`super::sweep::nearest_column`]) they take mirror-image columns in every plane. In the
//! doubled volume a ray of direction d that steps out through the mirror, into the vacuum column,
//! *is* (by symmetry) the ray of its mirror image d′ that steps in from the vacuum column at the
//! same plane and row. So:
//!
//! - a ray stepping *into* the vacuum column through a mirror side records its radiance under
//!   (plane, lattice cell) — [`MirrorRecords`];
//! - a ray stepping *out of* the vacuum column into the volume through mirror sides S takes the
//!   radiance recorded by the direction mirrored across S, at the same plane, in the cell its own
//!   came from (the vacuum column on the axes of S, its own column on the others).
//!
//! Across a mirror of the **sweep axis** the doubled volume's plane N (one past the last) is the
//! mirror image of plane N − 1, which is plane 0 of the mirror-image direction (the opposite face's
//! sweep): as for a periodic axis ([`super::periodic`]) the plan nudges directions swept across a
//! mirror so that their lattice moves a whole number M of columns over the N planes; then the
//! ray in lattice cell c at plane N continues as the mirror-image direction's ray in cell c at its
//! plane 0, exactly ([`FarCarry`]). The step from plane N − 1 to plane N follows the lateral rules
//! above (records and hand-overs under plane N), so corners and edges are mirrored too.
//!
//! **Lagged by one order.** A sweep hands over to sweeps that may run before it in the same order
//! (or in the same GPU dispatch), so every hand-over is read in the next order: what order k
//! records, order k + 1 takes. The light reflected at a mirror thus arrives one order late (a
//! pure absorber needs one more order per reflection), and the converged answer is the doubled
//! volume's. Deterministic at any thread count: records are kept per row of rays, joined in row
//! order.
//!
//! **Energy books.** What reaches a mirror counts as out through that face when it leaves the
//! volume (as for an open face), and what comes back counts as in through the mirror face that
//! hands it over; the net power through a mirror converges to 0. The recorded radiance the next
//! order will take is the pending power of the stop rule ([`MirrorState::power`]), like a periodic
//! axis's carried rays.
//!
//! A ray may cross a mirror while it is still outside the volume along the other lateral axis
//! (it has not come in through that axis's side yet): it is handed over all the same, because its
//! mirror image, outside as well, recorded what it carried; only a slot that wraps into a vacuum
//! column in the same step holds a new ray, born at that axis's far side, and takes no hand-over.
//! The half volume matches the doubled one to 1e-5 at k = 3 and 4, with low and high mirrors and
//! three meeting at a corner (`tests/it/reflective.rs`).
//!
//! Limits (refused when the scene is read): the linear scheme (its rays straddle the mirror),
//! lights that are not their own mirror image (point lights, environment maps, a sun with a
//! component across a mirror), periodic and reflective axes in one scene, the diffusion
//! acceleration. The GPU backend, whose kernels have no hand-over, solves the doubled volume
//! itself ([`super::unfold`]), and so does the twin where a traced emission's scattered light
//! takes directions of its own (they have no hand-over either). The diffusion correction works across mirrors (a
//! voxel's partner beyond a mirror is its image, [`super::antidiffusion`]).

use super::plan::{Plan, SweepDirection};
use super::sweep::FaceSweep;
use crate::quadrature::FACES;
use std::collections::HashMap;

/// Where a recorded radiance lies: (plane, lattice column b, lattice column c).
pub type CellKey = (u32, u32, u32);

/// For every direction of every face, its mirror image across the volume's x, y and z planes,
/// as (face, index within the face): across the face's own axis the opposite face's direction
/// with the same lateral slope, across a lateral axis the same face's direction with that slope
/// negated. Directions are matched by their ω (the cube-face sets and the nudged slopes are
/// mirror-symmetric, ties of the nudge included: [`super::periodic::periodic_slope`]).
pub fn mirror_images(faces: &[Vec<SweepDirection>]) -> Vec<Vec<[(usize, usize); 3]>> {
    faces
        .iter()
        .enumerate()
        .map(|(face, dirs)| {
            dirs.iter()
                .enumerate()
                .map(|(i, dir)| {
                    [0, 1, 2].map(|axis| {
                        let target_face = if FACES[face].axis == axis { face ^ 1 } else { face };
                        let mut w = dir.omega.to_array();
                        w[axis] = -w[axis];
                        let image = glam::DVec3::from_array(w);
                        faces
                            .get(target_face)
                            .and_then(|t| t.iter().position(|d| (d.omega - image).length() < 1e-9))
                            .map(|j| (target_face, j))
                            // The sets are mirror-symmetric by construction (tested for k ≤ 16
                            // and up to 64 planes: `periodic::tests`); an unmatched direction
                            // would silently hand light to the wrong one.
                            .unwrap_or_else(|| {
                                panic!("internal error: direction {i} of face {face} has no mirror image across axis {axis}")
                            })
                    })
                })
                .collect()
        })
        .collect()
}

/// What one direction's sweep hands over to its mirror images in one order.
#[derive(Clone, Debug, Default)]
pub struct MirrorRecords {
    /// Rays that stepped into the vacuum column through a mirror side: (plane, cell) and radiance,
    /// in row order of the sweep.
    pub lateral: Vec<(CellKey, [f64; 3])>,
    /// With a mirror across the far face: what each lattice cell holds at plane N.
    pub far: Option<FarCarry>,
}

/// The radiance per lattice cell (row c, column b) at the plane one past the last, for the
/// mirror-image direction's plane 0 (cells in a vacuum column too: see `cpu_sweep::far_step`).
#[derive(Clone, Debug, Default)]
pub struct FarCarry {
    pub cells: Vec<[f64; 3]>,
}

/// One direction's records, indexed for the next order's look-ups.
#[derive(Debug, Default)]
struct Indexed {
    lateral: HashMap<CellKey, [f64; 3]>,
    far: Option<FarCarry>,
}

/// The hand-overs between orders: what the last order recorded (read now) and what this order
/// records (read next time), per face and direction.
#[derive(Debug, Default)]
pub struct MirrorState {
    last: Vec<Vec<Indexed>>,
    next: Vec<Vec<MirrorRecords>>,
}

impl MirrorState {
    pub fn new(plan: &Plan) -> Self {
        MirrorState {
            last: plan.faces.iter().map(|f| f.iter().map(|_| Indexed::default()).collect()).collect(),
            next: plan.faces.iter().map(|f| vec![MirrorRecords::default(); f.len()]).collect(),
        }
    }

    /// Starts an order: what the previous one recorded becomes readable, and recording starts
    /// afresh.
    pub fn begin_order(&mut self) {
        for (last, next) in self.last.iter_mut().flatten().zip(self.next.iter_mut().flatten()) {
            let records = std::mem::take(next);
            *last = Indexed { lateral: records.lateral.into_iter().collect(), far: records.far };
        }
    }

    /// Keeps what direction `dir` of `face` recorded this order.
    pub fn store(&mut self, face: usize, dir: usize, records: MirrorRecords) {
        self.next[face][dir] = records;
    }

    /// The power (per channel) the records of this order bring back into the next one.
    pub fn power(&self, plan: &Plan) -> [f64; 3] {
        let mut power = [0.0; 3];
        for (records, dirs) in self.next.iter().zip(&plan.faces) {
            for (r, dir) in records.iter().zip(dirs) {
                let far = r.far.iter().flat_map(|f| f.cells.iter());
                for l in r.lateral.iter().map(|(_, l)| l).chain(far) {
                    for (p, v) in power.iter_mut().zip(l) {
                        *p += v * dir.power_per_radiance;
                    }
                }
            }
        }
        power
    }

    /// What the sweep of direction `dir` of `face` reads this order.
    pub fn view<'a>(&'a self, plan: &'a Plan, face: usize, dir: usize) -> MirrorView<'a> {
        let sweep = FaceSweep::for_plan(face, plan);
        let lateral = FACES[face].lateral;
        let images = &plan.mirrors[face];
        // Mirror images across the lateral axes: b, c, and both.
        let across_b = images[dir][lateral[0]];
        let across_c = images[dir][lateral[1]];
        let across_bc = images[across_b.1][lateral[1]];
        let records = |(f, d): (usize, usize)| &self.last[f][d].lateral;
        let (af, ad) = images[dir][FACES[face].axis];
        MirrorView {
            sweep,
            sources: [records(across_b), records(across_c), records(across_bc)],
            entry: self.last[af][ad].far.as_ref(),
        }
    }
}

/// One sweep's view of the last order's records: where its rays coming in through mirrors take
/// their radiance from.
pub struct MirrorView<'a> {
    sweep: FaceSweep,
    /// The records of the direction mirrored across b, across c, across both.
    sources: [&'a HashMap<CellKey, [f64; 3]>; 3],
    /// What the mirror image across the sweep axis carried to plane N (this sweep's plane 0).
    entry: Option<&'a FarCarry>,
}

/// The ray a slot holds after a step that wrapped it along the axes where `wraps` ≠ 0 (a new ray,
/// born at the side opposite the one the old ray left by): per lateral axis whether it was born at
/// an open side, and its radiance: `birth` if any of those sides is open, else dark (nothing
/// enters through a mirror from outside; what comes back is handed over). No wrap: `l` itself.
pub fn rebirth(sweep: &FaceSweep, wraps: [i32; 2], l: [f64; 3], birth: [f64; 3]) -> ([bool; 2], [f64; 3]) {
    let open = [0, 1].map(|k| wraps[k] != 0 && !sweep.mirror[1 + k][(wraps[k] < 0) as usize]);
    let radiance = match (wraps, open) {
        ([0, 0], _) => l,
        (_, [false, false]) => [0.0; 3],
        _ => birth,
    };
    (open, radiance)
}

/// What a ray that stepped out through a mirror in a step with lateral `wraps` carried: the ray
/// of the slot before the step (`before`), unless the slot wrapped past the low side of an axis in
/// that step, so that a new ray came in there (`reborn`, see [`rebirth`]).
pub fn stepped_out_radiance(wraps: [i32; 2], before: [f64; 3], reborn: [f64; 3]) -> [f64; 3] {
    if wraps.iter().any(|&w| w > 0) {
        reborn
    } else {
        before
    }
}

/// Whether lateral column `col` of axis k (0: b, 1: c) is the vacuum column.
fn vacuum(sweep: &FaceSweep, k: usize, col: u32) -> bool {
    !sweep.periodic[1 + k] && col == sweep.n[1 + k]
}

/// The side (0 low, 1 high) a step between the vacuum column and the volume crosses on one axis:
/// a step that wraps the lattice (`wrap` ≠ 0) goes between column 0 and the vacuum column (the low
/// side), one that does not between column n − 1 and it (the high side).
fn side(wrap: i32) -> usize {
    (wrap == 0) as usize
}

impl MirrorView<'_> {
    pub fn sweep(&self) -> &FaceSweep {
        &self.sweep
    }

    /// Whether a ray stepping from cell `prev` to cell `now` (lateral wrap counts changed by
    /// `wraps`) steps into the vacuum column through a mirror side: then its radiance is recorded.
    pub fn records_step(&self, prev: [u32; 2], now: [u32; 2], wraps: [i32; 2]) -> bool {
        (0..2).any(|k| {
            vacuum(&self.sweep, k, now[k])
                && !vacuum(&self.sweep, k, prev[k])
                && self.sweep.mirror[1 + k][side(wraps[k])]
        })
    }

    /// The mirror sides a ray stepping from `prev` to `now` comes in through (out of the vacuum
    /// column of an axis, into the volume along it): per axis (b, c), the side, or `None` when it
    /// does not come in through a mirror along that axis. A ray coming in through a mirror and an
    /// open side at once, or still outside along the other axis, is handed over too: its mirror
    /// image stepped out through the mirror on the same path and recorded what it carried. `None`
    /// overall: not a hand-over (also when the slot wraps into a vacuum column: a new ray).
    pub fn entry_sides(&self, prev: [u32; 2], now: [u32; 2], wraps: [i32; 2]) -> Option<[Option<usize>; 2]> {
        // A slot that wrapped into the vacuum column of an axis holds a new ray born outside
        // that axis's high side: whatever it crossed on the other axis, it comes from there.
        if (0..2).any(|k| wraps[k] < 0 && vacuum(&self.sweep, k, now[k])) {
            return None;
        }
        let mut sides = [None; 2];
        for k in 0..2 {
            let s = side(wraps[k]);
            if vacuum(&self.sweep, k, prev[k]) && !vacuum(&self.sweep, k, now[k]) && self.sweep.mirror[1 + k][s] {
                sides[k] = Some(s);
            }
        }
        (sides != [None; 2]).then_some(sides)
    }

    /// The radiance handed over to a ray coming in at plane `t` into cell `now` through the mirror
    /// sides `sides` ([`MirrorView::entry_sides`]): what the mirror image across those axes
    /// recorded in the last order at plane `t` in the vacuum-column cell it stepped into (zero
    /// when it recorded nothing, as in the first order).
    pub fn handed_over(&self, t: u32, now: [u32; 2], sides: [Option<usize>; 2]) -> [f64; 3] {
        let source = match sides {
            [Some(_), None] => 0,
            [None, Some(_)] => 1,
            _ => 2,
        };
        let key = (
            t,
            if sides[0].is_some() { self.sweep.n[1] } else { now[0] },
            if sides[1].is_some() { self.sweep.n[2] } else { now[1] },
        );
        self.sources[source].get(&key).copied().unwrap_or([0.0; 3])
    }

    /// With a mirror across the near face: the radiance each slot enters plane 0 with (slot order,
    /// row c then column b): what the mirror image across the sweep axis carried to its plane N
    /// in the slot's cell in the last order (zero before it was swept: the light arrives an order
    /// late, as everything across a mirror). `None` when the near face is not a mirror.
    pub fn entry_radiance(&self, dir: &SweepDirection) -> Option<Vec<[f64; 3]>> {
        let near = if FACES[self.sweep.face].sign > 0.0 { 0 } else { 1 };
        if !self.sweep.mirror[0][near] {
            return None;
        }
        let [lb, lc] = self.sweep.lattice();
        let o = dir.offsets[0];
        let mut entry = Vec::with_capacity((lb * lc) as usize);
        for q in 0..lc {
            let cc = self.sweep.column(1, q, o[1]).0;
            for p in 0..lb {
                let cb = self.sweep.column(0, p, o[0]).0;
                let cell = (cc * lb + cb) as usize;
                entry.push(self.entry.and_then(|e| e.cells.get(cell).copied()).unwrap_or([0.0; 3]));
            }
        }
        Some(entry)
    }

    /// Whether the far face is a mirror (the sweep then ends with a step to plane N).
    pub fn far_is_mirror(&self) -> bool {
        let far = if FACES[self.sweep.face].sign > 0.0 { 1 } else { 0 };
        self.sweep.mirror[0][far]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_into_the_vacuum_column_is_recorded_only_through_a_mirror() {
        let mut sweep = FaceSweep::new(4, [8, 5, 6]);
        sweep.mirror[1] = [false, true];
        let empty = HashMap::new();
        let view = MirrorView { sweep, sources: [&empty; 3], entry: None };
        let (n, m) = (sweep.n[1], sweep.n[2]);
        // Column n − 1 → n (the vacuum column) without a wrap: through the high side.
        assert!(view.records_step([n - 1, 2], [n, 2], [0, 0]));
        // Column 0 → n by a wrap: through the low side, which is open.
        assert!(!view.records_step([0, 2], [n, 2], [-1, 0]));
        // Coming back in through the high side is a hand-over; through the low side a birth.
        assert_eq!(view.entry_sides([n, 2], [n - 1, 2], [0, 0]), Some([Some(1), None]));
        assert_eq!(view.entry_sides([n, 2], [0, 2], [1, 0]), None);
        // Through the mirror and an open side at once: handed over (the image came in there too).
        assert_eq!(view.entry_sides([n, m], [n - 1, m - 1], [0, 0]), Some([Some(1), None]));
        // Through the mirror while still outside along c: handed over too (the image, outside
        // along c as well, recorded what it carried past the mirror).
        assert_eq!(view.entry_sides([n, m], [n - 1, m], [0, 0]), Some([Some(1), None]));
        // Through the mirror while wrapping into the vacuum column of c: a new ray, born at the
        // high side of c, not the one that crossed the mirror.
        assert_eq!(view.entry_sides([n, 0], [n - 1, m], [0, -1]), None);
    }
}
