//! The CPU backend's sweep of one direction: plane by plane, on every core, bitwise identical at
//! any thread count.
//!
//! The GPU runs one thread per ray and marches it through a slice's planes; the CPU does the same
//! work plane-major, as two data-parallel steps per plane:
//!
//! 1. **step** — every ray of the direction advances through the plane (rows of rays in parallel):
//!    it is reborn if its slot wrapped, gathers the medium and the source from the voxels it lies
//!    between, solves its segment exactly ([`segment`]) and writes its segment-average radiance
//!    into its own cell of the plane's deposit buffer (`propagate.comp`);
//! 2. **collect** — every voxel of the plane pulls its share of those averages from the two-by-two
//!    lattice cells around it, with the plane's lattice weights, into the fluence and the next
//!    order's source (`collect.comp`; rows of voxels in parallel).
//!
//! Rays of one direction occupy distinct lattice cells in every plane ([`super::sweep`]), and a
//! plane's voxels are distinct, so neither step has two tasks writing one place, and every sum is
//! taken in a fixed order (taps in `collect.comp`'s order, directions in the plan's order, row
//! tallies in row order). How rayon splits the rows therefore changes nothing: the result is the
//! same bits with 1 thread or 64 (`tests/it/cpu_threads.rs`). The thread count is the rayon pool's
//! the sweep runs in (`lpm solve --backend cpu --threads N` builds it).
//!
//! Empty bricks are skipped as on the GPU: their voxels are not collected (no fluence or source is
//! kept there), and a plane whose bricks are all empty is a vacuum plane in which rays only wrap
//! (crossing vacuum changes no radiance, so this is exact).

use super::energy::{volume_face, Tallies};
use super::exitance::{record_exit, record_far_exit, Exit, ExitEntry, ExitMaps};
use super::mirror::{rebirth, stepped_out_radiance, CellKey, FarCarry, MirrorRecords, MirrorView};
use super::periodic::PeriodStep;
use super::plan::{Plan, SweepDirection};
use super::segment::segment;
use super::sweep::FaceSweep;
use crate::store::{BrickGrid, BRICK_EDGE};
use rayon::prelude::*;

/// Read-only inputs of a sweep, per voxel (x fastest).
pub(super) struct SweepInputs<'a> {
    pub density: &'a [f64],
    /// The source the rays gain, `[voxel][d·C + ch]`.
    pub gained: &'a [f64],
    /// Per brick (x fastest over the brick grid): whether it holds any medium.
    pub occupied: &'a [bool],
}

/// The fields a sweep adds into, per voxel: this order's fluence `[voxel][ch]` (the order loop
/// adds it to the total, `super::passes`) and the next order's source `[voxel][d·C + ch]`; and
/// the per-face exitance maps, per boundary pixel ([`super::exitance`]).
pub(super) struct SweepOutputs<'a> {
    pub fluence_order: &'a mut [f64],
    pub j_next: &'a mut [f64],
    pub exits: &'a mut ExitMaps,
}

/// What one sweep needs to know besides its direction.
#[derive(Clone, Copy)]
pub(super) struct SweepMode {
    /// Rays are born carrying the direction's boundary radiance (else zero).
    pub boundary: bool,
    /// Rays gain the previous order's source.
    pub gain: bool,
    /// Rays also gain the medium's emission (order 0).
    pub emit: bool,
}

/// Marches every ray of `dir` through the volume; returns the boundary tallies, the radiance
/// each slot carries out of the far face and what it hands over to its mirror images. `entry`:
/// the radiance each slot enters plane 0 with when the sweep axis is periodic
/// ([`super::periodic::entry_radiance`]) or its near face a mirror; `None`: the boundary birth.
/// `mirror`: the last order's hand-overs, with mirror faces ([`super::mirror`]).
pub(super) fn sweep_direction(
    plan: &Plan,
    dir: &SweepDirection,
    mode: SweepMode,
    entry: Option<&[[f64; 3]]>,
    mirror: Option<&MirrorView>,
    inputs: &SweepInputs,
    outputs: &mut SweepOutputs,
) -> (Tallies, Vec<[f64; 3]>, MirrorRecords) {
    let c = plan.channels as usize;
    let sweep = FaceSweep::for_plan(dir.face, plan);
    let na = sweep.n[0];
    let [lb, lc] = sweep.lattice();
    let (lb_us, lc_us) = (lb as usize, lc as usize);
    let birth: [f64; 3] = if mode.boundary { dir.boundary } else { [0.0; 3] };
    let geometry = Geometry { grid: BrickGrid::new(plan.dims) };

    // Ray state in slot order (row q, column p): radiance, and this plane's segment average.
    let mut radiance = match entry {
        Some(e) => e.to_vec(),
        None => vec![birth; lb_us * lc_us],
    };
    let mut average = vec![[0.0f64; 3]; lb_us * lc_us];
    // Tallies per row of slots, summed in row order at the end. Every ray is born at plane 0, on
    // the face the sweep enters by.
    let f = sweep.geometry();
    let (near, far) = (volume_face(f.axis, f.sign < 0.0), volume_face(f.axis, f.sign > 0.0));
    let mut rows = vec![RowTally::default(); lc_us];
    let mut row_records: Vec<Vec<(CellKey, [f64; 3])>> = vec![Vec::new(); lc_us];
    // Per row of slots, the side exits its rays made, where they made them (`super::exitance`):
    // added to the maps in row order after the sweep.
    let mut row_exits: Vec<Vec<ExitEntry>> = vec![Vec::new(); lc_us];
    // On a periodic sweep axis the slots that left through a side in the step from the last
    // period came in there as new rays ([`PeriodStep`]), the others through the near face.
    let period = sweep.periodic[0].then(|| PeriodStep::new(&sweep, dir));
    for (q, (row, l_row)) in rows.iter_mut().zip(radiance.chunks(lb_us)).enumerate() {
        for (p, l) in l_row.iter().enumerate() {
            for ch in 0..c {
                row.born[ch] += l[ch];
                match &period {
                    Some(s) => s.count_entry(&mut row.face_in, near, p, q, ch, l[ch]),
                    None => row.face_in[near][ch] += l[ch],
                }
            }
        }
    }
    // Lattice column and wrap count of every slot column (b) and row (c), at the previous plane
    // and at this one: computed once per plane, shared by every ray. A changed wrap count is a ray
    // that left (on an open axis; on a periodic one it goes on).
    let columns = |t: usize| -> [Vec<Column>; 2] {
        let o = dir.offsets[t];
        [(0..lb).map(|p| sweep.column(0, p, o[0])).collect(), (0..lc).map(|q| sweep.column(1, q, o[1])).collect()]
    };
    let leaves = [!sweep.periodic[1] as i32, !sweep.periodic[2] as i32];
    let [mut wrap_b, mut wrap_c] = columns(0);

    for t in 0..na {
        let w = dir.weights[t as usize];
        let [now_b, now_c] = columns(t as usize);
        let vacuum = geometry.vacuum_plane(&sweep, t, inputs.occupied);
        let step =
            PlaneStep { plan, dir, mode, inputs, sweep: &sweep, geometry: &geometry, t, w, birth, vacuum, mirror };
        radiance
            .par_chunks_mut(lb_us)
            .zip(average.par_chunks_mut(lb_us))
            .zip(rows.par_iter_mut().zip(row_records.par_iter_mut()).zip(row_exits.par_iter_mut()))
            .enumerate()
            .for_each(|(q, ((l_row, avg_row), ((tally, records), exits)))| {
                let (cc, row_wrap) = now_c[q];
                for (p, &(cb, wrap)) in now_b.iter().enumerate() {
                    // How the slot's wrap counts changed: +1 past n (the + side), −1 below 0.
                    let wraps = if t > 0 {
                        [leaves[0] * (wrap - wrap_b[p].1), leaves[1] * (row_wrap - wrap_c[q].1)]
                    } else {
                        [0; 2]
                    };
                    let (l, avg) = (&mut l_row[p], &mut avg_row[p]);
                    let prev = [wrap_b[p].0, wrap_c[q].0];
                    step.ray([cb, cc], prev, wraps, l, avg, tally, records, exits);
                }
            });
        (wrap_b, wrap_c) = (now_b, now_c);
        if !vacuum {
            collect_plane(plan, dir, &sweep, &geometry, t, &average, inputs, outputs);
        }
    }
    // Across a mirror of the far face the rays step on to plane N, the mirror image's plane 0.
    let far_carry = mirror.filter(|m| m.far_is_mirror()).map(|m| {
        let o = dir.offsets[0];
        let o_n = [o[0] + dir.period_shift[0], o[1] + dir.period_shift[1]];
        far_step(m, na, o_n, (&wrap_b, &wrap_c), leaves, birth, &radiance, &mut row_records)
    });
    // Rays still inside leave through the far face (on a periodic sweep axis, those that leave
    // through a side in the step into the next period count there: [`PeriodStep`]).
    let last = na - 1;
    let mut far_exits = Vec::new();
    for (q, row) in radiance.chunks(lb_us).enumerate() {
        for (p, l) in row.iter().enumerate() {
            for ch in 0..c {
                rows[q].left[ch] += l[ch];
                match &period {
                    Some(s) => s.count_exit(&mut rows[q].face_out, far, p, q, ch, l[ch]),
                    None => rows[q].face_out[far][ch] += l[ch],
                }
            }
            // The same exits per boundary pixel, where the books put them.
            let (columns, weights) = ([wrap_b[p].0, wrap_c[q].0], dir.weights[last as usize]);
            let sides = period.as_ref().map_or([None; 2], |s| s.side_exits(p, q));
            record_far_exit(&mut far_exits, &sweep, far, sides, columns, weights, last, *l);
        }
    }
    let power = dir.power_per_radiance;
    for entries in row_exits.iter().chain(std::iter::once(&far_exits)) {
        outputs.exits.add(entries, power);
    }
    let mut tallies = Tallies::default();
    for ch in 0..c {
        tallies.boundary_in[ch] = rows.iter().map(|r| r.born[ch]).sum::<f64>() * power;
        tallies.boundary_out[ch] = rows.iter().map(|r| r.left[ch]).sum::<f64>() * power;
        for face in 0..6 {
            tallies.face_in[face][ch] = rows.iter().map(|r| r.face_in[face][ch]).sum::<f64>() * power;
            tallies.face_out[face][ch] = rows.iter().map(|r| r.face_out[face][ch]).sum::<f64>() * power;
        }
    }
    let records = MirrorRecords { lateral: row_records.into_iter().flatten().collect(), far: far_carry };
    (tallies, radiance, records)
}

/// The step from the last plane to plane N across a mirror of the far face ([`super::mirror`]):
/// records the rays that step into a vacuum column through a mirror side (under plane N), and
/// returns what each lattice cell holds at plane N: the ray's radiance, or the radiance handed
/// over to a ray coming in through mirror sides, or `birth` for a ray born at an open side in
/// that step. Cells in a vacuum column are carried too: their rays may come in through an open
/// side later in the mirror image's sweep (lagged by an order, as everything across a mirror).
#[allow(clippy::too_many_arguments)]
fn far_step(
    mirror: &MirrorView,
    na: u32,
    o_n: [i32; 2],
    (last_b, last_c): (&[Column], &[Column]),
    leaves: [i32; 2],
    birth: [f64; 3],
    radiance: &[[f64; 3]],
    row_records: &mut [Vec<(CellKey, [f64; 3])>],
) -> FarCarry {
    let sweep = mirror.sweep();
    let [lb, lc] = sweep.lattice();
    let mut cells = vec![[0.0; 3]; (lb * lc) as usize];
    for q in 0..lc as usize {
        let (cc, row_wrap) = sweep.column(1, q as u32, o_n[1]);
        for p in 0..lb as usize {
            let (cb, wrap) = sweep.column(0, p as u32, o_n[0]);
            let prev = [last_b[p].0, last_c[q].0];
            let wraps = [leaves[0] * (wrap - last_b[p].1), leaves[1] * (row_wrap - last_c[q].1)];
            let (now, l) = ([cb, cc], radiance[q * lb as usize + p]);
            // As in a plane's step (`PlaneStep::ray`): a slot that wraps is a new ray, born at
            // the opposite side (dark at a mirror); one coming in through mirrors is handed over.
            let (_, reborn) = rebirth(sweep, wraps, l, birth);
            if mirror.records_step(prev, now, wraps) {
                row_records[q].push(((na, cb, cc), stepped_out_radiance(wraps, l, reborn)));
            }
            cells[(cc * lb + cb) as usize] = match mirror.entry_sides(prev, now, wraps) {
                Some(sides) => mirror.handed_over(na, now, sides),
                None => reborn,
            };
        }
    }
    FarCarry { cells }
}

/// The radiance one row of slots carried in and out: in all, and per face of the volume
/// ([`super::energy::VOLUME_FACES`]). The totals are kept apart from the faces' so that tests can
/// check that the split adds up.
#[derive(Clone, Copy, Default)]
struct RowTally {
    born: [f64; 3],
    left: [f64; 3],
    face_in: [[f64; 3]; 6],
    face_out: [[f64; 3]; 6],
}

/// A slot's lattice column in a plane and how often it has wrapped ([`FaceSweep::column`]).
type Column = (u32, i32);

/// Voxel indexing (x fastest, the twin's layout) and the store's brick grid.
struct Geometry {
    grid: BrickGrid,
}

impl Geometry {
    fn index(&self, v: [u32; 3]) -> usize {
        let [nx, ny, _] = self.grid.dims.map(|d| d as usize);
        v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize)
    }

    fn brick(&self, v: [u32; 3]) -> usize {
        self.grid.locate(v).0
    }

    /// Whether every brick the plane `t` crosses is empty (then rays cross it unchanged).
    fn vacuum_plane(&self, sweep: &FaceSweep, t: u32, occupied: &[bool]) -> bool {
        let f = sweep.geometry();
        let a = sweep.plane_coordinate(t) / BRICK_EDGE;
        let (kb, kc) = (self.grid.bricks[f.lateral[0]], self.grid.bricks[f.lateral[1]]);
        (0..kc).all(|bc| {
            (0..kb).all(|bb| {
                let mut b = [0u32; 3];
                b[f.axis] = a;
                b[f.lateral[0]] = bb;
                b[f.lateral[1]] = bc;
                !occupied[self.grid.brick_index(b)]
            })
        })
    }
}

/// One plane of one direction's sweep: what every ray of the plane shares.
struct PlaneStep<'s, 'a> {
    plan: &'s Plan,
    dir: &'s SweepDirection,
    mode: SweepMode,
    inputs: &'s SweepInputs<'a>,
    sweep: &'s FaceSweep,
    geometry: &'s Geometry,
    t: u32,
    w: [f64; 2],
    birth: [f64; 3],
    vacuum: bool,
    mirror: Option<&'s MirrorView<'s>>,
}

impl PlaneStep<'_, '_> {
    /// Advances the ray at lattice column `[cb, cc]` (from `prev` at the plane before) through
    /// the plane: rebirth after a wrap (`wraps`: per lateral axis, +1 when the slot passed n, −1
    /// when it went below 0; its side exit placed on the face in `exits`), hand-overs at mirror
    /// sides (recorded in `records`), gather, exact segment.
    #[allow(clippy::too_many_arguments)]
    fn ray(
        &self,
        [cb, cc]: [u32; 2],
        prev: [u32; 2],
        wraps: [i32; 2],
        l: &mut [f64; 3],
        avg: &mut [f64; 3],
        tally: &mut RowTally,
        records: &mut Vec<(CellKey, [f64; 3])>,
        exits: &mut Vec<ExitEntry>,
    ) {
        let c = self.plan.channels as usize;
        let wrapped = wraps != [0, 0];
        let lateral = self.sweep.geometry().lateral;
        let mirror = self.mirror.filter(|_| self.t > 0);
        let stepped_out = mirror.is_some_and(|m| m.records_step(prev, [cb, cc], wraps));
        let before = *l;
        if wrapped {
            // The ray left through a side: a new one enters from the opposite side. Across an
            // edge (both axes wrap) each side takes half. Nothing enters through a mirror from
            // outside: a ray born at one starts dark (what comes back is handed over below).
            let share = if wraps[0] != 0 && wraps[1] != 0 { 0.5 } else { 1.0 };
            let (open, birth) = rebirth(self.sweep, wraps, *l, self.birth);
            let births = open.iter().filter(|&&o| o).count() as f64;
            for k in 0..2 {
                if wraps[k] != 0 {
                    let exit = volume_face(lateral[k], wraps[k] > 0);
                    for ch in 0..c {
                        tally.face_out[exit][ch] += share * l[ch];
                    }
                    // Where it left: plane t − 1, at its position there along the other axis.
                    let t_last = self.t - 1;
                    let w = self.dir.weights[t_last as usize];
                    record_exit(exits, self.sweep, exit, Exit::Side(k), prev, w, t_last, share, *l);
                }
                if open[k] {
                    let entry = volume_face(lateral[k], wraps[k] < 0);
                    for ch in 0..c {
                        tally.face_in[entry][ch] += birth[ch] / births;
                    }
                }
            }
            for ch in 0..c {
                tally.left[ch] += l[ch];
                l[ch] = birth[ch];
                tally.born[ch] += birth[ch];
            }
        }
        if stepped_out {
            // The ray that stepped out through the mirror: this one, unless a new ray came in
            // past the low side of the other axis in the same step (then it is that one).
            records.push(((self.t, cb, cc), stepped_out_radiance(wraps, before, *l)));
        }
        if let Some(m) = mirror {
            if let Some(sides) = m.entry_sides(prev, [cb, cc], wraps) {
                // Coming in through mirror sides: the mirror image's ray that stepped out there.
                let handed = m.handed_over(self.t, [cb, cc], sides);
                let faces = [0, 1].map(|k| sides[k].map(|s| volume_face(lateral[k], s == 1)));
                let entered = faces.iter().flatten().count() as f64;
                for ch in 0..c {
                    let change = handed[ch] - l[ch];
                    for &face in faces.iter().flatten() {
                        tally.face_in[face][ch] += change / entered;
                    }
                    tally.born[ch] += change;
                    l[ch] = handed[ch];
                }
            }
        }
        if self.vacuum {
            return;
        }
        let comps = self.plan.source_components() as usize;
        let k0 = self.dir.gain_storage as usize * c;
        let mut rho = 0.0;
        let mut j = [0.0f64; 3];
        for (vc, tc) in self.sweep.taps(1, cc, self.w[1]) {
            for (vb, tb) in self.sweep.taps(0, cb, self.w[0]) {
                let v = self.geometry.index(self.sweep.voxel(self.t, vb, vc));
                let wt = tb * tc;
                rho += wt * self.inputs.density[v];
                if self.mode.gain {
                    for ch in 0..c {
                        j[ch] += wt * self.inputs.gained[v * comps + k0 + ch];
                    }
                }
            }
        }
        for ch in 0..c {
            let (st, _, sa) = self.plan.coefficients(ch);
            let mut jc = j[ch];
            if self.mode.gain && self.mode.emit {
                jc += rho * sa * self.plan.medium.emission[ch];
            }
            let (out, a) = segment(l[ch], jc, rho * st, self.dir.path_length);
            l[ch] = out;
            avg[ch] = a;
        }
    }
}

/// Every voxel of plane `t` in an occupied brick pulls its share of the plane's segment averages
/// (in slot order in `average`) into the fluence and the next source, rows of voxels in parallel.
#[allow(clippy::too_many_arguments)]
fn collect_plane(
    plan: &Plan,
    dir: &SweepDirection,
    sweep: &FaceSweep,
    geometry: &Geometry,
    t: u32,
    average: &[[f64; 3]],
    inputs: &SweepInputs,
    outputs: &mut SweepOutputs,
) {
    let c = plan.channels as usize;
    let comps = plan.source_components() as usize;
    let [_, nb, nc] = sweep.n;
    let [lb, lc] = sweep.lattice();
    let o = dir.offsets[t as usize];
    let w = dir.weights[t as usize];
    let fluence_order = SharedRows::new(outputs.fluence_order);
    let j_next = SharedRows::new(outputs.j_next);
    (0..nc).into_par_iter().for_each(|vc| {
        for vb in 0..nb {
            let voxel = sweep.voxel(t, vb, vc);
            if !inputs.occupied[geometry.brick(voxel)] {
                continue;
            }
            let v = geometry.index(voxel);
            // Lattice column k + 1 meets voxel column k with weight 1 − w, column k with w; the
            // slot at lattice column ℓ is s = (ℓ − o − 1) mod (n + 1) (mod n on a periodic axis,
            // where lattice column n is column 0). Taps of weight 0 are left
            // out, in collect.comp's order.
            let mut pulled = [0.0f64; 3];
            for dc in 0..2u32 {
                let wc = if dc == 0 { 1.0 - w[1] } else { w[1] };
                if wc == 0.0 {
                    continue;
                }
                let q = slot_of(vc + 1 - dc, o[1], lc);
                for db in 0..2u32 {
                    let wb = if db == 0 { 1.0 - w[0] } else { w[0] };
                    if wb == 0.0 {
                        continue;
                    }
                    let p = slot_of(vb + 1 - db, o[0], lb);
                    let a = &average[q as usize * lb as usize + p as usize];
                    for ch in 0..c {
                        pulled[ch] += (wb * wc) * a[ch];
                    }
                }
            }
            let rho = inputs.density[v];
            for ch in 0..c {
                let share = dir.fluence_weight * pulled[ch];
                // SAFETY: voxel v lies in plane t and row vc, which only this task visits; the
                // plane's voxels are distinct (`FaceSweep::voxel` is one-to-one), so no other task
                // reads or writes element v of these fields while the loop runs.
                unsafe { *fluence_order.at(v * c + ch) += share };
                let sigma_s = rho * plan.coefficients(ch).1;
                if sigma_s > 0.0 {
                    for (d, m) in dir.collect_row.iter().enumerate() {
                        // SAFETY: as above, element v's components belong to this task alone.
                        unsafe { *j_next.at(v * comps + d * c + ch) += sigma_s * m * pulled[ch] };
                    }
                }
            }
        }
    });
}

/// The slot whose ray sits at lattice column `l` in a plane of offset `o` (period `n`).
fn slot_of(l: u32, o: i32, period: u32) -> u32 {
    (l as i64 - o as i64 - 1).rem_euclid(period as i64) as u32
}

/// A field shared by the tasks of one collect, each of which touches only its own voxels.
struct SharedRows {
    ptr: *mut f64,
    len: usize,
}

// SAFETY: the pointer is only dereferenced through `at`, whose callers guarantee that no two
// threads touch the same element; the borrow it came from outlives every task (rayon's for_each
// returns only when all tasks have finished).
unsafe impl Sync for SharedRows {}

impl SharedRows {
    fn new(field: &mut [f64]) -> Self {
        SharedRows { ptr: field.as_mut_ptr(), len: field.len() }
    }

    /// Element `i` of the field.
    ///
    /// # Safety
    /// No other thread may access element `i` while the returned reference lives.
    #[allow(clippy::mut_from_ref)]
    unsafe fn at(&self, i: usize) -> &mut f64 {
        assert!(i < self.len, "voxel index out of the field");
        // SAFETY: in bounds (checked above); exclusivity is the caller's contract.
        unsafe { &mut *self.ptr.add(i) }
    }
}
