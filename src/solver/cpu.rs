//! The CPU twin: the GPU kernels' discretisation in plain Rust and f64, the reference the GPU is
//! tested against, selectable with `--backend cpu`.
//!
//! It walks exactly the voxels the GPU walks (same offset tables, same wrap rule, same segment
//! formulas, empty bricks skipped) but keeps every field in memory, so it is meant for volumes that
//! fit in RAM. Its sweep ([`super::cpu_sweep`]) reads like the two kernels: per plane, a step of
//! every ray (`glsl/propagate.comp`) and a collect of every voxel (`glsl/collect.comp`), each on
//! every core of the current rayon pool, with the same bits at any thread count. When the plan stores the gained source in
//! f16, the twin rounds it exactly where the GPU does: once per order, before the rays gain it,
//! with the same power-of-two scale (the GPU rounds its f32 sums, the twin its f64 ones).

use super::cpu_sweep::{sweep_direction, SweepInputs, SweepMode, SweepOutputs};
use super::energy::Tallies;
use super::fields::LoopState;
use super::orders::{Backend, OrderFields};
use super::plan::{half_scale_exponent, Plan, Precision, SweepDirection};
use super::remaining::{RemainingError, RemainingTally};
use super::SolveError;

pub struct CpuTwin<'a> {
    plan: &'a Plan,
    /// Density per voxel, x fastest.
    density: Vec<f64>,
    /// Per 16³ brick (x fastest): whether it holds medium. Empty bricks are skipped, as on the GPU.
    occupied: Vec<bool>,
    /// Sources per voxel, `[voxel][d·C + ch]`.
    j_prev: Vec<f64>,
    /// The source the rays gain when the plan stores it in f16: `j_prev` rounded (else empty).
    j_gain: Vec<f64>,
    j_next: Vec<f64>,
    j_total: Vec<f64>,
    /// Fluence per voxel, `[voxel][ch]`: over all orders, and of the order being propagated.
    fluence: Vec<f64>,
    fluence_order: Vec<f64>,
    /// Power of a per-voxel emission (`solver::emission`), when the first order's source is one.
    emitted_field: Option<[f64; 3]>,
}

impl<'a> CpuTwin<'a> {
    /// `density(v)` gives the density of voxel v = (x, y, z).
    pub fn new(plan: &'a Plan, density: impl Fn([u32; 3]) -> f32) -> Result<Self, SolveError> {
        let [nx, ny, nz] = plan.dims;
        let voxels = nx as usize * ny as usize * nz as usize;
        let comps = plan.source_components() as usize;
        let half = plan.source_precision == Precision::F16;
        let sources = if half { 4 } else { 3 };
        let bytes = voxels as u128 * (sources * comps + 2 * plan.channels as usize + 1) as u128 * 8;
        if bytes > 16 << 30 {
            return Err(SolveError::TooLargeForCpu { bytes: bytes as u64 });
        }
        let mut values = Vec::with_capacity(voxels);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    values.push(density([x, y, z]) as f64);
                }
            }
        }
        let bricks = plan.dims.map(|n| n.div_ceil(crate::store::BRICK_EDGE) as usize);
        let mut occupied = vec![false; bricks[0] * bricks[1] * bricks[2]];
        for (i, &rho) in values.iter().enumerate() {
            if rho != 0.0 {
                let (x, rest) = (i % nx as usize, i / nx as usize);
                let (y, z) = (rest % ny as usize, rest / ny as usize);
                let e = crate::store::BRICK_EDGE as usize;
                occupied[x / e + bricks[0] * (y / e + bricks[1] * (z / e))] = true;
            }
        }
        Ok(CpuTwin {
            plan,
            density: values,
            occupied,
            j_prev: vec![0.0; voxels * comps],
            j_gain: if half { vec![0.0; voxels * comps] } else { Vec::new() },
            j_next: vec![0.0; voxels * comps],
            j_total: vec![0.0; voxels * comps],
            fluence: vec![0.0; voxels * plan.channels as usize],
            fluence_order: vec![0.0; voxels * plan.channels as usize],
            emitted_field: None,
        })
    }

    /// Starts from the order-0 source in `source` (a store field, as the GPU gains it) instead of
    /// zero: a per-voxel emission, which emits `power` per channel.
    pub fn set_initial_source(&mut self, source: &crate::store::Field, power: [f64; 3]) {
        let comps = self.plan.source_components();
        let [nx, ny, nz] = self.plan.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = self.index([x, y, z]);
                    for k in 0..comps {
                        self.j_prev[i * comps as usize + k as usize] = source.value([x, y, z], k) as f64;
                    }
                }
            }
        }
        self.emitted_field = Some(power);
    }

    fn index(&self, v: [u32; 3]) -> usize {
        let [nx, ny, _] = self.plan.dims;
        v[0] as usize + nx as usize * (v[1] as usize + ny as usize * v[2] as usize)
    }

    /// Fluence of voxel v, channel ch.
    pub fn fluence(&self, v: [u32; 3], ch: usize) -> f64 {
        self.fluence[self.index(v) * self.plan.channels as usize + ch]
    }

    /// Summed in-scattered source of voxel v, component d·C + ch.
    pub fn source(&self, v: [u32; 3], component: usize) -> f64 {
        self.j_total[self.index(v) * self.plan.source_components() as usize + component]
    }

    /// Marches every ray of one direction through the whole volume, depositing fluence and the next
    /// order's source ([`super::cpu_sweep`]: plane by plane, on the current rayon pool's threads).
    /// `boundary`: rays are born carrying the direction's boundary radiance (else zero); `gain`:
    /// rays gain the previous order's source (and the emission when `emit`).
    fn sweep(&mut self, dir: &SweepDirection, boundary: bool, gain: bool, emit: bool) -> Tallies {
        let gained = if self.j_gain.is_empty() { &self.j_prev } else { &self.j_gain };
        let inputs = SweepInputs { density: &self.density, gained, occupied: &self.occupied };
        let mut outputs = SweepOutputs {
            fluence: &mut self.fluence,
            fluence_order: &mut self.fluence_order,
            j_next: &mut self.j_next,
        };
        sweep_direction(self.plan, dir, SweepMode { boundary, gain, emit }, &inputs, &mut outputs)
    }
}

impl Backend for CpuTwin<'_> {
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        let mut tallies = Tallies::default();
        self.fluence_order.iter_mut().for_each(|f| *f = 0.0);
        if plan.source_precision == Precision::F16 {
            // What the GPU's copy workers do to the source during the gather.
            let largest = self.j_prev.iter().fold(0f64, |m, &j| m.max(j.abs()));
            let e = half_scale_exponent(largest as f32);
            let (scale, unscale) = (2f64.powi(e), 2f64.powi(-e));
            for (g, &j) in self.j_gain.iter_mut().zip(&self.j_prev) {
                *g = half::f16::from_f64(j * scale).to_f64() * unscale;
            }
        }
        if order == 0 {
            for beam in &plan.beams {
                tallies.add(&self.sweep(beam, true, false, false));
            }
        }
        for face in &plan.faces {
            for dir in face {
                tallies.add(&self.sweep(dir, order == 0, true, order == 0 && plan.emission));
            }
        }
        Ok(tallies)
    }

    fn fields(&mut self) -> &mut dyn OrderFields {
        self
    }
}

/// The twin keeps its fields in memory, in f64.
impl OrderFields for CpuTwin<'_> {
    fn commit_order(&mut self) -> Result<[f64; 3], SolveError> {
        let c = self.plan.channels as usize;
        let comps = self.plan.source_components() as usize;
        let h3 = self.plan.voxel_size.powi(3);
        let mut power = [0.0; 3];
        for (v, chunk) in self.j_next.chunks(comps).enumerate() {
            for (k, &j) in chunk.iter().enumerate() {
                power[k % c] += self.plan.storage.solid_angle[k / c] * j * h3;
                self.j_total[v * comps + k] += j;
            }
        }
        std::mem::swap(&mut self.j_prev, &mut self.j_next);
        self.j_next.iter_mut().for_each(|j| *j = 0.0);
        Ok(power)
    }

    fn apply_tail(&mut self, factor: [f64; 3]) -> Result<(), SolveError> {
        let c = self.plan.channels as usize;
        let comps = self.plan.source_components() as usize;
        for (k, (t, p)) in self.j_total.iter_mut().zip(&self.j_prev).enumerate() {
            *t += factor[(k % comps) % c] * p;
        }
        for (k, (f, o)) in self.fluence.iter_mut().zip(&self.fluence_order).enumerate() {
            *f += factor[k % c] * o;
        }
        Ok(())
    }

    fn remaining_error(&mut self, factor: [f64; 3]) -> Result<RemainingError, SolveError> {
        let c = self.plan.channels as usize;
        let mut tally = RemainingTally::default();
        for (v, &rho) in self.density.iter().enumerate() {
            if rho > 0.0 {
                for (ch, &f) in factor.iter().enumerate().take(c) {
                    tally.add(self.fluence[v * c + ch], self.fluence_order[v * c + ch], f);
                }
            }
        }
        Ok(tally.finish())
    }

    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError> {
        let plan = self.plan;
        let c = plan.channels as usize;
        let h3 = plan.voxel_size.powi(3);
        let four_pi: f64 = plan.storage.solid_angle.iter().sum();
        let (mut emitted, mut absorbed) = ([0.0; 3], [0.0; 3]);
        for (v, &rho) in self.density.iter().enumerate() {
            for ch in 0..c {
                let sa = rho * plan.coefficients(ch).2;
                if plan.emission {
                    emitted[ch] += four_pi * sa * plan.medium.emission[ch] * h3;
                }
                absorbed[ch] += sa * self.fluence[v * c + ch] * h3;
            }
        }
        Ok((self.emitted_field.unwrap_or(emitted), absorbed))
    }

    fn checkpoint(&mut self, _state: &LoopState) -> Result<(), SolveError> {
        // Nothing to resume from: the fields live in this process only (`--resume` needs the GPU).
        Ok(())
    }
}

impl CpuTwin<'_> {
    /// Writes the fluence and the summed source into the store's fields (as f32).
    pub fn write_into(&self, store: &crate::store::BrickStore, fields: &mut super::fields::StoreFields) {
        let c = self.plan.channels as usize;
        let comps = self.plan.source_components() as usize;
        let [nx, ny, nz] = self.plan.dims;
        let grid = *store.grid();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let v = [x, y, z];
                    let i = self.index(v);
                    let (brick, local) = grid.locate(v);
                    if let Some(dst) = fields.fluence_total.brick_mut(brick) {
                        for ch in 0..c {
                            dst[ch * crate::store::BRICK_VOXELS + local] = self.fluence[i * c + ch] as f32;
                        }
                    }
                    if let Some(dst) = fields.source_total.brick_mut(brick) {
                        for k in 0..comps {
                            dst[k * crate::store::BRICK_VOXELS + local] = self.j_total[i * comps + k] as f32;
                        }
                    }
                }
            }
        }
    }
}
