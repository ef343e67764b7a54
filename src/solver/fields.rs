//! The solver's fields in the brick store, the host pass between orders, and checkpoints.
//!
//! Every field covers the occupied bricks only: empty bricks hold no medium, so nothing scatters
//! there and nothing is solved there (their fluence is exported as NaN, "not solved"). Sources have
//! storage directions × channels components per voxel, fluence has channels.
//!
//! Each order accumulates into fields of its own: `source_next` (the next order's source) and
//! `fluence` (this order's fluence), both zero when the order starts. The committed results —
//! `source_total` and `fluence_total` — have a spare copy each: the pass at the end of an order
//! writes `committed + this order` into the spares, flushes them, and only then writes
//! `checkpoint.json` (atomically) naming the spares as committed. Nothing a checkpoint names is
//! written afterwards until the next checkpoint replaces it, so a solve killed at any moment
//! resumes from its last completed order and ends bitwise identical to an uninterrupted one (which
//! runs the very same passes).

use super::energy::Tallies;
use super::orders::{OrderFields, OrderRecord};
use super::plan::Plan;
use super::SolveError;
use crate::store::{BrickStore, Coverage, Field, StoreError, BRICK_VOXELS};
use serde::{Deserialize, Serialize};
use std::path::Path;

const CHECKPOINT: &str = "checkpoint.json";
/// 2: fluence covers the occupied bricks only (version 1 stored it for every brick).
const CHECKPOINT_VERSION: u32 = 2;

pub struct StoreFields {
    /// The source rays gain in this order.
    pub source_prev: Field,
    /// The source this order scatters (the next order's), accumulated over the order's sweeps.
    pub source_next: Field,
    /// This order's fluence, accumulated over its sweeps.
    pub fluence: Field,
    /// Committed sums over the completed orders.
    pub source_total: Field,
    pub fluence_total: Field,
    source_spare: Field,
    fluence_spare: Field,
    /// The order's accumulators are known to be zero (fresh files, or just cleared).
    clean: bool,
    /// `source_prev` holds a warm start's guess x0 that order 0's commit takes back off (see
    /// [`super::warm`]).
    initial_guess: bool,
    /// The solve started from a guess: its last source is a residual of either sign.
    warm_started: bool,
}

/// The order loop's state after a completed order, as saved in `checkpoint.json`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct LoopState {
    /// Orders completed (the next order to propagate).
    pub orders_done: u32,
    pub tallies: [[f64; 3]; 2],
    pub total_power: [f64; 3],
    pub last_new_power: [f64; 3],
    /// Per channel, the new power of the order before the last, and the ratio of the last two
    /// (for the tail estimate).
    #[serde(default)]
    pub previous_new_power: [f64; 3],
    #[serde(default)]
    pub previous_ratio: [f64; 3],
    pub history: Vec<OrderRecord>,
    /// The solve started from a guess ([`super::warm`]); kept so that a resumed warm solve closes
    /// its energy balance the same way.
    #[serde(default)]
    pub warm_start: bool,
}

impl LoopState {
    pub fn tallies(&self) -> Tallies {
        Tallies { boundary_in: self.tallies[0], boundary_out: self.tallies[1] }
    }
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    version: u32,
    /// Identifies the scene and plan the fields belong to.
    digest: String,
    /// Field file names in their current roles.
    source_prev: String,
    source_next: String,
    source_total: String,
    source_spare: String,
    fluence_total: String,
    fluence_spare: String,
    state: LoopState,
}

impl StoreFields {
    /// Fresh, zero fields.
    pub fn create(store: &BrickStore, plan: &Plan) -> Result<Self, SolveError> {
        let comps = plan.source_components();
        let c = plan.channels;
        Ok(StoreFields {
            source_prev: store.create_field("source_a", comps, Coverage::Occupied)?,
            source_next: store.create_field("source_b", comps, Coverage::Occupied)?,
            fluence: store.create_field("fluence_order", c, Coverage::Occupied)?,
            source_total: store.create_field("total_a", comps, Coverage::Occupied)?,
            source_spare: store.create_field("total_b", comps, Coverage::Occupied)?,
            fluence_total: store.create_field("fluence_a", c, Coverage::Occupied)?,
            fluence_spare: store.create_field("fluence_b", c, Coverage::Occupied)?,
            clean: true,
            initial_guess: false,
            warm_started: false,
        })
    }

    /// Reopens the fields of `store` in the roles its checkpoint names, with the saved loop state;
    /// `None` when the store holds no checkpoint.
    pub fn resume(store: &BrickStore, plan: &Plan, digest: &str) -> Result<Option<(Self, LoopState)>, SolveError> {
        let path = store.dir().join(CHECKPOINT);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(StoreError::Io { path, action: "read", source }.into()),
        };
        let cp: Checkpoint =
            serde_json::from_str(&text).map_err(|source| StoreError::Json { path: path.clone(), source })?;
        if cp.version != CHECKPOINT_VERSION || cp.digest != digest {
            return Err(SolveError::CheckpointMismatch { path });
        }
        let comps = plan.source_components();
        let c = plan.channels;
        let fields = StoreFields {
            source_prev: store.open_field(&cp.source_prev, comps, Coverage::Occupied)?,
            source_next: store.open_field(&cp.source_next, comps, Coverage::Occupied)?,
            fluence: store.open_field("fluence_order", c, Coverage::Occupied)?,
            source_total: store.open_field(&cp.source_total, comps, Coverage::Occupied)?,
            source_spare: store.open_field(&cp.source_spare, comps, Coverage::Occupied)?,
            fluence_total: store.open_field(&cp.fluence_total, c, Coverage::Occupied)?,
            fluence_spare: store.open_field(&cp.fluence_spare, c, Coverage::Occupied)?,
            clean: false,
            initial_guess: false,
            warm_started: cp.state.warm_start,
        };
        // A killed order's partial sums are cleared when the next order begins; the order fields
        // still hold the last completed order's (the tail estimate may need its fluence).
        Ok(Some((fields, cp.state)))
    }

    /// Marks `source_prev` as a warm start's guess x0 ([`super::warm::seed`] wrote it): order 0's
    /// commit takes it back off the new source.
    pub fn mark_initial_guess(&mut self) {
        self.initial_guess = true;
        self.warm_started = true;
    }

    /// The end-of-order pass: commits the order's fluence and source into the spare copies, makes
    /// them the committed ones and the new source the next order's previous one, and returns the
    /// new source's scattered power per channel: Σ|J|·Ω·h³, the norm the ratio and the tail are
    /// estimated from (for a cold solve J ≥ 0 and this is the power itself). After the first order
    /// of a warm start the new source is the residual r = (b + K x0) − x0: the guess x0, still in
    /// `source_prev`, is subtracted from it once the total has taken the whole (see
    /// [`super::warm`]). The order's accumulators are cleared by
    /// [`StoreFields::begin_order`], after any checkpoint is written: until then they still hold
    /// what the previous checkpoint names.
    pub fn commit_order(&mut self, plan: &Plan) -> [f64; 3] {
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let h3 = plan.voxel_size.powi(3);
        let mut power = [0.0; 3];
        let weight = |k: usize| plan.storage.solid_angle[k / c] * h3;
        combine(
            &mut self.source_spare,
            &self.source_total,
            &self.source_next,
            |_| 1.0,
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
        combine(&mut self.fluence_spare, &self.fluence_total, &self.fluence, |_| 1.0, |_, _| {});
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
        for (block, values) in self.source_prev.as_slice().chunks(BRICK_VOXELS).enumerate() {
            let k = block % comps;
            power[k % c] += plan.storage.solid_angle[k / c] * h3 * values.iter().map(|&v| v as f64).sum::<f64>();
        }
        self.source_prev.release_all();
        Some(power)
    }

    /// Flushes the committed state and records it in `checkpoint.json` (atomically).
    pub fn write_checkpoint(&self, dir: &Path, digest: &str, state: &LoopState) -> Result<(), SolveError> {
        for f in [&self.source_prev, &self.source_total, &self.fluence_total, &self.fluence] {
            f.flush()?;
        }
        let mut state = state.clone();
        state.warm_start = self.warm_started;
        let cp = Checkpoint {
            version: CHECKPOINT_VERSION,
            digest: digest.to_string(),
            source_prev: self.source_prev.name().to_string(),
            source_next: self.source_next.name().to_string(),
            source_total: self.source_total.name().to_string(),
            source_spare: self.source_spare.name().to_string(),
            fluence_total: self.fluence_total.name().to_string(),
            fluence_spare: self.fluence_spare.name().to_string(),
            state,
        };
        crate::output::write_json_atomic(&dir.join(CHECKPOINT), &cp).map_err(SolveError::Checkpoint)
    }

    /// Adds the estimated tail of the order series: `factor[ch]` times the last order's fluence and
    /// the last (unpropagated) source, written into the spare copies so that what the checkpoint
    /// names stays intact.
    pub fn apply_tail(&mut self, plan: &Plan, factor: [f64; 3]) {
        let c = plan.channels as usize;
        let comps = plan.source_components() as usize;
        let f = |ch: usize| factor[ch] as f32;
        combine(&mut self.source_spare, &self.source_total, &self.source_prev, |b| f((b % comps) % c), |_, _| {});
        combine(&mut self.fluence_spare, &self.fluence_total, &self.fluence, |b| f(b % c), |_, _| {});
        std::mem::swap(&mut self.source_total, &mut self.source_spare);
        std::mem::swap(&mut self.fluence_total, &mut self.fluence_spare);
    }

    /// Clears the order's accumulators before an order starts.
    pub fn begin_order(&mut self) -> Result<(), SolveError> {
        if !self.clean {
            self.source_next.fill_zero()?;
            self.fluence.fill_zero()?;
            self.clean = true;
        }
        Ok(())
    }

    /// Power emitted in order 0 and absorbed over all committed orders, per channel.
    pub fn emitted_and_absorbed(&self, store: &BrickStore, plan: &Plan) -> ([f64; 3], [f64; 3]) {
        let c = plan.channels as usize;
        let h3 = plan.voxel_size.powi(3);
        let four_pi: f64 = plan.storage.solid_angle.iter().sum();
        let (mut emitted, mut absorbed) = ([0.0; 3], [0.0; 3]);
        for (n, brick) in store.occupied_bricks().enumerate() {
            if n % RELEASE_BRICKS == 0 {
                store.release_all_density();
                self.fluence_total.release_all();
            }
            let (Some(density), Some(phi)) = (store.density_brick(brick), self.fluence_total.brick(brick)) else {
                continue;
            };
            for ch in 0..c {
                let sa = plan.coefficients(ch).2;
                let phi = &phi[ch * BRICK_VOXELS..(ch + 1) * BRICK_VOXELS];
                let (mut rho_sum, mut rho_phi) = (0.0, 0.0);
                for (&rho, &f) in density.iter().zip(phi) {
                    rho_sum += rho as f64;
                    rho_phi += rho as f64 * f as f64;
                }
                if plan.emission {
                    emitted[ch] += four_pi * sa * plan.medium.emission[ch] * rho_sum * h3;
                }
                absorbed[ch] += sa * rho_phi * h3;
            }
        }
        store.release_all_density();
        self.fluence_total.release_all();
        (emitted, absorbed)
    }
}

impl StoreFields {
    /// The remaining relative error over the medium's voxels (see [`super::remaining`]): after
    /// [`StoreFields::commit_order`], `fluence_total` holds the sum so far and `fluence` the newest
    /// order's.
    pub fn remaining_error(
        &self,
        store: &BrickStore,
        plan: &Plan,
        factor: [f64; 3],
    ) -> super::remaining::RemainingError {
        let c = plan.channels as usize;
        let mut tally = super::remaining::RemainingTally::default();
        for (n, brick) in store.occupied_bricks().enumerate() {
            if n % RELEASE_BRICKS == 0 {
                store.release_all_density();
                self.fluence_total.release_all();
                self.fluence.release_all();
            }
            let (Some(density), Some(total), Some(newest)) =
                (store.density_brick(brick), self.fluence_total.brick(brick), self.fluence.brick(brick))
            else {
                continue;
            };
            for (ch, &f) in factor.iter().enumerate().take(c) {
                let range = ch * BRICK_VOXELS..(ch + 1) * BRICK_VOXELS;
                for ((&rho, &t), &k) in density.iter().zip(&total[range.clone()]).zip(&newest[range]) {
                    if rho > 0.0 {
                        tally.add(t as f64, k as f64, f);
                    }
                }
            }
        }
        store.release_all_density();
        self.fluence_total.release_all();
        self.fluence.release_all();
        tally.finish()
    }
}

/// The store's fields as the order loop sees them ([`OrderFields`]): the host passes above, with
/// the plan and the store they need, and checkpoints when a scene digest is given.
pub struct StoreOrderFields<'a> {
    pub fields: &'a mut StoreFields,
    plan: &'a Plan,
    store: &'a BrickStore,
    /// The scene digest checkpoints are written under; `None`: no checkpoints.
    checkpoint_digest: Option<String>,
}

impl<'a> StoreOrderFields<'a> {
    pub fn new(fields: &'a mut StoreFields, plan: &'a Plan, store: &'a BrickStore) -> Self {
        StoreOrderFields { fields, plan, store, checkpoint_digest: None }
    }

    /// Writes a checkpoint into the store after every completed order.
    pub fn enable_checkpoints(&mut self, digest: String) {
        self.checkpoint_digest = Some(digest);
    }
}

impl OrderFields for StoreOrderFields<'_> {
    fn commit_order(&mut self) -> Result<[f64; 3], SolveError> {
        Ok(self.fields.commit_order(self.plan))
    }

    fn apply_tail(&mut self, factor: [f64; 3]) -> Result<(), SolveError> {
        self.fields.apply_tail(self.plan, factor);
        Ok(())
    }

    fn checkpoint(&mut self, state: &LoopState) -> Result<(), SolveError> {
        match &self.checkpoint_digest {
            Some(digest) => self.fields.write_checkpoint(self.store.dir(), digest, state),
            None => Ok(()),
        }
    }

    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError> {
        let (emitted, absorbed) = self.fields.emitted_and_absorbed(self.store, self.plan);
        if self.plan.emission_field {
            return Ok((super::emission::emitted_power(self.store, self.plan)?, absorbed));
        }
        Ok((emitted, absorbed))
    }

    fn remaining_error(&mut self, factor: [f64; 3]) -> Result<super::remaining::RemainingError, SolveError> {
        Ok(self.fields.remaining_error(self.store, self.plan, factor))
    }

    fn unpropagated_power(&mut self) -> Result<Option<[f64; 3]>, SolveError> {
        Ok(self.fields.signed_last_power(self.plan))
    }
}

/// Bricks a pass over whole fields walks before handing their pages back (see
/// [`crate::store::Field`] on resident memory): a few tens of MiB per field.
const RELEASE_BRICKS: usize = 1024;

/// `next −= guess`, brick-component block by block; calls `block_sum(block, Σ|next|)` for each
/// block (a warm start's first commit, see [`StoreFields::commit_order`]).
fn subtract(next: &mut Field, guess: &Field, mut block_sum: impl FnMut(usize, f64)) {
    let bricks = next.stored_bricks();
    let per_brick = next.brick_len();
    let mut block = 0;
    for first in (0..bricks).step_by(RELEASE_BRICKS) {
        let range = first * per_brick..(first + RELEASE_BRICKS).min(bricks) * per_brick;
        let (n, g) = (&mut next.as_mut_slice()[range.clone()], &guess.as_slice()[range]);
        for (n, g) in n.chunks_mut(BRICK_VOXELS).zip(g.chunks(BRICK_VOXELS)) {
            let mut sum = 0.0;
            for (n, &g) in n.iter_mut().zip(g) {
                *n -= g;
                sum += n.abs() as f64;
            }
            block_sum(block, sum);
            block += 1;
        }
        for field in [&*next, guess] {
            field.release_stored(first, RELEASE_BRICKS);
        }
    }
}

/// `spare = total + factor(block)·last`, brick-component block by block (4096 values each); calls
/// `block_sum(block, Σ last)` for each block. With factor 1 this is exactly `total + last`. The
/// three fields' pages are handed back every [`RELEASE_BRICKS`] bricks.
fn combine(
    spare: &mut Field,
    total: &Field,
    last: &Field,
    factor: impl Fn(usize) -> f32,
    mut block_sum: impl FnMut(usize, f64),
) {
    let bricks = spare.stored_bricks();
    let per_brick = spare.brick_len();
    let mut block = 0;
    for first in (0..bricks).step_by(RELEASE_BRICKS) {
        let range = first * per_brick..(first + RELEASE_BRICKS).min(bricks) * per_brick;
        let (s, t, l) =
            (&mut spare.as_mut_slice()[range.clone()], &total.as_slice()[range.clone()], &last.as_slice()[range]);
        for ((s, t), l) in s.chunks_mut(BRICK_VOXELS).zip(t.chunks(BRICK_VOXELS)).zip(l.chunks(BRICK_VOXELS)) {
            let f = factor(block);
            let mut sum = 0.0;
            for ((s, &t), &l) in s.iter_mut().zip(t).zip(l) {
                *s = t + f * l;
                // The norm: a warm start's residual has either sign (cold sources are ≥ 0).
                sum += l.abs() as f64;
            }
            block_sum(block, sum);
            block += 1;
        }
        for field in [&*spare, total, last] {
            field.release_stored(first, RELEASE_BRICKS);
        }
    }
}
