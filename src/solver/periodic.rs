//! Periodic boundaries (`[boundary] x|y|z = "periodic"`): the volume repeats along an axis without
//! end, so light leaving through one face of that axis enters through the opposite face.
//!
//! **Lateral axes of a sweep** are exact and need nothing between orders: the ray lattice of a
//! periodic lateral axis of n voxels has n slots with period n (not n + 1 with a slot of vacuum,
//! [`super::sweep`]), lattice column ℓ lies between voxel columns ℓ − 1 and ℓ modulo n, and a ray
//! whose slot wraps simply goes on with its radiance: no ray leaves, none is born.
//!
//! **The sweep axis** cannot be closed inside one sweep (the rays entering at plane 0 are the
//! ones leaving after the last plane), so it is closed across orders, like the source iteration
//! itself: what the rays of a direction carry out through the far face in one order is what that
//! direction's rays carry in through the near face in the next. To make that hand-over exact (no
//! resampling between lattices) the plan nudges every direction swept along a periodic axis so
//! that after one period of N planes its rays have moved a whole number M of columns per lateral
//! axis: lateral slope δ' = round(δ·N)/N (a change of at most 1/(2N) per plane), so the offsets
//! repeat with period N up to M and the weights repeat exactly. The ray leaving slot s then
//! re-enters in slot s + M (modulo the lattice), at its own lateral position ([`entry_radiance`]).
//! On an open lateral axis a ray whose column would wrap in that step (from plane N − 1 to plane
//! N ≡ plane 0 one period on) has reached the side: it is not carried, and its slot is a ray born
//! at the side (with the boundary radiance, as any ray born there) ([`PeriodStep`]). Sun beams along a periodic axis are swept again in every order, carrying what they
//! carried out the order before (and gaining nothing else).
//!
//! Energy books: what leaves through a face of a periodic axis counts as out through that face,
//! and what the next order carries in counts as in through the opposite face; a converged solve's
//! net power through a periodic face is therefore ≈ 0, and the balance closes exactly as for open
//! faces. A ray that leaves through an open side in the step between periods counts as out through
//! that side, and the ray born in its slot as in through the opposite side, not through the
//! periodic faces (counted there, its light left through a periodic face and never came back in
//! through the opposite one: 4–16 % of the light, so R + T fell short of 1, with the linear
//! scheme, whose lattice shifts in that step for most directions, and with periods of one voxel,
//! where every step is that step). The carried radiance of the last order is in the books as out
//! (the solve stops there).
//!
//! The carried radiance is ray state between orders (per direction and slot, f64), held by the
//! backend: [`PeriodicCarry`]. Checkpoints save it beside the fields (`carry_<orders>.f64`,
//! [`PeriodicCarry::to_bytes`]), so a resumed periodic solve ends bitwise identical to an
//! uninterrupted one.

use super::energy::volume_face;
use super::plan::{Plan, SweepDirection};
use super::sweep::FaceSweep;
use crate::scene::SpatialScheme;

/// One direction's rays' radiance per slot (slot order: row c, column b) and channel.
pub type RayRadiance = Vec<[f64; 3]>;

/// What each direction swept along a periodic axis carried out of its far face in the last
/// order it was swept: the radiance its rays carry in next time.
#[derive(Clone, Debug, Default)]
pub struct PeriodicCarry {
    /// Per face (0..6) and direction of the face, then per beam: `None` until swept once.
    faces: Vec<Vec<Option<RayRadiance>>>,
    beams: Vec<Option<RayRadiance>>,
}

/// Which sweep a carried state belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CarryOf {
    /// Direction `dir` of face `face`.
    Face {
        face: usize,
        dir: usize,
    },
    Beam(usize),
}

impl PeriodicCarry {
    pub fn new(plan: &Plan) -> Self {
        PeriodicCarry {
            faces: plan.faces.iter().map(|f| vec![None; f.len()]).collect(),
            beams: vec![None; plan.beams.len()],
        }
    }

    /// Whether nothing is carried (no periodic sweep axis, or nothing swept yet).
    pub fn is_empty(&self) -> bool {
        self.faces.iter().flatten().chain(&self.beams).all(Option::is_none)
    }

    /// The carried radiance as bytes for a checkpoint: per sweep direction in plan order (the
    /// faces' directions, then the beams), its slot count as a little-endian u64 (0: nothing
    /// carried) and then each slot's three channels as little-endian f64 (exact: the values came
    /// from f32 ray state or were born f64 on the twin).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::new();
        for carried in self.faces.iter().flatten().chain(&self.beams) {
            let slots = carried.as_ref().map_or(&[][..], Vec::as_slice);
            bytes.extend_from_slice(&(slots.len() as u64).to_le_bytes());
            for l in slots {
                l.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
            }
        }
        bytes
    }

    /// Reads [`PeriodicCarry::to_bytes`] back for `plan`; `None` when the bytes do not fit it
    /// (another plan's, or a damaged file).
    pub fn from_bytes(plan: &Plan, bytes: &[u8]) -> Option<Self> {
        let mut carry = PeriodicCarry::new(plan);
        let mut rest = bytes;
        let mut take = |n: usize| -> Option<&[u8]> {
            let (head, tail) = (rest.get(..n)?, rest.get(n..)?);
            rest = tail;
            Some(head)
        };
        let sweeps: Vec<&SweepDirection> = plan.faces.iter().flatten().chain(&plan.beams).collect();
        for (slot, dir) in carry.faces.iter_mut().flatten().chain(carry.beams.iter_mut()).zip(sweeps) {
            let n = u64::from_le_bytes(take(8)?.try_into().ok()?) as usize;
            if n == 0 {
                continue;
            }
            if n != FaceSweep::for_plan(dir.face, plan).rays() {
                return None;
            }
            let values = take(n.checked_mul(24)?)?;
            let f = |b: &[u8]| f64::from_le_bytes(b.try_into().unwrap_or([0; 8]));
            *slot = Some(values.chunks_exact(24).map(|l| [f(&l[..8]), f(&l[8..16]), f(&l[16..])]).collect());
        }
        rest.is_empty().then_some(carry)
    }

    fn slot(&mut self, of: CarryOf) -> &mut Option<RayRadiance> {
        match of {
            CarryOf::Face { face, dir } => &mut self.faces[face][dir],
            CarryOf::Beam(b) => &mut self.beams[b],
        }
    }

    /// The radiance every ray of `dir` starts with at plane 0 when its sweep axis is periodic
    /// (`None` when it is open: the rays are born with `birth`, as always): what the same slot
    /// carried out last time ([`entry_radiance`]), or `birth` where the ray enters by a side.
    pub fn entry(&mut self, plan: &Plan, of: CarryOf, dir: &SweepDirection, birth: [f64; 3]) -> Option<RayRadiance> {
        let sweep = FaceSweep::for_plan(dir.face, plan);
        if !sweep.periodic[0] {
            return None;
        }
        let exits = self.slot(of).take();
        Some(entry_radiance(&sweep, dir, exits.as_deref(), birth))
    }

    /// The power the stored radiance carries into the next order, per channel.
    pub fn power(&self, plan: &Plan) -> [f64; 3] {
        let mut power = [0.0; 3];
        let faces = self.faces.iter().zip(&plan.faces).flat_map(|(c, d)| c.iter().zip(d));
        for (exits, dir) in faces.chain(self.beams.iter().zip(&plan.beams)) {
            let Some(exits) = exits else { continue };
            let sweep = FaceSweep::for_plan(dir.face, plan);
            let step = PeriodStep::new(&sweep, dir);
            let lb = sweep.lattice()[0] as usize;
            for (i, l) in exits.iter().enumerate() {
                // What left through a side in the step into the next period is not carried.
                let [sb, sc] = step.exit_shares(i % lb, i / lb);
                for (p, v) in power.iter_mut().zip(l) {
                    *p += v * (1.0 - sb - sc) * dir.power_per_radiance;
                }
            }
        }
        power
    }

    /// Keeps what the rays of a periodic-axis sweep carried out of its far face.
    pub fn store_exit(&mut self, plan: &Plan, of: CarryOf, dir: &SweepDirection, exits: RayRadiance) {
        if FaceSweep::for_plan(dir.face, plan).periodic[0] {
            *self.slot(of) = Some(exits);
        }
    }
}

/// The step from one period into the next of a direction swept along a periodic axis (plane
/// N − 1 to plane N, which is plane 0 of the next order with every slot moved by M): per open
/// lateral axis, the slots whose column leaves the lattice in that step have left through that
/// side, as in any other step of the sweep. They are not carried over: the books count what they
/// carried out through the side, not through the far face (it would otherwise leave through a
/// periodic face and never come back in through the opposite one), and the slots that continue
/// them next time are rays born at the opposite side.
pub struct PeriodStep {
    lattice: [u32; 2],
    shift: [i64; 2],
    /// Per lateral axis, for each slot along it: whether its ray leaves through the side.
    leaves: [Vec<bool>; 2],
    /// Per lateral axis: the volume faces a leaving ray exits through and the ray born in its
    /// place enters by (`None`: no slot leaves along that axis).
    sides: [Option<(usize, usize)>; 2],
}

impl PeriodStep {
    pub fn new(sweep: &FaceSweep, dir: &SweepDirection) -> Self {
        let lattice = sweep.lattice();
        let (last, first) = (dir.offsets[dir.offsets.len() - 1], dir.offsets[0]);
        let lateral = sweep.geometry().lateral;
        let mut leaves = [Vec::new(), Vec::new()];
        let mut sides = [None; 2];
        for k in 0..2 {
            let period = lattice[k] as i64;
            // Columns moved from plane N − 1 to plane N (≡ plane 0 + M).
            let step = first[k] as i64 + dir.period_shift[k] as i64 - last[k] as i64;
            let open = !sweep.periodic[1 + k];
            leaves[k] = (0..period)
                .map(|s| {
                    // Unwrapped columns at the last plane and one step on (as `FaceSweep::column`).
                    let before = s + last[k] as i64 + 1;
                    open && before.div_euclid(period) != (before + step).div_euclid(period)
                })
                .collect();
            if open && step != 0 {
                sides[k] = Some((volume_face(lateral[k], step > 0), volume_face(lateral[k], step < 0)));
            }
        }
        PeriodStep { lattice, shift: dir.period_shift.map(i64::from), leaves, sides }
    }

    /// Books `value` (channel `ch`) of what slot (p, q) carried out of the far face: in
    /// `faces[far]`, except the shares that left through a side in the step into the next period.
    pub fn count_exit(&self, faces: &mut [[f64; 3]; 6], far: usize, p: usize, q: usize, ch: usize, value: f64) {
        let sides = self.sides.map(|s| s.map(|(exit, _)| exit));
        split_by_sides(faces, far, value, ch, self.exit_shares(p, q), sides);
    }

    /// Per lateral axis (b, c): the face and the share of what slot (p, q) carried out of the far
    /// face that [`PeriodStep::count_exit`] books through a side instead (`None`: none).
    pub fn side_exits(&self, p: usize, q: usize) -> [Option<(usize, f64)>; 2] {
        let shares = self.exit_shares(p, q);
        [0, 1].map(|k| match self.sides[k] {
            Some((exit, _)) if shares[k] > 0.0 => Some((exit, shares[k])),
            _ => None,
        })
    }

    /// Books `value` (channel `ch`) that slot (p', q') entered plane 0 with: in `faces[near]`,
    /// except the shares of a ray born at a side in the step from the last period.
    pub fn count_entry(&self, faces: &mut [[f64; 3]; 6], near: usize, p: usize, q: usize, ch: usize, value: f64) {
        let sides = self.sides.map(|s| s.map(|(_, entry)| entry));
        let (sp, sq) = self.source(p, q);
        split_by_sides(faces, near, value, ch, self.exit_shares(sp, sq), sides);
    }

    /// Of what slot (p, q) carried out of the far face, the shares (b, c) that left through the
    /// sides in the step into the next period: 1 along the axis it leaves by, ½ each across an
    /// edge (the kernels' rule for a ray that wraps along both axes at once).
    fn exit_shares(&self, p: usize, q: usize) -> [f64; 2] {
        match (self.leaves[0][p], self.leaves[1][q]) {
            (true, true) => [0.5, 0.5],
            (b, c) => [b as u8 as f64, c as u8 as f64],
        }
    }

    /// The exit slot (p, q) that entry slot (p', q') continues: s = s' − M per axis, modulo the
    /// lattice.
    fn source(&self, p: usize, q: usize) -> (usize, usize) {
        let back = |k: usize, e: usize| (e as i64 - self.shift[k]).rem_euclid(self.lattice[k] as i64) as usize;
        (back(0, p), back(1, q))
    }
}

/// Adds `value` (channel `ch`) to `faces[main]`, except the `shares` (b, c) of it that crossed
/// the sides `sides` instead: those go to the sides' faces.
fn split_by_sides(
    faces: &mut [[f64; 3]; 6],
    main: usize,
    value: f64,
    ch: usize,
    shares: [f64; 2],
    sides: [Option<usize>; 2],
) {
    let mut rest = value;
    for (share, side) in shares.into_iter().zip(sides) {
        if let (true, Some(face)) = (share > 0.0, side) {
            faces[face][ch] += share * value;
            rest -= share * value;
        }
    }
    faces[main][ch] += rest;
}

/// The radiance each slot of `dir` enters plane 0 with, from `exits` (per slot: what it carried
/// out after the last plane; `None`: nothing yet, as before the first order): slot s' takes what
/// slot s = s' − M left with (per lateral axis, modulo the lattice), unless on an open lateral axis
/// the ray of slot s left through the side in that step ([`PeriodStep`]): slot s' is born there,
/// `birth`.
pub fn entry_radiance(
    sweep: &FaceSweep,
    dir: &SweepDirection,
    exits: Option<&[[f64; 3]]>,
    birth: [f64; 3],
) -> RayRadiance {
    let step = PeriodStep::new(sweep, dir);
    let [lb, lc] = sweep.lattice().map(|l| l as usize);
    let mut entry = Vec::with_capacity(lb * lc);
    for q in 0..lc {
        for p in 0..lb {
            let (sp, sq) = step.source(p, q);
            let born = step.leaves[0][sp] || step.leaves[1][sq];
            entry.push(match exits {
                _ if born => birth,
                Some(exits) => exits[sq * lb + sp],
                None => [0.0; 3],
            });
        }
    }
    entry
}

/// The lateral slope a direction with slope `slope` is swept with when its sweep axis (of
/// `planes` planes) is periodic, and the whole columns M it moves per period: δ' = M/N with
/// M = round(δ·N) (module docs). Ties (δ·N a half, as 3/12 over 10 planes) go away from zero
/// whatever the last bit of δ says, so that δ and −δ (a direction and its mirror image, whose
/// slopes come from different float sums) always get M and −M (`super::mirror`).
pub fn periodic_slope(slope: [f64; 2], planes: u32) -> ([f64; 2], [i32; 2]) {
    let n = planes as f64;
    let m = slope.map(|d| (d.abs() * n + 0.5 + 1e-9).floor().copysign(d));
    ([m[0] / n, m[1] / n], m.map(|v| v as i32))
}

/// [`super::sweep::lattice`] for the slope M/N, in exact integer arithmetic: D(t) = M·(2t + 1)/(2N),
/// so the offsets of plane t + N are those of plane t plus M and the weights are equal, to the bit
/// (a float product could round across an integer in one period and not in the next).
pub fn periodic_lattice(m: [i32; 2], planes: u32, scheme: SpatialScheme) -> (Vec<[i32; 2]>, Vec<[f64; 2]>) {
    let two_n = 2 * planes as i64;
    let mut offsets = Vec::with_capacity(planes as usize);
    let mut weights = Vec::with_capacity(planes as usize);
    for t in 0..planes as i64 {
        let mut o = [0; 2];
        let mut w = [0.0; 2];
        for k in 0..2 {
            let num = m[k] as i64 * (2 * t + 1);
            match scheme {
                SpatialScheme::Linear => {
                    o[k] = num.div_euclid(two_n) as i32;
                    w[k] = num.rem_euclid(two_n) as f64 / two_n as f64;
                }
                SpatialScheme::Constant => {
                    // The nearest column, halves away from zero (super::sweep::nearest_column).
                    let nearest = (num.abs() + planes as i64).div_euclid(two_n) * num.signum();
                    o[k] = nearest as i32 - 1;
                    w[k] = 1.0;
                }
            }
        }
        offsets.push(o);
        weights.push(w);
    }
    (offsets, weights)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::sweep::lattice;

    #[test]
    fn mirror_image_directions_are_nudged_to_mirror_image_slopes() {
        // A direction's mirror image has the negated slope, computed from other float sums; at a
        // tie of the nudge (δ·N a half) both must still round away from zero (else the mirror
        // hand-over finds no image: solver::mirror).
        use crate::quadrature::PropagationSet;
        use crate::solver::sweep::lateral_slope;
        for k in 1..=16 {
            let set = PropagationSet::new(k);
            for face in 0..6 {
                let dirs = set.face(face);
                for d in dirs {
                    let slope = lateral_slope(face, d.omega);
                    for axis in 0..2 {
                        let mirrored = dirs
                            .iter()
                            .map(|e| lateral_slope(face, e.omega))
                            .find(|s| {
                                (s[axis] + slope[axis]).abs() < 1e-12 && (s[1 - axis] - slope[1 - axis]).abs() < 1e-12
                            })
                            .expect("the cube-face set is mirror-symmetric");
                        for planes in 1..=64 {
                            let (a, m) = periodic_slope(slope, planes);
                            let (b, n) = periodic_slope(mirrored, planes);
                            assert_eq!(m[axis], -n[axis], "k {k} face {face} slope {slope:?} planes {planes}");
                            assert_eq!(a[axis], -b[axis]);
                            assert_eq!(m[1 - axis], n[1 - axis]);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_periodic_lattice_repeats_after_one_period_and_matches_the_float_one() {
        for scheme in [SpatialScheme::Linear, SpatialScheme::Constant] {
            for slope in [0.0, 0.37, -0.81, 1.0, -0.02, 2.0 / 23.0] {
                let planes = 23;
                let (nudged, m) = periodic_slope([slope, -slope], planes);
                assert!((nudged[0] - slope).abs() <= 0.5 / planes as f64 + 1e-15);
                // Two periods, computed as one lattice of 2N planes with slope 2M/(2N).
                let (offs, weights) = periodic_lattice(m.map(|v| 2 * v), 2 * planes, scheme);
                let (one, one_w) = periodic_lattice(m, planes, scheme);
                let (float, float_w) = lattice(nudged, planes, scheme);
                for t in 0..planes as usize {
                    let u = t + planes as usize;
                    assert_eq!(offs[t], one[t]);
                    assert_eq!(offs[u][0] - offs[t][0], m[0], "slope {slope} t {t}");
                    assert_eq!(offs[u][1] - offs[t][1], m[1]);
                    assert_eq!(weights[u], weights[t]);
                    assert_eq!(weights[t], one_w[t]);
                    // The same lattice as the float one, up to the float's rounding at ties.
                    for k in 0..2 {
                        let (a, b) = (one[t][k] as f64 + one_w[t][k], float[t][k] as f64 + float_w[t][k]);
                        assert!((a - b).abs() < 1e-9 || scheme == SpatialScheme::Constant, "{a} {b}");
                    }
                }
            }
        }
    }
}
