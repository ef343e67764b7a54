//! The host passes between orders, written once for both backends: commit an order, add the
//! geometric tail, the remaining error of the stop rule, and the energy books.
//!
//! A per-voxel albedo (`volume.albedo_*`) lives here too: the sweeps scatter with the medium's
//! albedo, and the commit multiplies each voxel's new source by its factor a(v) before anything
//! reads it (the stop rule, the tail, checkpoints and the next order all see the scaled source);
//! absorption in the energy books uses σa(v) = ρ·(σt − σs·a(v)).
//!
//! Both backends keep the same set of fields ([`OrderFieldSet`]): the previous and next source (and a
//! scratch source the diffusion correction writes into, [`super::antidiffusion`]), this order's
//! fluence, the committed totals and a spare copy of each total. They differ only in
//! where a field lives and in what precision: the GPU driver's are memory-mapped files of f32 in
//! the brick store ([`crate::store::Field`]), the CPU twin's vectors of f64 in memory
//! ([`MemField`]). Both implement [`FieldPlanes`]: a field is a run of *units* (a brick of the
//! store; a voxel for the twin, whose fields are `[voxel][component]`), each unit `components`
//! blocks of `unit_voxels` values, component-major. The passes walk units in groups of
//! [`RELEASE_UNITS`], handing back the pages of a group when done with it (a no-op in memory), so
//! a pass over fields far larger than RAM keeps the resident set bounded.
//!
//! The passes run on every core (rayon), each group of units split across threads, yet their
//! results do not depend on the number of threads: element-wise updates are independent, and every
//! sum is first taken per block or unit in a fixed order, then added up in unit order on one thread.
//!
//! Each pass does its arithmetic in the fields' own precision (`t + f·l` in f32 for the store, in
//! f64 for the twin) and sums into f64, so the store's results are bitwise what they were before
//! the passes were shared, and the twin stays an f64 reference. A warm start's first commit
//! ([`super::warm`]) and its signed last power are passes here too (store only, in practice: the
//! twin starts cold).

use super::acceleration::Acceleration;
use super::antidiffusion::{self, VoxelUnits};
use super::plan::Plan;
use super::remaining::{self, RemainingError, UnitTally};
use super::SolveError;
use crate::store::{BrickStore, Field, BRICK_VOXELS};
use rayon::prelude::*;
use std::ops::{Add, Mul, Sub};

/// Units a pass walks before handing their pages back (see [`crate::store::Field`] on resident
/// memory): a few tens of MiB per field of bricks.
pub const RELEASE_UNITS: usize = 1024;

/// Values a task of a parallel pass handles at least: below this, handing work to another thread
/// costs more than it saves (the twin's units are single voxels).
const VALUES_PER_TASK: usize = 4096;

/// The fewest items of `len` values each a parallel task takes.
fn min_items(len: usize) -> usize {
    (VALUES_PER_TASK / len.max(1)).max(1)
}

/// A value of a field: f32 in the brick store, f64 in the twin.
pub trait Value:
    Copy + Send + Sync + PartialOrd + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    /// `v` rounded to this precision (`as` semantics).
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
}

impl Value for f32 {
    const ZERO: f32 = 0.0;
    const ONE: f32 = 1.0;
    fn from_f64(v: f64) -> f32 {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
}

impl Value for f64 {
    const ZERO: f64 = 0.0;
    const ONE: f64 = 1.0;
    fn from_f64(v: f64) -> f64 {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// One field as the passes see it: `units()` units of `components × unit_voxels` values each,
/// component-major within a unit, all in one slice.
pub trait FieldPlanes {
    type V: Value;
    /// Voxels per unit (per component block).
    fn unit_voxels(&self) -> usize;
    fn components(&self) -> usize;
    fn values(&self) -> &[Self::V];
    fn values_mut(&mut self) -> &mut [Self::V];
    /// Hands back the resident pages of units `first .. first + count` (the values are kept).
    fn release(&self, first: usize, count: usize);
    /// Hands back every resident page.
    fn release_all(&self);
    /// Sets every value to zero.
    fn clear(&mut self) -> Result<(), SolveError>;

    /// Values per unit.
    fn unit_len(&self) -> usize {
        self.components() * self.unit_voxels()
    }
    fn units(&self) -> usize {
        self.values().len().checked_div(self.unit_len()).unwrap_or(0)
    }
}

impl FieldPlanes for Field {
    type V = f32;
    fn unit_voxels(&self) -> usize {
        BRICK_VOXELS
    }
    fn components(&self) -> usize {
        Field::components(self) as usize
    }
    fn values(&self) -> &[f32] {
        self.as_slice()
    }
    fn values_mut(&mut self) -> &mut [f32] {
        self.as_mut_slice()
    }
    fn release(&self, first: usize, count: usize) {
        self.release_stored(first, count);
    }
    fn release_all(&self) {
        Field::release_all(self);
    }
    fn clear(&mut self) -> Result<(), SolveError> {
        Ok(self.fill_zero()?)
    }
}

/// A field in memory, in f64, one unit per voxel: value `v·components + k` is component k of
/// voxel v (the twin's sweep, `super::cpu_sweep`, indexes it so).
pub struct MemField {
    pub values: Vec<f64>,
    components: usize,
}

impl MemField {
    pub fn zeros(components: usize, voxels: usize) -> MemField {
        MemField { values: vec![0.0; components * voxels], components }
    }
}

impl FieldPlanes for MemField {
    type V = f64;
    fn unit_voxels(&self) -> usize {
        1
    }
    fn components(&self) -> usize {
        self.components
    }
    fn values(&self) -> &[f64] {
        &self.values
    }
    fn values_mut(&mut self) -> &mut [f64] {
        &mut self.values
    }
    fn release(&self, _first: usize, _count: usize) {}
    fn release_all(&self) {}
    fn clear(&mut self) -> Result<(), SolveError> {
        self.values.iter_mut().for_each(|v| *v = 0.0);
        Ok(())
    }
}

/// The medium's density (and per-voxel albedo factor, when the scene has one) over the same units
/// as the fields: unit `i`'s values.
pub trait Medium: Sync {
    type V: Value;
    fn density(&self, unit: usize) -> Option<&[Self::V]>;
    /// The albedo factor `a(v)` of unit `i`'s voxels (`volume.albedo_*`, see
    /// [`crate::store::albedo`]); `None` everywhere when the albedo is uniform.
    fn albedo(&self, unit: usize) -> Option<&[Self::V]>;
    /// Whether the medium has a per-voxel albedo factor at all.
    fn has_albedo(&self) -> bool;
    /// Hands back every resident page of the density (and the albedo factor).
    fn release_all(&self);
}

/// The store's density over its occupied bricks, in slot order (the order the fields store them).
pub struct StoreMedium<'a> {
    pub(super) store: &'a BrickStore,
    /// The occupied bricks in slot order: unit `i` is brick `bricks[i]`.
    pub(super) bricks: Vec<usize>,
    /// The store's albedo factor field, when the plan has one.
    albedo: Option<Field>,
}

impl<'a> StoreMedium<'a> {
    /// The store's medium; with `plan.albedo_field` its albedo factor field is opened too.
    pub fn new(store: &'a BrickStore, plan: &Plan) -> Result<Self, SolveError> {
        let albedo = if plan.albedo_field { Some(crate::store::albedo::open_albedo(store)?) } else { None };
        Ok(StoreMedium { store, bricks: store.occupied_bricks().collect(), albedo })
    }
}

impl StoreMedium<'_> {
    /// The store's albedo factor field (over the occupied bricks in slot order), when the plan
    /// has one.
    pub fn albedo_field(&self) -> Option<&Field> {
        self.albedo.as_ref()
    }
}

impl Medium for StoreMedium<'_> {
    type V = f32;
    fn density(&self, unit: usize) -> Option<&[f32]> {
        self.store.density_brick(*self.bricks.get(unit)?)
    }
    fn albedo(&self, unit: usize) -> Option<&[f32]> {
        self.albedo.as_ref()?.brick(*self.bricks.get(unit)?)
    }
    fn has_albedo(&self) -> bool {
        self.albedo.is_some()
    }
    fn release_all(&self) {
        self.store.release_all_density();
        if let Some(a) = &self.albedo {
            a.release_all();
        }
    }
}

/// The twin's medium: one unit per voxel, voxels x fastest over `dims`.
pub struct VoxelMedium {
    pub density: Vec<f64>,
    /// The albedo factor per voxel (x fastest), or empty: the albedo is uniform.
    pub albedo: Vec<f64>,
    pub dims: [u32; 3],
}

impl Medium for VoxelMedium {
    type V = f64;
    fn density(&self, unit: usize) -> Option<&[f64]> {
        self.density.get(unit..unit + 1)
    }
    fn albedo(&self, unit: usize) -> Option<&[f64]> {
        self.albedo.get(unit..unit + 1)
    }
    fn has_albedo(&self) -> bool {
        !self.albedo.is_empty()
    }
    fn release_all(&self) {}
}

/// The solver's fields, as both backends keep them.
///
/// Each order accumulates into fields of its own: `source_next` (the next order's source) and
/// `fluence` (this order's fluence), both zero when the order starts. The committed results —
/// `source_total` and `fluence_total` — have a spare copy each: the pass at the end of an order
/// writes `committed + this order` into the spares and swaps, so that until the next commit the
/// fields a checkpoint names are never written (see [`super::fields`]).
pub struct OrderFieldSet<F> {
    /// The source rays gain in this order.
    pub source_prev: F,
    /// The source this order scatters (the next order's), accumulated over the order's sweeps.
    pub source_next: F,
    /// A spare source field: where the diffusion correction writes the corrected `source_next`
    /// when the previous source is not free ([`OrderFieldSet::correct_diffusion`]); its contents
    /// mean nothing between orders.
    pub(crate) source_scratch: F,
    /// This order's fluence, accumulated over its sweeps.
    pub fluence: F,
    /// Committed sums over the completed orders.
    pub source_total: F,
    pub fluence_total: F,
    pub(crate) source_spare: F,
    pub(crate) fluence_spare: F,
    /// The order's accumulators are known to be zero (fresh fields, or just cleared).
    pub(crate) clean: bool,
    /// The order's accumulators hold what was written before its sweeps (the point lights' order
    /// 0, [`super::point`]): a device-resident order loads them instead of starting from zeros.
    pub seeded: bool,
    /// `source_prev` holds a warm start's guess x0 that order 0's commit takes back off (see
    /// [`super::warm`]).
    pub(crate) initial_guess: bool,
    /// The solve started from a guess: its last source is a residual of either sign.
    pub(crate) warm_started: bool,
    /// Which roles hold a field the last checkpoint names, so that orders between checkpoints
    /// never write one (see [`Named`]); all false when no checkpoints are written.
    pub(crate) named: Named,
    /// While the last checkpoint is still being written in the background
    /// ([`super::fields::PendingCheckpoint`]), the roles of the fields the one before it names:
    /// that is the checkpoint a crash would resume from, so nothing writes them either until the
    /// new one is on disk ([`Self::checkpoint_on_disk`]). All false otherwise.
    pub(crate) named_previous: Named,
    /// The diffusion synthetic acceleration's grid and last correction ([`super::acceleration`]),
    /// built at the first commit when the plan accelerates.
    pub(crate) acceleration: Option<Acceleration>,
    /// A resumed solve's last correction (and the file it came from), until the grid is built.
    pub(crate) resumed_correction: Option<(std::path::PathBuf, Vec<f64>)>,
    /// A resumed solve's carried ray state on periodic sweep axes, until the backend takes it.
    pub(crate) resumed_carry: Option<super::periodic::PeriodicCarry>,
    /// A resumed solve's exitance maps of the orders its checkpoint holds, until the backend
    /// takes them (none when the checkpoint kept none).
    pub(crate) resumed_exits: Option<super::exitance::ExitMaps>,
}

/// Per role of [`OrderFieldSet`], whether the field in it is one the last checkpoint named (and
/// must therefore not be written until the next checkpoint replaces it). The flags travel with
/// the fields through every swap of roles. Checkpoints need not follow every order
/// (`solver.checkpoint_every_*`): between two, the commit adds an order into the committed totals
/// in place when their spares are named, and an order's new source goes into the scratch field
/// when the named previous source has come round to the `source_next` role. The values are the
/// same either way (`t + f·l`), so results are bitwise independent of the checkpoint cadence (the
/// diffusion correction too: see `OrderFieldSet::correct_diffusion`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Named {
    pub prev: bool,
    pub next: bool,
    pub scratch: bool,
    /// The committed totals (source and fluence swap together).
    pub total: bool,
    /// Their spare copies.
    pub spare: bool,
}

impl Named {
    /// Right after a checkpoint: it names the previous source and the committed totals.
    pub fn after_checkpoint() -> Named {
        Named { prev: true, total: true, ..Named::default() }
    }
}

/// Where [`OrderFieldSet::correct_diffusion`] left an order's raw (unsharpened) source, which
/// the commit adds to the total.
#[derive(Clone, Copy, Debug)]
enum RawSource {
    Prev,
    Scratch,
}

impl OrderFieldSet<MemField> {
    /// Fresh, zero fields in memory over `voxels` voxels.
    pub fn in_memory(plan: &Plan, voxels: usize) -> Self {
        let (comps, c) = (plan.source_components() as usize, plan.channels as usize);
        OrderFieldSet {
            source_prev: MemField::zeros(comps, voxels),
            source_next: MemField::zeros(comps, voxels),
            source_scratch: MemField::zeros(comps, voxels),
            fluence: MemField::zeros(c, voxels),
            source_total: MemField::zeros(comps, voxels),
            fluence_total: MemField::zeros(c, voxels),
            source_spare: MemField::zeros(comps, voxels),
            fluence_spare: MemField::zeros(c, voxels),
            clean: true,
            seeded: false,
            initial_guess: false,
            warm_started: false,
            named: Named::default(),
            named_previous: Named::default(),
            acceleration: None,
            resumed_correction: None,
            resumed_carry: None,
            resumed_exits: None,
        }
    }
}

impl<F: FieldPlanes> OrderFieldSet<F> {
    /// Clears the order's accumulators before an order starts (after any checkpoint is written:
    /// until then they hold what the previous checkpoint names). With `clear_on_host` false the
    /// backend starts them from zeros itself and overwrites them whole at the end of the order
    /// (the GPU's resident mode), so the host copies are left as they are.
    pub fn begin_order(&mut self, clear_on_host: bool) -> Result<(), SolveError> {
        if self.named.next || self.named_previous.next {
            // The checkpoint's previous source came round to this role (no checkpoint after the
            // last order, or the last one is still being written): accumulate into the scratch
            // field instead (see [`Named`]).
            std::mem::swap(&mut self.source_next, &mut self.source_scratch);
            self.swap_named(|n| std::mem::swap(&mut n.next, &mut n.scratch));
            self.clean = false;
        }
        debug_assert!(!self.named.next && !self.named_previous.next, "an order would write a field a checkpoint names");
        if !self.clean && clear_on_host {
            self.source_next.clear()?;
            self.fluence.clear()?;
            self.clean = true;
            self.seeded = false;
        }
        Ok(())
    }

    /// Marks `source_prev` as a warm start's guess x0 ([`super::warm::seed`] wrote it): order 0's
    /// commit takes it back off the new source.
    pub fn mark_initial_guess(&mut self) {
        self.initial_guess = true;
        self.warm_started = true;
    }

    /// The end-of-order pass: with a per-voxel albedo, first multiplies the new source by each
    /// voxel's albedo factor a(v) (the sweeps scattered with `medium.albedo`; see
    /// `scale_by_albedo`), and at high albedo folds in the acceleration. With the diffusion
    /// correction on, then writes into a free field the change the new source makes to the
    /// sharpened total: that change is what the next order propagates, while the raw source is
    /// what the total takes (so the series converges to one answer whatever its path; see
    /// [`antidiffusion`]). Then commits the order's fluence and source into the spare copies, makes
    /// them the committed ones and the new source the next order's previous one, and returns the
    /// new source's scattered power per channel: Σ|J|·Ω·h³, the norm the ratio and the tail are
    /// estimated from (for a cold solve J ≥ 0 and this is the power itself). After the first order
    /// of a warm start the new source is the residual r = (b + K x0) − x0: the guess x0, still in
    /// `source_prev`, is subtracted from it once the total has taken the whole (see
    /// [`super::warm`]). The order's accumulators are cleared by [`OrderFieldSet::begin_order`],
    /// after any checkpoint is written: until then they still hold what the previous checkpoint
    /// names.
    pub fn commit_order<U: VoxelUnits<V = F::V> + Medium<V = F::V>>(
        &mut self,
        plan: &Plan,
        units: &U,
    ) -> Result<[f64; 3], SolveError>
    where
        F: Sync + Send,
    {
        debug_assert!(
            self.named_previous == Named::default(),
            "the commit would run before the pending checkpoint is on disk"
        );
        if units.has_albedo() {
            scale_by_albedo(&mut self.source_next, units);
        }
        if self.acceleration_due(plan, units)? {
            if let Some(acceleration) = self.acceleration.as_mut() {
                acceleration.fold(plan, units, &mut self.fluence, &mut self.source_next);
            }
        }
        // With the diffusion correction the next order propagates C(T + S) − C(T), the change S
        // makes to the sharpened total, while the total takes the order's raw source S (see
        // [`antidiffusion`], "Positive, and independent of the path"): `raw` is where the
        // correction left S.
        let raw = if plan.diffusion_correction.iter().any(|&k| k > 0.0) {
            Some(self.correct_diffusion(plan, units)?)
        } else {
            None
        };
        let mut power = [0.0; 3];
        // Into the spares, unless they are what the last checkpoint names: then in place.
        let in_place = self.named.spare;
        let committed = match raw {
            None => &self.source_next,
            Some(RawSource::Prev) => &self.source_prev,
            Some(RawSource::Scratch) => &self.source_scratch,
        };
        combine(
            (!in_place).then_some(&mut self.source_spare),
            &mut self.source_total,
            committed,
            |_| F::V::ONE,
            |block, sum| block_power(plan, &mut power, block, sum),
        );
        if self.initial_guess {
            power = [0.0; 3];
            subtract(&mut self.source_next, &self.source_prev, |block, sum| block_power(plan, &mut power, block, sum));
            self.initial_guess = false;
        }
        combine(
            (!in_place).then_some(&mut self.fluence_spare),
            &mut self.fluence_total,
            &self.fluence,
            |_| F::V::ONE,
            |_, _| {},
        );
        if !in_place {
            self.swap_totals();
        }
        std::mem::swap(&mut self.source_prev, &mut self.source_next);
        self.swap_named(|n| std::mem::swap(&mut n.prev, &mut n.next));
        self.clean = false;
        self.seeded = false;
        Ok(power)
    }

    /// Whether this order's commit folds in the diffusion acceleration (the plan accelerates,
    /// and this is not a warm start's first order, whose new source still holds the guess: it is
    /// accelerated from the next order on, once the commit has made the source a residual). The
    /// grid, in `self.acceleration`, is built at the first such commit, with a resumed solve's
    /// last correction.
    pub fn acceleration_due<U: VoxelUnits<V = F::V> + Medium<V = F::V>>(
        &mut self,
        plan: &Plan,
        units: &U,
    ) -> Result<bool, SolveError> {
        if !plan.acceleration || self.initial_guess {
            return Ok(false);
        }
        if self.acceleration.is_none() {
            let resumed = self.resumed_correction.take();
            let (path, values) = resumed.map_or((None, None), |(p, v)| (Some(p), Some(v)));
            let grid = Acceleration::build(plan, units, self.fluence.units(), self.fluence.unit_voxels(), values)
                .map_err(|why| {
                    tracing::error!("{why}");
                    SolveError::CheckpointMismatch { path: path.unwrap_or_default() }
                })?;
            self.acceleration = Some(grid);
        }
        Ok(true)
    }

    /// The diffusion correction ([`antidiffusion::sharpen_increment`]): the change C(T + S) − C(T)
    /// that this order's raw source S makes to the sharpened committed total T (after a warm
    /// start's first order the commit then takes the guess off it) is written into a field that
    /// neither this order nor the last checkpoint needs any more and becomes the new source; the
    /// raw source moves to that field's role, which is returned, for the commit to add to the
    /// total. The order's own previous source is free once its sweeps are done (unless a
    /// checkpoint names it, right after one, or a warm start's first commit still subtracts it);
    /// otherwise the scratch field is, since a checkpoint names one source field at most. So the
    /// correction never forces a checkpoint.
    fn correct_diffusion<U: VoxelUnits<V = F::V>>(&mut self, plan: &Plan, units: &U) -> Result<RawSource, SolveError>
    where
        F: Sync,
    {
        let free = if !self.named.prev && !self.initial_guess {
            RawSource::Prev
        } else if !self.named.scratch {
            RawSource::Scratch
        } else {
            return Err(SolveError::Internal(
                "the diffusion correction found no source field free to write (a checkpoint names two)",
            ));
        };
        let dst = match free {
            RawSource::Prev => &mut self.source_prev,
            RawSource::Scratch => &mut self.source_scratch,
        };
        let how = antidiffusion::Sharpening::of(plan);
        antidiffusion::sharpen_increment(dst, &self.source_total, &self.source_next, units, &how);
        std::mem::swap(&mut self.source_next, dst);
        self.swap_named(|n| match free {
            RawSource::Prev => std::mem::swap(&mut n.next, &mut n.prev),
            RawSource::Scratch => std::mem::swap(&mut n.next, &mut n.scratch),
        });
        Ok(free)
    }

    /// The GPU's resident mode committed the orders since its fields were last here on the device
    /// ([`super::gpu::end_of_order`]): `fill` writes its committed source and fluence, its new
    /// source and its last order's fluence into the host fields it is given (the spares,
    /// `source_next` and `fluence`: none of them named by the last checkpoint, once the one
    /// before it is on disk), which then take the roles [`Self::commit_order`] gives them.
    pub fn take_device_commit(
        &mut self,
        fill: impl FnOnce(&mut F, &mut F, &mut F, &mut F) -> Result<(), SolveError>,
    ) -> Result<(), SolveError> {
        if self.named.spare || self.named.next || self.named_previous != Named::default() {
            return Err(SolveError::Internal("the device's fields would overwrite what a checkpoint names"));
        }
        fill(&mut self.source_spare, &mut self.fluence_spare, &mut self.source_next, &mut self.fluence)?;
        self.swap_totals();
        std::mem::swap(&mut self.source_prev, &mut self.source_next);
        self.swap_named(|n| std::mem::swap(&mut n.prev, &mut n.next));
        self.clean = false;
        self.seeded = false;
        Ok(())
    }

    /// The committed totals and their spares change roles (with their [`Named`] flags).
    fn swap_totals(&mut self) {
        std::mem::swap(&mut self.source_total, &mut self.source_spare);
        std::mem::swap(&mut self.fluence_total, &mut self.fluence_spare);
        self.swap_named(|n| std::mem::swap(&mut n.total, &mut n.spare));
    }

    /// Applies a swap of roles to the flags of both checkpoints (the last and, while it is being
    /// written, the one before it).
    fn swap_named(&mut self, swap: impl Fn(&mut Named)) {
        swap(&mut self.named);
        swap(&mut self.named_previous);
    }

    /// Records that a checkpoint now names the fields in their current roles (see [`Named`]); the
    /// one before it stays protected until [`Self::checkpoint_on_disk`].
    pub fn checkpoint_started(&mut self) {
        self.named_previous = self.named;
        self.named = Named::after_checkpoint();
    }

    /// The checkpoint last started is on disk: the one before it is free to be overwritten.
    pub fn checkpoint_on_disk(&mut self) {
        self.named_previous = Named::default();
    }

    /// The signed power of what no order has propagated yet, per channel, for the energy balance
    /// of a warm start (whose last source is a residual of either sign) or an accelerated solve
    /// (the same, less the light the last correction added: see [`super::acceleration`]). `None`
    /// for a plain cold solve, whose last source's norm is that power.
    pub fn signed_last_power(&self, plan: &Plan) -> Option<[f64; 3]> {
        if !self.warm_started && self.acceleration.is_none() {
            return None;
        }
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let h3 = plan.voxel_size.powi(3);
        let mut power = [0.0; 3];
        let block_len = self.source_prev.unit_voxels();
        for (block, values) in self.source_prev.values().chunks(block_len).enumerate() {
            let k = block % comps;
            power[k % c] += plan.storage.solid_angle[k / c] * h3 * values.iter().map(|&v| v.to_f64()).sum::<f64>();
        }
        self.source_prev.release_all();
        if let Some(acceleration) = &self.acceleration {
            let pending = acceleration.pending_power(plan);
            for (p, q) in power.iter_mut().zip(pending) {
                *p -= q;
            }
        }
        Some(power)
    }

    /// Adds the estimated tail of the order series: `factor[ch]` times the last order's fluence and
    /// the last (unpropagated) source, written into the spare copies so that what a checkpoint
    /// names stays intact (in place if the spares are what it names).
    pub fn apply_tail(&mut self, plan: &Plan, factor: [f64; 3]) {
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let f = |ch: usize| F::V::from_f64(factor[ch]);
        let in_place = self.named.spare;
        combine(
            (!in_place).then_some(&mut self.source_spare),
            &mut self.source_total,
            &self.source_prev,
            |b| f((b % comps) % c),
            |_, _| {},
        );
        combine(
            (!in_place).then_some(&mut self.fluence_spare),
            &mut self.fluence_total,
            &self.fluence,
            |b| f(b % c),
            |_, _| {},
        );
        if !in_place {
            self.swap_totals();
        }
    }

    /// The remaining relative error over the medium's voxels (see [`super::remaining`]): after
    /// [`OrderFieldSet::commit_order`], `fluence_total` holds the sum so far and `fluence` the
    /// newest order's. Two passes: the brightest counted fluence (which sets the dark floor),
    /// then each unit's tally, added up in unit order (as the GPU's resident mode does,
    /// [`super::gpu::end_of_order`]).
    pub fn remaining_error<M: Medium>(&self, medium: &M, plan: &Plan, factor: [f64; 3]) -> RemainingError {
        let c = plan.channels as usize;
        let n = self.fluence.unit_voxels();
        let (total, newest) = (self.fluence_total.values(), self.fluence.values());
        let per_unit = self.fluence.unit_len();
        let units = self.fluence.units();
        // Calls `visit(channel, t, k)` for each medium voxel of `unit`, channel by channel.
        let walk = |unit: usize, visit: &mut dyn FnMut(usize, f64, f64)| {
            let Some(density) = medium.density(unit) else { return };
            let (total, newest) = (&total[unit * per_unit..], &newest[unit * per_unit..]);
            for ch in 0..c {
                let range = ch * n..(ch + 1) * n;
                for ((&rho, &t), &k) in density.iter().zip(&total[range.clone()]).zip(&newest[range]) {
                    if rho > M::V::ZERO {
                        visit(ch, t.to_f64(), k.to_f64());
                    }
                }
            }
        };
        let release = || {
            medium.release_all();
            self.fluence_total.release_all();
            self.fluence.release_all();
        };
        let mut brightest = 0.0f64;
        for first in (0..units).step_by(RELEASE_UNITS) {
            let part = (first..(first + RELEASE_UNITS).min(units))
                .into_par_iter()
                .with_min_len(min_items(per_unit))
                .map(|unit| {
                    let mut b = 0.0f64;
                    walk(unit, &mut |_, t, _| {
                        let t = t.abs();
                        if remaining::counts(t) {
                            b = b.max(t);
                        }
                    });
                    b
                })
                .reduce(|| 0.0, f64::max);
            brightest = brightest.max(part);
            release();
        }
        let floor = remaining::dark_floor(brightest);
        let mut all = UnitTally::default();
        let mut parts = Vec::new();
        for first in (0..units).step_by(RELEASE_UNITS) {
            (first..(first + RELEASE_UNITS).min(units))
                .into_par_iter()
                .with_min_len(min_items(per_unit))
                .map(|unit| {
                    let mut tally = UnitTally::default();
                    walk(unit, &mut |ch, t, k| tally.add(t, k, factor[ch], floor));
                    tally
                })
                .collect_into_vec(&mut parts);
            for part in parts.drain(..) {
                all.merge(part);
            }
            release();
        }
        all.finish()
    }

    /// Power emitted in order 0 and absorbed over all committed orders, per channel.
    pub fn emitted_and_absorbed<M: Medium>(&self, medium: &M, plan: &Plan) -> ([f64; 3], [f64; 3]) {
        let c = plan.channels as usize;
        let n = self.fluence_total.unit_voxels();
        let h3 = plan.voxel_size.powi(3);
        let four_pi: f64 = plan.storage.solid_angle.iter().sum();
        let (mut emitted, mut absorbed) = ([0.0; 3], [0.0; 3]);
        let per_unit = self.fluence_total.unit_len();
        let values = self.fluence_total.values();
        let units = self.fluence_total.units();
        let albedo_grid = medium.has_albedo();
        let mut sums = Vec::new();
        for first in (0..units).step_by(RELEASE_UNITS) {
            // Per unit and channel: Σρ and Σ(σa-weighted) ρ·φ, each summed over the unit's voxels in
            // order; then added up in unit order below.
            (first..(first + RELEASE_UNITS).min(units))
                .into_par_iter()
                .with_min_len(min_items(per_unit))
                .map(|unit| {
                    let mut unit_sums = [(0.0f64, 0.0f64); 3];
                    let density = medium.density(unit)?;
                    let phi = &values[unit * per_unit..(unit + 1) * per_unit];
                    let albedo = medium.albedo(unit);
                    for (ch, sums) in unit_sums.iter_mut().enumerate().take(c) {
                        let (st, ss, _) = plan.coefficients(ch);
                        let phi = &phi[ch * n..(ch + 1) * n];
                        let (mut rho_sum, mut rho_phi) = (0.0, 0.0);
                        if let Some(albedo) = albedo {
                            // σa(v) per unit density = σt − σs·a(v), the same expression as the
                            // emission's source (`solver::emission`).
                            for ((&rho, &f), &a) in density.iter().zip(phi).zip(albedo) {
                                rho_sum += rho.to_f64();
                                rho_phi += (st - ss * a.to_f64()) * rho.to_f64() * f.to_f64();
                            }
                        } else {
                            for (&rho, &f) in density.iter().zip(phi) {
                                rho_sum += rho.to_f64();
                                rho_phi += rho.to_f64() * f.to_f64();
                            }
                        }
                        *sums = (rho_sum, rho_phi);
                    }
                    Some(unit_sums)
                })
                .collect_into_vec(&mut sums);
            for unit_sums in sums.drain(..).flatten() {
                for (ch, &(rho_sum, rho_phi)) in unit_sums.iter().enumerate().take(c) {
                    let (_, _, sa) = plan.coefficients(ch);
                    absorbed[ch] += if albedo_grid { rho_phi * h3 } else { sa * rho_phi * h3 };
                    if plan.emission {
                        emitted[ch] += four_pi * sa * plan.medium.emission[ch] * rho_sum * h3;
                    }
                }
            }
            medium.release_all();
            self.fluence_total.release_all();
        }
        (emitted, absorbed)
    }
}

/// Adds one block's Σ|J| to the order's scattered power: the commit's accounting, shared by the
/// host's pass and the device's so that both give the same bits.
pub fn block_power(plan: &Plan, power: &mut [f64; 3], block: usize, sum: f64) {
    let c = plan.channels as usize;
    let k = block % plan.source_components() as usize;
    power[k % c] += plan.storage.solid_angle[k / c] * plan.voxel_size.powi(3) * sum;
}

/// `source[v] ·= a(v)` for every component of every voxel, in the field's precision: the sweeps
/// scatter with `medium.albedo`, a voxel of albedo factor a(v) scatters a(v) of that (and absorbs
/// the rest, which the energy books count with the same a(v)). Done before the diffusion
/// correction, whose fluxes conserve the total they are given: scaling after it would move power
/// between voxels of different albedo and the books would no longer close.
fn scale_by_albedo<F: FieldPlanes, M: Medium<V = F::V>>(source: &mut F, medium: &M) {
    let units = source.units();
    let per_unit = source.unit_len();
    let block_len = source.unit_voxels();
    for first in (0..units).step_by(RELEASE_UNITS) {
        let range = first * per_unit..(first + RELEASE_UNITS).min(units) * per_unit;
        source.values_mut()[range].par_chunks_mut(per_unit).with_min_len(min_items(per_unit)).enumerate().for_each(
            |(i, values)| match medium.albedo(first + i) {
                Some(a) => {
                    for block in values.chunks_mut(block_len) {
                        for (s, &a) in block.iter_mut().zip(a) {
                            *s = *s * a;
                        }
                    }
                }
                // A unit the medium does not hold has no medium, hence no source: keep it zero.
                None => values.iter_mut().for_each(|s| *s = F::V::ZERO),
            },
        );
        source.release(first, RELEASE_UNITS);
        medium.release_all();
    }
}

/// `next −= guess`, block by block; calls `block_sum(block, Σ|next|)` for each block, in block
/// order (a warm start's first commit, see [`OrderFieldSet::commit_order`]).
fn subtract<F: FieldPlanes>(next: &mut F, guess: &F, mut block_sum: impl FnMut(usize, f64)) {
    let units = next.units();
    let per_unit = next.unit_len();
    let block_len = next.unit_voxels();
    let mut block = 0;
    let mut sums = Vec::new();
    for first in (0..units).step_by(RELEASE_UNITS) {
        let range = first * per_unit..(first + RELEASE_UNITS).min(units) * per_unit;
        let (n, g) = (&mut next.values_mut()[range.clone()], &guess.values()[range]);
        n.par_chunks_mut(block_len)
            .zip(g.par_chunks(block_len))
            .with_min_len(min_items(block_len))
            .map(|(n, g)| {
                let mut sum = 0.0;
                for (n, &g) in n.iter_mut().zip(g) {
                    *n = *n - g;
                    sum += n.to_f64().abs();
                }
                sum
            })
            .collect_into_vec(&mut sums);
        for &sum in &sums {
            block_sum(block, sum);
            block += 1;
        }
        next.release(first, RELEASE_UNITS);
        guess.release(first, RELEASE_UNITS);
    }
}

/// `spare = total + factor(block)·last` (or, without a spare, `total += factor(block)·last`: the
/// same values), block by block (one component of one unit each), in the fields' precision; calls
/// `block_sum(block, Σ|last|)` (summed in f64: the norm, as a warm start's residual has either
/// sign; cold sources are ≥ 0) for each block, in block order. With factor 1 this is exactly
/// `total + last`. The fields' pages are handed back every [`RELEASE_UNITS`] units.
fn combine<F: FieldPlanes>(
    mut spare: Option<&mut F>,
    total: &mut F,
    last: &F,
    factor: impl Fn(usize) -> F::V + Sync,
    mut block_sum: impl FnMut(usize, f64),
) {
    let units = total.units();
    let per_unit = total.unit_len();
    let block_len = total.unit_voxels();
    let mut block = 0;
    let mut sums = Vec::new();
    for first in (0..units).step_by(RELEASE_UNITS) {
        let range = first * per_unit..(first + RELEASE_UNITS).min(units) * per_unit;
        let l = &last.values()[range.clone()];
        // (destination, the total it adds to: `None` when the destination is the total itself)
        let (s, t) = match spare.as_deref_mut() {
            Some(spare) => (&mut spare.values_mut()[range.clone()], Some(&total.values()[range])),
            None => (&mut total.values_mut()[range], None),
        };
        let base = block;
        let add = |i: usize, s: &mut [F::V], t: Option<&[F::V]>, l: &[F::V]| {
            let f = factor(base + i);
            let mut sum = 0.0;
            for (j, (s, &l)) in s.iter_mut().zip(l).enumerate() {
                *s = t.map_or(*s, |t| t[j]) + f * l;
                sum += l.to_f64().abs();
            }
            sum
        };
        match t {
            Some(t) => s
                .par_chunks_mut(block_len)
                .zip(t.par_chunks(block_len))
                .zip(l.par_chunks(block_len))
                .with_min_len(min_items(block_len))
                .enumerate()
                .map(|(i, ((s, t), l))| add(i, s, Some(t), l))
                .collect_into_vec(&mut sums),
            None => s
                .par_chunks_mut(block_len)
                .zip(l.par_chunks(block_len))
                .with_min_len(min_items(block_len))
                .enumerate()
                .map(|(i, (s, l))| add(i, s, None, l))
                .collect_into_vec(&mut sums),
        }
        for &sum in &sums {
            block_sum(block, sum);
            block += 1;
        }
        if let Some(spare) = spare.as_deref() {
            spare.release(first, RELEASE_UNITS);
        }
        total.release(first, RELEASE_UNITS);
        last.release(first, RELEASE_UNITS);
    }
}
