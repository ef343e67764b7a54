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
//! Each pass does its arithmetic in the fields' own precision (`t + f·l` in f32 for the store, in
//! f64 for the twin) and sums into f64, so the store's results are bitwise what they were before
//! the passes were shared, and the twin stays an f64 reference. A warm start's first commit
//! ([`super::warm`]) and its signed last power are passes here too (store only, in practice: the
//! twin starts cold).

use super::antidiffusion::{self, VoxelUnits};
use super::plan::Plan;
use super::remaining::{RemainingError, RemainingTally};
use super::SolveError;
use crate::store::{BrickStore, Field, BRICK_VOXELS};
use std::ops::{Add, Mul, Sub};

/// Units a pass walks before handing their pages back (see [`crate::store::Field`] on resident
/// memory): a few tens of MiB per field of bricks.
pub const RELEASE_UNITS: usize = 1024;

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
pub trait Medium {
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
    /// Where the end-of-order pass writes the corrected `source_next` before the two swap
    /// ([`super::antidiffusion`]); its contents mean nothing between orders.
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
    /// `source_prev` holds a warm start's guess x0 that order 0's commit takes back off (see
    /// [`super::warm`]).
    pub(crate) initial_guess: bool,
    /// The solve started from a guess: its last source is a residual of either sign.
    pub(crate) warm_started: bool,
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
            initial_guess: false,
            warm_started: false,
        }
    }
}

impl<F: FieldPlanes> OrderFieldSet<F> {
    /// Clears the order's accumulators before an order starts (after any checkpoint is written:
    /// until then they hold what the previous checkpoint names).
    pub fn begin_order(&mut self) -> Result<(), SolveError> {
        if !self.clean {
            self.source_next.clear()?;
            self.fluence.clear()?;
            self.clean = true;
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
    /// `scale_by_albedo`). With the diffusion correction on, then writes the corrected new
    /// source into the scratch field and makes it the new source (the order's own accumulator is
    /// named by no checkpoint, so nothing a resume needs is touched). Then commits the order's
    /// fluence and source into the spare copies, makes
    /// them the committed ones and the new source the next order's previous one, and returns the
    /// new source's scattered power per channel: Σ|J|·Ω·h³, the norm the ratio and the tail are
    /// estimated from (for a cold solve J ≥ 0 and this is the power itself). After the first order
    /// of a warm start the new source is the residual r = (b + K x0) − x0: the guess x0, still in
    /// `source_prev`, is subtracted from it once the total has taken the whole (see
    /// [`super::warm`]). The order's accumulators are cleared by [`OrderFieldSet::begin_order`],
    /// after any checkpoint is written: until then they still hold what the previous checkpoint
    /// names.
    pub fn commit_order<U: VoxelUnits<V = F::V> + Medium<V = F::V>>(&mut self, plan: &Plan, units: &U) -> [f64; 3]
    where
        F: Sync,
    {
        if units.has_albedo() {
            scale_by_albedo(&mut self.source_next, units);
        }
        if plan.diffusion_correction.iter().any(|&k| k > 0.0) {
            antidiffusion::sharpen(&mut self.source_scratch, &self.source_next, units, plan.diffusion_correction);
            std::mem::swap(&mut self.source_next, &mut self.source_scratch);
        }
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let h3 = plan.voxel_size.powi(3);
        let mut power = [0.0; 3];
        let weight = |k: usize| plan.storage.solid_angle[k / c] * h3;
        combine(
            &mut self.source_spare,
            &self.source_total,
            &self.source_next,
            |_| F::V::ONE,
            |block, sum| {
                let k = block % comps;
                power[k % c] += weight(k) * sum;
            },
        );
        if self.initial_guess {
            power = [0.0; 3];
            subtract(&mut self.source_next, &self.source_prev, |block, sum| {
                let k = block % comps;
                power[k % c] += weight(k) * sum;
            });
            self.initial_guess = false;
        }
        combine(&mut self.fluence_spare, &self.fluence_total, &self.fluence, |_| F::V::ONE, |_, _| {});
        std::mem::swap(&mut self.source_total, &mut self.source_spare);
        std::mem::swap(&mut self.fluence_total, &mut self.fluence_spare);
        std::mem::swap(&mut self.source_prev, &mut self.source_next);
        self.clean = false;
        power
    }

    /// The signed scattered power of the last (unpropagated) source, per channel, for a warm
    /// start's energy balance (`None` for a cold solve, whose norm is the power).
    pub fn signed_last_power(&self, plan: &Plan) -> Option<[f64; 3]> {
        if !self.warm_started {
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
        Some(power)
    }

    /// Adds the estimated tail of the order series: `factor[ch]` times the last order's fluence and
    /// the last (unpropagated) source, written into the spare copies so that what a checkpoint
    /// names stays intact.
    pub fn apply_tail(&mut self, plan: &Plan, factor: [f64; 3]) {
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let f = |ch: usize| F::V::from_f64(factor[ch]);
        combine(&mut self.source_spare, &self.source_total, &self.source_prev, |b| f((b % comps) % c), |_, _| {});
        combine(&mut self.fluence_spare, &self.fluence_total, &self.fluence, |b| f(b % c), |_, _| {});
        std::mem::swap(&mut self.source_total, &mut self.source_spare);
        std::mem::swap(&mut self.fluence_total, &mut self.fluence_spare);
    }

    /// The remaining relative error over the medium's voxels (see [`super::remaining`]): after
    /// [`OrderFieldSet::commit_order`], `fluence_total` holds the sum so far and `fluence` the
    /// newest order's.
    pub fn remaining_error<M: Medium>(&self, medium: &M, plan: &Plan, factor: [f64; 3]) -> RemainingError {
        let c = plan.channels as usize;
        let n = self.fluence.unit_voxels();
        let mut tally = RemainingTally::default();
        let (total, newest) = (self.fluence_total.values(), self.fluence.values());
        let per_unit = self.fluence.unit_len();
        for unit in 0..self.fluence.units() {
            if unit % RELEASE_UNITS == 0 {
                medium.release_all();
                self.fluence_total.release_all();
                self.fluence.release_all();
            }
            let Some(density) = medium.density(unit) else { continue };
            let (total, newest) = (&total[unit * per_unit..], &newest[unit * per_unit..]);
            for (ch, &f) in factor.iter().enumerate().take(c) {
                let range = ch * n..(ch + 1) * n;
                for ((&rho, &t), &k) in density.iter().zip(&total[range.clone()]).zip(&newest[range]) {
                    if rho > M::V::ZERO {
                        tally.add(t.to_f64(), k.to_f64(), f);
                    }
                }
            }
        }
        medium.release_all();
        self.fluence_total.release_all();
        self.fluence.release_all();
        tally.finish()
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
        for unit in 0..self.fluence_total.units() {
            if unit % RELEASE_UNITS == 0 {
                medium.release_all();
                self.fluence_total.release_all();
            }
            let Some(density) = medium.density(unit) else { continue };
            let phi = &values[unit * per_unit..(unit + 1) * per_unit];
            let albedo = medium.albedo(unit);
            for ch in 0..c {
                let (st, ss, sa) = plan.coefficients(ch);
                let phi = &phi[ch * n..(ch + 1) * n];
                let (mut rho_sum, mut rho_phi) = (0.0, 0.0);
                if let Some(albedo) = albedo {
                    // σa(v) per unit density = σt − σs·a(v), the same expression as the emission's
                    // source (`solver::emission`).
                    for ((&rho, &f), &a) in density.iter().zip(phi).zip(albedo) {
                        rho_sum += rho.to_f64();
                        rho_phi += (st - ss * a.to_f64()) * rho.to_f64() * f.to_f64();
                    }
                    absorbed[ch] += rho_phi * h3;
                } else {
                    for (&rho, &f) in density.iter().zip(phi) {
                        rho_sum += rho.to_f64();
                        rho_phi += rho.to_f64() * f.to_f64();
                    }
                    absorbed[ch] += sa * rho_phi * h3;
                }
                if plan.emission {
                    emitted[ch] += four_pi * sa * plan.medium.emission[ch] * rho_sum * h3;
                }
            }
        }
        medium.release_all();
        self.fluence_total.release_all();
        (emitted, absorbed)
    }
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
    for unit in 0..units {
        if unit % RELEASE_UNITS == 0 && unit > 0 {
            source.release(unit - RELEASE_UNITS, RELEASE_UNITS);
            medium.release_all();
        }
        let values = &mut source.values_mut()[unit * per_unit..(unit + 1) * per_unit];
        match medium.albedo(unit) {
            Some(a) => {
                for block in values.chunks_mut(block_len) {
                    for (s, &a) in block.iter_mut().zip(a) {
                        *s = *s * a;
                    }
                }
            }
            // A unit the medium does not hold has no medium, hence no source: keep it zero.
            None => values.iter_mut().for_each(|s| *s = F::V::ZERO),
        }
    }
    source.release_all();
    medium.release_all();
}

/// `next −= guess`, block by block; calls `block_sum(block, Σ|next|)` for each block (a warm
/// start's first commit, see [`OrderFieldSet::commit_order`]).
fn subtract<F: FieldPlanes>(next: &mut F, guess: &F, mut block_sum: impl FnMut(usize, f64)) {
    let units = next.units();
    let per_unit = next.unit_len();
    let block_len = next.unit_voxels();
    let mut block = 0;
    for first in (0..units).step_by(RELEASE_UNITS) {
        let range = first * per_unit..(first + RELEASE_UNITS).min(units) * per_unit;
        let (n, g) = (&mut next.values_mut()[range.clone()], &guess.values()[range]);
        for (n, g) in n.chunks_mut(block_len).zip(g.chunks(block_len)) {
            let mut sum = 0.0;
            for (n, &g) in n.iter_mut().zip(g) {
                *n = *n - g;
                sum += n.to_f64().abs();
            }
            block_sum(block, sum);
            block += 1;
        }
        next.release(first, RELEASE_UNITS);
        guess.release(first, RELEASE_UNITS);
    }
}

/// `spare = total + factor(block)·last`, block by block (one component of one unit each), in the
/// fields' precision; calls `block_sum(block, Σ|last|)` (summed in f64: the norm, as a warm
/// start's residual has either sign; cold sources are ≥ 0) for each block. With factor 1 this is
/// exactly `total + last`. The three fields' pages are handed back every [`RELEASE_UNITS`] units.
fn combine<F: FieldPlanes>(
    spare: &mut F,
    total: &F,
    last: &F,
    factor: impl Fn(usize) -> F::V,
    mut block_sum: impl FnMut(usize, f64),
) {
    let units = spare.units();
    let per_unit = spare.unit_len();
    let block_len = spare.unit_voxels();
    let mut block = 0;
    for first in (0..units).step_by(RELEASE_UNITS) {
        let range = first * per_unit..(first + RELEASE_UNITS).min(units) * per_unit;
        let (s, t, l) = (&mut spare.values_mut()[range.clone()], &total.values()[range.clone()], &last.values()[range]);
        for ((s, t), l) in s.chunks_mut(block_len).zip(t.chunks(block_len)).zip(l.chunks(block_len)) {
            let f = factor(block);
            let mut sum = 0.0;
            for ((s, &t), &l) in s.iter_mut().zip(t).zip(l) {
                *s = t + f * l;
                sum += l.to_f64().abs();
            }
            block_sum(block, sum);
            block += 1;
        }
        spare.release(first, RELEASE_UNITS);
        total.release(first, RELEASE_UNITS);
        last.release(first, RELEASE_UNITS);
    }
}
