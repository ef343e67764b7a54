//! The CPU twin: the GPU kernels' discretisation in plain Rust and f64, the reference the GPU is
//! tested against, selectable with `--backend cpu`.
//!
//! It walks exactly the voxels the GPU walks (same offset tables, same wrap rule, same segment
//! formulas, empty bricks skipped) but keeps every field in memory, so it is meant for volumes that
//! fit in RAM. Its sweep (`solver/cpu_sweep.rs`) reads like the two kernels: per plane, a step of
//! every ray (`glsl/propagate.comp`) and a collect of every voxel (`glsl/collect.comp`), each on
//! every core of the current rayon pool, with the same bits at any thread count. When the plan stores the gained source in
//! f16, the twin rounds it exactly where the GPU does: once per order, before the rays gain it,
//! with the same power-of-two scale (the GPU rounds its f32 sums, the twin its f64 ones).
//!
//! Its fields are the GPU driver's set ([`OrderFieldSet`]) kept in memory in f64, `[voxel][component]`;
//! the host passes between orders are the order loop's, shared with the GPU driver
//! ([`super::passes`]).

use super::cpu_sweep::{sweep_direction, SweepInputs, SweepMode, SweepOutputs};
use super::energy::Tallies;
use super::exitance::ExitMaps;
use super::mirror::MirrorState;
use super::orders::Backend;
use super::passes::{MemField, OrderFieldSet, VoxelMedium};
use super::periodic::{CarryOf, PeriodicCarry};
use super::plan::{half_scale_exponent, Plan, Precision, SweepDirection};
use super::SolveError;

pub struct CpuTwin<'a> {
    plan: &'a Plan,
    /// Density per voxel, x fastest.
    medium: VoxelMedium,
    /// Per 16³ brick (x fastest): whether it holds medium. Empty bricks are skipped, as on the GPU.
    occupied: Vec<bool>,
    /// The fields: sources `[voxel][d·C + ch]`, fluence `[voxel][ch]`.
    fields: OrderFieldSet<MemField>,
    /// The source the rays gain when the plan stores it in f16: `source_prev` rounded (else empty).
    j_gain: Vec<f64>,
    /// Power of a per-voxel emission (`solver::emission`), when the first order's source is one.
    emitted_field: Option<[f64; 3]>,
    /// What the rays of periodic-axis sweeps carried out last order ([`super::periodic`]).
    carry: PeriodicCarry,
    /// What the sweeps hand over to their mirror images across mirror faces ([`super::mirror`]).
    mirror: MirrorState,
    /// Where the light left, per boundary pixel of each face, over every sweep so far
    /// ([`super::exitance`]).
    exits: ExitMaps,
    /// Looked at before each direction's sweep (SIGTERM): the twin keeps no checkpoint, so a
    /// cancelled solve stops there with nothing to resume from.
    cancel: Option<super::cancel::CancelFlag>,
}

/// The twin's view of a volume's density: per voxel (x fastest, then y, z) in f64, and per brick
/// of the store's grid whether it holds medium (the store's own rule: any voxel non-zero).
/// `density(v)` gives the density of voxel v = (x, y, z).
pub(super) fn dense_density(dims: [u32; 3], density: impl Fn([u32; 3]) -> f32) -> (Vec<f64>, Vec<bool>) {
    let [nx, ny, nz] = dims;
    let grid = crate::store::BrickGrid::new(dims);
    let mut occupied = vec![false; grid.brick_count()];
    let mut values = Vec::with_capacity(nx as usize * ny as usize * nz as usize);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let rho = density([x, y, z]);
                if rho != 0.0 {
                    occupied[grid.locate([x, y, z]).0] = true;
                }
                values.push(rho as f64);
            }
        }
    }
    (values, occupied)
}

impl<'a> CpuTwin<'a> {
    /// `density(v)` gives the density of voxel v = (x, y, z).
    pub fn new(plan: &'a Plan, density: impl Fn([u32; 3]) -> f32) -> Result<Self, SolveError> {
        let [nx, ny, nz] = plan.dims;
        let voxels = nx as usize * ny as usize * nz as usize;
        let comps = plan.source_components() as usize;
        let half = plan.source_precision == Precision::F16;
        // Previous, next, scratch, total and spare sources (and the rounded one); order, total and
        // spare fluence; density.
        let sources = if half { 6 } else { 5 };
        let bytes = voxels as u128 * (sources * comps + 3 * plan.channels as usize + 1) as u128 * 8;
        if bytes > 16 << 30 {
            return Err(SolveError::TooLargeForCpu { bytes: bytes as u64 });
        }
        let (values, occupied) = dense_density(plan.dims, density);
        Ok(CpuTwin {
            plan,
            medium: VoxelMedium { density: values, albedo: Vec::new(), dims: plan.dims },
            occupied,
            fields: OrderFieldSet::in_memory(plan, voxels),
            j_gain: if half { vec![0.0; voxels * comps] } else { Vec::new() },
            emitted_field: None,
            carry: PeriodicCarry::new(plan),
            mirror: MirrorState::new(plan),
            exits: ExitMaps::new(plan.dims, plan.channels as usize),
            cancel: None,
        })
    }

    /// Stops the solve before the next direction's sweep once `cancel` is raised.
    pub fn set_cancel(&mut self, cancel: Option<super::cancel::CancelFlag>) {
        self.cancel = cancel;
    }

    fn check_cancel(&self) -> Result<(), SolveError> {
        match self.cancel {
            Some(c) if c.is_raised() => Err(SolveError::Cancelled { resumable: false }),
            _ => Ok(()),
        }
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
                        self.fields.source_prev.values[i * comps as usize + k as usize] =
                            source.value([x, y, z], k) as f64;
                    }
                }
            }
        }
        self.emitted_field = Some(power);
    }

    /// Takes each voxel's albedo factor a(v) from `albedo` (the store's field, as the GPU's host
    /// passes read it): each order's scattered source is multiplied by it and absorption counted
    /// with it ([`super::passes`]).
    pub fn set_albedo(&mut self, albedo: &crate::store::Field) {
        let [nx, ny, nz] = self.plan.dims;
        let mut values = Vec::with_capacity(self.medium.density.len());
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    values.push(albedo.value([x, y, z], 0) as f64);
                }
            }
        }
        self.medium.albedo = values;
    }

    /// Starts order 0's accumulators from `fluence` and `source_next` (store fields, as the GPU's
    /// order 0 starts from them) instead of zero: the point lights' uncollided fluence and first
    /// scattering ([`super::point`]).
    pub fn set_order0_accumulators(&mut self, fluence: &crate::store::Field, source_next: &crate::store::Field) {
        let (c, comps) = (self.plan.channels, self.plan.source_components());
        let [nx, ny, nz] = self.plan.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = self.index([x, y, z]);
                    for ch in 0..c {
                        self.fields.fluence.values[i * c as usize + ch as usize] = fluence.value([x, y, z], ch) as f64;
                    }
                    for k in 0..comps {
                        self.fields.source_next.values[i * comps as usize + k as usize] =
                            source_next.value([x, y, z], k) as f64;
                    }
                }
            }
        }
    }

    fn index(&self, v: [u32; 3]) -> usize {
        let [nx, ny, _] = self.plan.dims;
        v[0] as usize + nx as usize * (v[1] as usize + ny as usize * v[2] as usize)
    }

    /// Fluence of voxel v, channel ch.
    pub fn fluence(&self, v: [u32; 3], ch: usize) -> f64 {
        self.fields.fluence_total.values[self.index(v) * self.plan.channels as usize + ch]
    }

    /// The per-face exitance maps over every order propagated so far: each face's sum is its
    /// `power_out` in the energy books ([`super::exitance`]).
    pub fn exit_maps(&self) -> &ExitMaps {
        &self.exits
    }

    /// Summed in-scattered source of voxel v, component d·C + ch.
    pub fn source(&self, v: [u32; 3], component: usize) -> f64 {
        self.fields.source_total.values[self.index(v) * self.plan.source_components() as usize + component]
    }

    /// Marches every ray of one direction through the whole volume, depositing fluence and the next
    /// order's source ([`super::cpu_sweep`]: plane by plane, on the current rayon pool's threads).
    /// `of`: which sweep's rays periodic axes carry and mirrors hand over (`None`: the sky's own
    /// directions, which neither touches). `boundary`: rays are born carrying the direction's
    /// boundary radiance (else zero); `gain`: rays gain the previous order's source (and the
    /// emission when `emit`).
    fn sweep(&mut self, dir: &SweepDirection, of: Option<CarryOf>, boundary: bool, gain: bool, emit: bool) -> Tallies {
        let fields = &mut self.fields;
        let gained = if self.j_gain.is_empty() { &fields.source_prev.values } else { &self.j_gain };
        let inputs = SweepInputs { density: &self.medium.density, gained, occupied: &self.occupied };
        let mut outputs = SweepOutputs {
            fluence_order: &mut fields.fluence.values,
            j_next: &mut fields.source_next.values,
            exits: &mut self.exits,
        };
        let birth = if boundary { dir.boundary } else { [0.0; 3] };
        // With mirror faces, a face's direction hands over to and from its mirror images.
        let mirrored = match of {
            Some(CarryOf::Face { face, dir }) if !self.plan.mirrors.is_empty() => Some((face, dir)),
            _ => None,
        };
        let mirror = mirrored.map(|(face, dir)| self.mirror.view(self.plan, face, dir));
        let entry = mirror
            .as_ref()
            .and_then(|m| m.entry_radiance(dir))
            .or_else(|| of.and_then(|of| self.carry.entry(self.plan, of, dir, birth)));
        let mode = SweepMode { boundary, gain, emit };
        let (tallies, exits, records) =
            sweep_direction(self.plan, dir, mode, entry.as_deref(), mirror.as_ref(), &inputs, &mut outputs);
        if let Some(of) = of {
            self.carry.store_exit(self.plan, of, dir, exits);
        }
        if let Some((face, dir)) = mirrored {
            self.mirror.store(face, dir, records);
        }
        tallies
    }
}

impl Backend for CpuTwin<'_> {
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        let mut tallies = Tallies::default();
        self.fields.begin_order(true)?;
        self.mirror.begin_order();
        if plan.source_precision == Precision::F16 {
            // What the GPU's copy workers do to the source during the gather.
            let prev = &self.fields.source_prev.values;
            let largest = prev.iter().fold(0f64, |m, &j| m.max(j.abs()));
            let e = half_scale_exponent(largest as f32);
            let (scale, unscale) = (2f64.powi(e), 2f64.powi(-e));
            for (g, &j) in self.j_gain.iter_mut().zip(prev) {
                *g = half::f16::from_f64(j * scale).to_f64() * unscale;
            }
        }
        for (b, beam) in plan.beams.iter().enumerate() {
            if plan.beam_swept_in(b, order) {
                self.check_cancel()?;
                tallies.add(&self.sweep(beam, Some(CarryOf::Beam(b)), order == 0, false, false));
            }
        }
        // The sky's own directions (plan docs): order 0 only, boundary light only, and nothing
        // carried or handed over (no periodic or mirror faces then).
        for dir in plan.sky_faces.iter().flatten().filter(|_| order == 0) {
            self.check_cancel()?;
            tallies.add(&self.sweep(dir, None, true, false, false));
        }
        // The scattered light's own directions (plan docs): orders 1 and 2 along them instead of
        // the k×k, with nothing carried (no periodic or mirror faces then).
        if plan.sweeps_scattered_in(order) {
            for dir in plan.scattered_faces.iter().flatten() {
                self.check_cancel()?;
                tallies.add(&self.sweep(dir, None, false, true, false));
            }
            return Ok(tallies);
        }
        for (face, dirs) in plan.faces.iter().enumerate() {
            for (d, dir) in dirs.iter().enumerate() {
                let of = Some(CarryOf::Face { face, dir: d });
                self.check_cancel()?;
                tallies.add(&self.sweep(dir, of, order == 0, true, order == 0 && plan.emission));
            }
        }
        Ok(tallies)
    }

    type Field = MemField;
    type Medium = VoxelMedium;

    fn fields(&mut self) -> (&mut OrderFieldSet<MemField>, &VoxelMedium) {
        (&mut self.fields, &self.medium)
    }

    fn carried_power(&self) -> [f64; 3] {
        let (carried, mirrored) = (self.carry.power(self.plan), self.mirror.power(self.plan));
        [0, 1, 2].map(|ch| carried[ch] + mirrored[ch])
    }

    fn emission_field_power(&mut self) -> Result<Option<[f64; 3]>, SolveError> {
        Ok(self.emitted_field)
    }
    // No checkpoints: the fields live in this process only (`--resume` needs the GPU).
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
                            dst[ch * crate::store::BRICK_VOXELS + local] =
                                self.fields.fluence_total.values[i * c + ch] as f32;
                        }
                    }
                    if let Some(dst) = fields.source_total.brick_mut(brick) {
                        for k in 0..comps {
                            dst[k * crate::store::BRICK_VOXELS + local] =
                                self.fields.source_total.values[i * comps + k] as f32;
                        }
                    }
                }
            }
        }
    }
}
