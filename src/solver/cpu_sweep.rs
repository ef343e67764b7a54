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

use super::energy::Tallies;
use super::plan::{Plan, SweepDirection};
use super::segment::{segment, segment_linear};
use super::sweep::{lattice_column, taps, FaceSweep};
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
/// adds it to the total, `super::passes`) and the next order's source `[voxel][d·C + ch]`.
pub(super) struct SweepOutputs<'a> {
    pub fluence_order: &'a mut [f64],
    pub j_next: &'a mut [f64],
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

/// Marches every ray of `dir` through the volume; returns the boundary tallies.
pub(super) fn sweep_direction(
    plan: &Plan,
    dir: &SweepDirection,
    mode: SweepMode,
    inputs: &SweepInputs,
    outputs: &mut SweepOutputs,
) -> Tallies {
    let c = plan.channels as usize;
    let sweep = FaceSweep::new(dir.face, plan.dims);
    let [na, nb, nc] = sweep.n;
    let [lb, lc] = sweep.lattice();
    let (lb_us, lc_us) = (lb as usize, lc as usize);
    let birth: [f64; 3] = if mode.boundary { dir.boundary } else { [0.0; 3] };
    let geometry = Geometry { grid: BrickGrid::new(plan.dims) };

    // Ray state in slot order (row q, column p): radiance, and this plane's segment average.
    let mut radiance = vec![birth; lb_us * lc_us];
    let mut average = vec![[0.0f64; 3]; lb_us * lc_us];
    // Tallies per row of slots, summed in row order at the end. Every ray is born at plane 0.
    let mut born = vec![[0.0f64; 3]; lc_us];
    let mut left = vec![[0.0f64; 3]; lc_us];
    for row in &mut born {
        for ch in 0..c {
            row[ch] = birth[ch] * lb as f64;
        }
    }
    // Lattice column and wrap count of every slot column (b) and row (c), at the previous plane
    // and at this one: computed once per plane, shared by every ray. A changed wrap count is a ray
    // that left.
    let columns = |t: usize| -> [Vec<Column>; 2] {
        let o = dir.offsets[t];
        [(0..lb).map(|p| lattice_column(p, o[0], nb)).collect(), (0..lc).map(|q| lattice_column(q, o[1], nc)).collect()]
    };
    let [mut wrap_b, mut wrap_c] = columns(0);

    for t in 0..na {
        let w = dir.weights[t as usize];
        let [now_b, now_c] = columns(t as usize);
        let vacuum = geometry.vacuum_plane(&sweep, t, inputs.occupied);
        let step = PlaneStep { plan, dir, mode, inputs, sweep: &sweep, geometry: &geometry, t, w, birth, vacuum };
        radiance
            .par_chunks_mut(lb_us)
            .zip(average.par_chunks_mut(lb_us))
            .zip(born.par_iter_mut().zip(left.par_iter_mut()))
            .enumerate()
            .for_each(|(q, ((l_row, avg_row), (born_row, left_row)))| {
                let (cc, row_wrap) = now_c[q];
                let row_wrapped = row_wrap != wrap_c[q].1;
                for (p, &(cb, wrap)) in now_b.iter().enumerate() {
                    let wrapped = t > 0 && (row_wrapped || wrap != wrap_b[p].1);
                    let (l, avg) = (&mut l_row[p], &mut avg_row[p]);
                    step.ray([cb, cc], wrapped, l, avg, born_row, left_row);
                }
            });
        (wrap_b, wrap_c) = (now_b, now_c);
        if !vacuum {
            collect_plane(plan, dir, &sweep, &geometry, t, &average, inputs, outputs);
        }
    }
    // Rays still inside leave through the far face.
    for (q, row) in radiance.chunks(lb_us).enumerate() {
        for l in row {
            for ch in 0..c {
                left[q][ch] += l[ch];
            }
        }
    }
    let mut tallies = Tallies::default();
    for ch in 0..c {
        let born: f64 = born.iter().map(|r| r[ch]).sum();
        let left: f64 = left.iter().map(|r| r[ch]).sum();
        tallies.boundary_in[ch] = born * dir.power_per_radiance;
        tallies.boundary_out[ch] = left * dir.power_per_radiance;
    }
    tallies
}

/// A slot's lattice column in a plane and how often it has wrapped ([`lattice_column`]).
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
}

impl PlaneStep<'_, '_> {
    /// Advances the ray at lattice column `[cb, cc]` through the plane: rebirth after a wrap,
    /// gather, exact segment.
    fn ray(
        &self,
        [cb, cc]: [u32; 2],
        wrapped: bool,
        l: &mut [f64; 3],
        avg: &mut [f64; 3],
        born: &mut [f64; 3],
        left: &mut [f64; 3],
    ) {
        let c = self.plan.channels as usize;
        if wrapped {
            // The ray left through a side: a new one enters from the opposite side.
            for ch in 0..c {
                left[ch] += l[ch];
                l[ch] = self.birth[ch];
                born[ch] += self.birth[ch];
            }
        }
        if self.vacuum {
            return;
        }
        let [nb, nc] = [self.sweep.n[1], self.sweep.n[2]];
        let comps = self.plan.source_components() as usize;
        let k0 = self.dir.gain_storage as usize * c;
        let mut rho = 0.0;
        let mut j = [0.0f64; 3];
        for (vc, tc) in taps(cc, self.w[1], nc) {
            for (vb, tb) in taps(cb, self.w[0], nb) {
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
        let mode_exp = std::env::var("LPM_EXP_SLOPE").unwrap_or_default();
        let mut slope = [0.0f64; 3];
        if self.mode.gain && !mode_exp.is_empty() && mode_exp != "none" {
            let o = |t: u32| self.dir.offsets[t as usize];
            let prev = if wrapped || self.t == 0 {
                [0.0; 3]
            } else {
                let (ot, op) = (o(self.t), o(self.t - 1));
                self.gather_j(self.t - 1, [cb as i64 - (ot[0] - op[0]) as i64, cc as i64 - (ot[1] - op[1]) as i64])
            };
            let next = if self.t + 1 >= self.sweep.n[0] {
                [0.0; 3]
            } else {
                let (ot, on) = (o(self.t), o(self.t + 1));
                self.gather_j(self.t + 1, [cb as i64 + (on[0] - ot[0]) as i64, cc as i64 + (on[1] - ot[1]) as i64])
            };
            for ch in 0..c {
                let (a, b) = (j[ch] - prev[ch], next[ch] - j[ch]);
                slope[ch] = match mode_exp.as_str() {
                    "central" => 0.5 * (a + b),
                    "up" => a,
                    "down" => b,
                    "neg" => -0.5 * (a + b),
                    "minmod" => {
                        if a * b <= 0.0 {
                            0.0
                        } else if a.abs() < b.abs() {
                            a
                        } else {
                            b
                        }
                    }
                    "mc" => {
                        if a * b <= 0.0 {
                            0.0
                        } else {
                            a.signum() * (0.5 * (a + b)).abs().min(2.0 * a.abs()).min(2.0 * b.abs())
                        }
                    }
                    _ => panic!("slope"),
                };
            }
        }
        for ch in 0..c {
            let (st, _, sa) = self.plan.coefficients(ch);
            let mut jc = j[ch];
            if self.mode.gain && self.mode.emit {
                jc += rho * sa * self.plan.medium.emission[ch];
            }
            let (out, a) = if slope[ch] != 0.0 {
                segment_linear(l[ch], jc, slope[ch], rho * st, self.dir.path_length)
            } else {
                segment(l[ch], jc, rho * st, self.dir.path_length)
            };
            l[ch] = out;
            avg[ch] = a;
        }
    }
}

impl PlaneStep<'_, '_> {
    fn gather_j(&self, t: u32, col: [i64; 2]) -> [f64; 3] {
        let [nb, nc] = [self.sweep.n[1], self.sweep.n[2]];
        let mut j = [0.0; 3];
        if col[0] < 0 || col[0] > nb as i64 || col[1] < 0 || col[1] > nc as i64 {
            return j;
        }
        let c = self.plan.channels as usize;
        let comps = self.plan.source_components() as usize;
        let k0 = self.dir.gain_storage as usize * c;
        let w = self.dir.weights[t as usize];
        for (vc, tc) in taps(col[1] as u32, w[1], nc) {
            for (vb, tb) in taps(col[0] as u32, w[0], nb) {
                let v = self.geometry.index(self.sweep.voxel(t, vb, vc));
                for ch in 0..c {
                    j[ch] += tb * tc * self.inputs.gained[v * comps + k0 + ch];
                }
            }
        }
        j
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
            // slot at lattice column ℓ is s = (ℓ − o − 1) mod (n + 1). Taps of weight 0 are left
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
