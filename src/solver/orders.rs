//! The order loop, shared by both backends: propagate an order (the backend's one job), fold it
//! into the totals with the host passes ([`super::passes`]), checkpoint, and stop when every voxel
//! of the medium is estimated to be within the tolerance of its converged value
//! ([`super::remaining`]), or, with `solver.extrapolate_tail`, when the geometric tail of the
//! series is known to the tolerance.
//!
//! **The geometric tail** (`solver.extrapolate_tail`, [`TailEstimate`]). In thick media with
//! albedo near 1 the orders shrink by a nearly constant ratio ρ, and the rest of the series after
//! the last order is ρ/(1 − ρ) times it. The ratio is not settled when the loop would like to
//! stop: it creeps up toward its limit by steps that shrink slowly (by a ratio q of 0.91–0.97 per
//! order in the thick clouds of `benches/RESULTS.md`), so the loop sums the steps still to come as
//! well: the ratio may still move by d = |Δρ|/(1 − |q|), the tail uses the middle of that range,
//! ρ̂ = ρ + ½d, and its uncertainty is half the tail's change over the range. The solve stops once
//! that uncertainty is within the tolerance of the total; the tail (ρ̂/(1 − ρ̂) times the last
//! order's fluence and source, per channel) is then added. The tolerance bounds the power the tail
//! misses; the fluence's shape is off a little more, since the last order's shape stands for the
//! tail's. An earlier form took one step of the drift for all of it and stopped far too early
//! while reporting an uncertainty within the tolerance.

use super::antidiffusion::VoxelUnits;
use super::energy::{EnergyBalance, Tallies};
use super::fields::LoopState;
use super::passes::{FieldPlanes, Medium, OrderFieldSet};
use super::plan::Plan;
use super::remaining::{tail_factor, RemainingError};
use super::SolveError;
use crate::progress::{Observer, OrderDone, Stage};
use serde::Serialize;
use std::time::{Duration, Instant};

/// What differs between the backends: how one order is propagated, and where the fields live.
/// Order 0 sweeps the sun beams and carries the boundary light (and the emission); every order
/// deposits fluence and the next order's source into the backend's [`OrderFieldSet`]. The host
/// passes between orders (commit, tail, remaining error, energy) are the order loop's, written
/// once in [`super::passes`] for both kinds of field.
pub trait Backend {
    /// Where a field lives: files of f32 in the brick store, or f64 in memory.
    type Field: FieldPlanes + Sync + Send;
    /// The medium's density over the fields' units, and where those units lie in the volume.
    type Medium: Medium<V = <Self::Field as FieldPlanes>::V> + VoxelUnits<V = <Self::Field as FieldPlanes>::V>;
    /// Propagates one order (the beams first when `order == 0`) and returns its boundary tallies.
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError>;
    /// The fields the order loop folds each order into, and the medium they cover. Current
    /// between orders, except while a backend keeps them elsewhere: then from the last order of
    /// the solve on (after [`Backend::checkpoint`] with `last`).
    fn fields(&mut self) -> (&mut OrderFieldSet<Self::Field>, &Self::Medium);
    /// Commits the order just propagated and returns the power its new source scatters, per
    /// channel ([`OrderFieldSet::commit_order`], unless the backend commits elsewhere).
    fn commit_order(&mut self, plan: &Plan) -> Result<[f64; 3], SolveError> {
        let (fields, medium) = self.fields();
        fields.commit_order(plan, medium)
    }
    /// The stop rule's remaining error after a commit, for the tail factor per channel
    /// ([`OrderFieldSet::remaining_error`], unless the backend keeps the fields elsewhere).
    fn remaining_error(&mut self, plan: &Plan, factor: [f64; 3]) -> Result<RemainingError, SolveError> {
        let (fields, medium) = self.fields();
        Ok(fields.remaining_error(medium, plan, factor))
    }
    /// Power (per channel) the rays of periodic sweeps carried out of the last order and carry
    /// into the next ([`super::periodic`]); zero without periodic axes.
    fn carried_power(&self) -> [f64; 3] {
        [0.0; 3]
    }

    /// How often the backend wants its state recorded for a resume (`None`: it keeps no
    /// checkpoints). The order loop schedules them ([`run_orders`]): the same rule for every
    /// backend.
    fn checkpoint_cadence(&self) -> Option<crate::scene::CheckpointCadence> {
        None
    }
    /// The state after a completed order: to be recorded so that a killed solve can resume from
    /// it when `due` (the cadence says so; always with `last` when the backend keeps
    /// checkpoints), else the latest state not recorded. `last`: the solve ends with this order.
    /// Only the brick store's fields outlive the process; the default does nothing.
    fn checkpoint(&mut self, _state: &LoopState, _due: bool, _last: bool) -> Result<(), SolveError> {
        Ok(())
    }
    /// The power emitted when order 0's source is a per-voxel emission ([`super::emission`]),
    /// which the uniform emission the energy pass counts does not cover; `None` otherwise.
    fn emission_field_power(&mut self) -> Result<Option<[f64; 3]>, SolveError> {
        Ok(None)
    }
}

#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct OrderRecord {
    pub order: u32,
    /// Scattered power of the source this order produced (summed over channels).
    pub new_source_power: f64,
    /// Scattered power of all sources so far.
    pub total_source_power: f64,
    /// The largest remaining relative error over the medium's voxels after this order (None
    /// while no ratio is known yet; infinite while light is still building up).
    #[serde(default)]
    pub remaining_max: Option<f64>,
    pub seconds: f64,
}

/// The orders not propagated, estimated as a geometric series.
///
/// The ratio ρ of successive orders' scattered power is not settled when the order loop would like
/// to stop: in a thick medium it creeps up toward its limit for hundreds of orders (the faster
/// decaying modes die out one after the other), by steps that shrink slowly. Using the last ratio
/// as it is underestimates the tail, and one step of its drift underestimates how far it has still
/// to go (by 30× at albedo 0.999 in the thick cloud of `tools/scenes/thick_cloud_a0.999.toml`). So
/// the steps still to come are summed as a geometric series too: with Δ the ratio's last step and
/// q the ratio of its last two steps, the ratio may still move by d = |Δ|/(1 − |q|). The tail
/// uses the middle of that range, ρ + ½d (in the direction of Δ), and its uncertainty is half the
/// tail's change over the range.
///
/// `report.json` gives each per-channel array for the solve's channels only (one entry when grey).
#[derive(Clone, Debug, Serialize)]
#[serde(into = "TailJson")]
pub struct TailEstimate {
    /// Per channel, the ratio of the last order's scattered power to the previous one's.
    pub ratio: [f64; 3],
    /// Per channel, how far the ratio may still move: |Δρ|/(1 − |q|).
    pub drift: [f64; 3],
    /// q: the last step of the ratio over the step before (from the power summed over channels).
    pub drift_ratio: f64,
    /// Per channel, ρ̂/(1 − ρ̂) with ρ̂ = ρ ± ½·drift: the tail in units of the last order.
    pub factor: [f64; 3],
    /// Scattered power of the tail (summed over channels).
    pub power: f64,
    /// How far off the tail may be: half its change as the ratio moves over the drift, summed over
    /// channels.
    pub uncertainty: f64,
    /// Per channel, that uncertainty in units of the last order: ½·|ρ_far/(1 − ρ_far) − ρ/(1 − ρ)|.
    /// Times each voxel's last-order fluence over its fluence with the tail, it is the remaining
    /// error the report gives after the tail ([`OrderOutcome::remaining`]).
    pub uncertainty_factor: [f64; 3],
    /// Per face ([`super::energy::VOLUME_FACES`] order) and channel, the power the tail's orders
    /// carry out: the last order's times the tail factor (its shape stands for theirs). The
    /// energy balance's faces cover the propagated orders; add this for the totals with the tail
    /// (e.g. the reflectance and transmittance of a converged high-albedo slab).
    pub face_out: [[f64; 3]; 6],
    /// How many channels the solve had (1 grey, or 3).
    pub channels: usize,
}

/// [`TailEstimate`] as `report.json` writes it: each per-channel array cut to the solve's channels.
#[derive(Serialize)]
struct TailJson {
    ratio: Vec<f64>,
    drift: Vec<f64>,
    drift_ratio: f64,
    factor: Vec<f64>,
    power: f64,
    uncertainty: f64,
    uncertainty_factor: Vec<f64>,
    face_out: Vec<Vec<f64>>,
}

impl From<TailEstimate> for TailJson {
    fn from(t: TailEstimate) -> Self {
        let n = t.channels.clamp(1, 3);
        let cut = |v: [f64; 3]| v[..n].to_vec();
        TailJson {
            ratio: cut(t.ratio),
            drift: cut(t.drift),
            drift_ratio: t.drift_ratio,
            factor: cut(t.factor),
            power: t.power,
            uncertainty: t.uncertainty,
            uncertainty_factor: cut(t.uncertainty_factor),
            face_out: t.face_out.iter().map(|&f| cut(f)).collect(),
        }
    }
}

/// Orders in a row whose scattered power grew, and by how much in all, that mark a diverging series
/// ([`check_divergence`]).
const GROWING_ORDERS: usize = 8;
const DIVERGED_GROWTH: f64 = 2.0;

/// Fails with [`SolveError::Diverged`] when this order's scattered power `new` (per channel) is
/// not finite, or when the power (summed over channels, in magnitude) grew in each of the last
/// [`GROWING_ORDERS`] orders and by [`DIVERGED_GROWTH`] or more over them. Transport alone cannot
/// do either: each order scatters at most the albedo times what the one before did. An
/// acceleration that amplifies a mode can: a thick cloud at albedo 0.999 under spatial = "linear"
/// with the diffusion acceleration forced on grew ×1.18 per order from order 10 on (RESULTS.md,
/// "Linear with the correction") and ran on to max_orders, reporting fields of 10¹³ as "solved";
/// later it would overflow to infinities. A converging accelerated series may grow for an order or
/// two, never for eight.
fn check_divergence(order: u32, new: [f64; 3], history: &[OrderRecord]) -> Result<(), SolveError> {
    if let Some(&power) = new.iter().find(|p| !p.is_finite()) {
        return Err(SolveError::Diverged { order, why: format!("it scattered a non-finite power ({power})") });
    }
    let now = new.iter().sum::<f64>().abs();
    // The last orders' powers, the newest first.
    let past: Vec<f64> = history.iter().rev().take(GROWING_ORDERS).map(|r| r.new_source_power.abs()).collect();
    let Some(&first) = past.get(GROWING_ORDERS - 1) else { return Ok(()) };
    let grew_every_order =
        std::iter::once(now).chain(past.iter().copied()).zip(past.iter()).all(|(later, &p)| later > p);
    if grew_every_order && first > 0.0 && now >= DIVERGED_GROWTH * first {
        return Err(SolveError::Diverged {
            order,
            why: format!(
                "its scattered power grew in each of the last {GROWING_ORDERS} orders, ×{:.3} in all ({first:.4e} → {now:.4e})",
                now / first
            ),
        });
    }
    Ok(())
}

/// Below this a step of the ratio counts as settled (the ratios are f64 quotients of sums over the
/// volume: far above rounding).
const SETTLED_STEP: f64 = 1e-10;

/// The tail estimate after the orders in `state`, when the ratios are settled enough to use:
/// at least four orders, every scattering channel's ratio in (0, 1), the ratio's steps shrinking
/// (|q| < 1) and the far end of its drift still below 1.
pub fn tail_estimate(plan: &Plan, state: &LoopState) -> Option<TailEstimate> {
    let h = &state.history;
    if state.orders_done < 4 || h.len() < 4 {
        return None;
    }
    // The drift's shrink ratio q, from the last four orders' power summed over channels (the
    // checkpointed history keeps no per-channel powers; the channels' decaying modes share the
    // medium's geometry).
    let n = h.len();
    let ratio_at = |i: usize| h[i].new_source_power / h[i - 1].new_source_power;
    let (step, step_before) = (ratio_at(n - 1) - ratio_at(n - 2), ratio_at(n - 2) - ratio_at(n - 3));
    let q = if step.abs() <= SETTLED_STEP { 0.0 } else { step / step_before };
    if !(q.abs() < 1.0) {
        return None;
    }
    let c = plan.channels as usize;
    let mut t = TailEstimate {
        ratio: [0.0; 3],
        drift: [0.0; 3],
        drift_ratio: q,
        factor: [0.0; 3],
        power: 0.0,
        uncertainty: 0.0,
        uncertainty_factor: [0.0; 3],
        face_out: [[0.0; 3]; 6],
        channels: c,
    };
    let tail = |rho: f64| rho / (1.0 - rho);
    for ch in 0..c {
        let (new, before) = (state.last_new_power[ch], state.previous_new_power[ch]);
        if new <= 0.0 {
            continue;
        }
        let rho = new / before;
        if !(rho > 0.0 && rho < 1.0) || !(state.previous_ratio[ch] > 0.0) {
            return None;
        }
        let delta = rho - state.previous_ratio[ch];
        let drift = delta.abs() / (1.0 - q.abs());
        let far = rho + drift.copysign(delta);
        if !(far < 1.0 && far > 0.0) {
            return None;
        }
        let mid = rho + 0.5 * drift.copysign(delta);
        t.ratio[ch] = rho;
        t.drift[ch] = drift;
        t.factor[ch] = tail(mid);
        t.power += new * t.factor[ch];
        t.uncertainty_factor[ch] = 0.5 * (tail(far) - tail(rho)).abs();
        for (out, last) in t.face_out.iter_mut().zip(&state.last_face_out) {
            out[ch] = last[ch] * t.factor[ch];
        }
        t.uncertainty += new * t.uncertainty_factor[ch];
    }
    Some(t)
}

/// Per channel, the tail factor ρ/(1 − ρ) the stop rule uses: ρ the ratio of the last two orders'
/// scattered power, moved to the far end of its drift while it is still creeping up (so the
/// estimate errs toward more orders). `None` before two orders have scattered anything.
fn tail_factors(plan: &Plan, state: &LoopState) -> Option<[f64; 3]> {
    if state.orders_done < 2 {
        return None;
    }
    let drift = tail_estimate(plan, state);
    let mut factor = [0.0; 3];
    for (ch, f) in factor.iter_mut().enumerate().take(plan.channels as usize) {
        let (new, before) = (state.last_new_power[ch], state.previous_new_power[ch]);
        if new <= 0.0 {
            continue;
        }
        if before <= 0.0 {
            return None;
        }
        let mut rho = new / before;
        if let Some(t) = &drift {
            // The tail's own ratio lies above ρ when ρ is still rising: then use its far end.
            let mid = t.factor[ch] / (1.0 + t.factor[ch]);
            if mid > t.ratio[ch] {
                rho = t.ratio[ch] + t.drift[ch];
            }
        }
        *f = tail_factor(rho);
    }
    Some(factor)
}

/// Whether the tail estimate is good to the tolerance.
fn tail_converged(plan: &Plan, state: &LoopState) -> bool {
    let total: f64 = state.total_power.iter().sum();
    tail_estimate(plan, state).is_some_and(|t| t.uncertainty <= plan.tolerance * (total + t.power))
}

#[derive(Clone, Debug, Serialize)]
pub struct OrderOutcome {
    /// Orders propagated (order 0 is the light straight from the boundary and the beams).
    pub orders: u32,
    pub converged: bool,
    /// New source power over total source power after the last order (0 when nothing scatters).
    pub residual: f64,
    /// The estimated remaining relative error over the medium's voxels after the last order (the
    /// stop rule's measure); with an extrapolated tail, after the tail was added: the tail's power
    /// uncertainty, voxel by voxel. That leaves out the error of the tail's shape (the last order's
    /// shape stands for every later one's): measured up to ~5× more in `tests/it/acceleration.rs`.
    pub remaining: Option<RemainingError>,
    pub history: Vec<OrderRecord>,
    pub energy: EnergyBalance,
    /// The geometric tail added after the last order (when `solver.extrapolate_tail` is on).
    pub tail: Option<TailEstimate>,
    #[serde(skip)]
    pub elapsed: Duration,
}

/// The residual a solve reports after the orders in `state` ([`OrderOutcome::residual`]): with
/// `solver.extrapolate_tail` and a tail known, the tail's uncertainty over the total with the
/// tail; else the last order's scattered power over the total (0 when nothing scatters). The
/// order loop gives each order's progress this same value, so that the last order's residual is
/// the report's.
fn reported_residual(plan: &Plan, state: &LoopState) -> f64 {
    let total: f64 = state.total_power.iter().sum();
    match plan.extrapolate_tail.then(|| tail_estimate(plan, state)).flatten() {
        Some(t) => t.uncertainty / (total + t.power),
        None if total > 0.0 => state.last_new_power.iter().sum::<f64>() / total,
        None => 0.0,
    }
}

/// Runs orders until the tolerance or the cap, from `start` (a fresh solve passes the default
/// state; a resumed one the state of its checkpoint). `progress` hears each order start
/// ([`Stage::Order`]) and end ([`OrderDone`]).
pub fn run_orders<B: Backend + ?Sized>(
    plan: &Plan,
    backend: &mut B,
    start: LoopState,
    mut progress: impl Observer,
) -> Result<OrderOutcome, SolveError> {
    let clock = Instant::now();
    let start_orders = start.orders_done;
    // Checkpoints: orders completed since the last one (or the start), and when that was.
    let cadence = backend.checkpoint_cadence();
    let mut since_checkpoint = (0u32, Instant::now());
    let mut state = start;
    let extrapolate = plan.extrapolate_tail;
    // Nothing scatters any more (a non-scattering medium after order 0): the fluence is complete.
    let exhausted = |s: &LoopState| s.orders_done > 0 && s.last_new_power.iter().all(|&p| p <= 0.0);
    let mut remaining: Option<RemainingError> = None;
    let remaining_of = |backend: &mut B, s: &LoopState| match tail_factors(plan, s) {
        Some(factor) if !exhausted(s) => backend.remaining_error(plan, factor).map(Some),
        _ => Ok(None),
    };
    let done = |s: &LoopState, remaining: Option<RemainingError>| {
        exhausted(s)
            || if extrapolate { tail_converged(plan, s) } else { remaining.is_some_and(|r| r.max <= plan.tolerance) }
    };
    let mut converged = match state.history.last() {
        Some(last) => done(&state, last.remaining_max.map(|max| RemainingError { max, l2: 0.0 })),
        None => false,
    };
    while !converged && state.orders_done < plan.max_orders {
        let order = state.orders_done;
        progress.stage(Stage::Order(order));
        let t = Instant::now();
        let mut tallies = state.tallies();
        let this_order = backend.propagate_order(order)?;
        tallies.add(&this_order);
        let scattered = backend.commit_order(plan)?;
        // What the next order propagates: the new source, and what periodic sweeps carry over.
        let carried = backend.carried_power();
        let new: [f64; 3] = std::array::from_fn(|c| scattered[c] + carried[c]);
        // Before anything of this order is kept (the totals, a checkpoint): a blown-up order
        // would otherwise run on to max_orders and write fields of infinities.
        check_divergence(order, new, &state.history)?;
        state.last_carried_power = carried;
        state.last_face_out = this_order.face_out;
        for c in 0..3 {
            state.total_power[c] += new[c];
            let last = state.last_new_power[c];
            state.previous_ratio[c] =
                if state.previous_new_power[c] > 0.0 { last / state.previous_new_power[c] } else { 0.0 };
            state.previous_new_power[c] = last;
        }
        state.last_new_power = new;
        state.tallies = tallies;
        state.orders_done += 1;
        let residual = reported_residual(plan, &state);
        remaining = remaining_of(backend, &state)?;
        // Kept with the state (and so in its checkpoint): what a solve resumed after this order
        // reports, measured once (see the end of the loop).
        state.last_remaining = remaining;
        let (power, seconds) = (new.iter().sum(), t.elapsed().as_secs_f64());
        state.history.push(OrderRecord {
            order,
            new_source_power: power,
            total_source_power: state.total_power.iter().sum(),
            remaining_max: remaining.map(|r| r.max),
            seconds,
        });
        converged = done(&state, remaining);
        let last = converged || state.orders_done >= plan.max_orders;
        since_checkpoint.0 += 1;
        let (orders_since, since) = since_checkpoint;
        let due = cadence.is_some_and(|c| c.due(orders_since, since.elapsed().as_secs_f64(), last));
        backend.checkpoint(&state, due, last)?;
        if due {
            since_checkpoint = (0, Instant::now());
        }
        // What the stop rule compares with the tolerance: the per-voxel remaining error (the
        // residual while no ratio is known yet, and under the tail's own rule, whose residual is
        // the tail's uncertainty once it is known).
        let measure = match remaining {
            Some(r) if !extrapolate => r.max,
            _ => residual,
        };
        // The ratio whose tail factor that measure holds (the estimate separates the two), when
        // it is the per-voxel error.
        let ratio = match (remaining, tail_factors(plan, &state)) {
            (Some(_), Some(factor)) if !extrapolate => factor
                .iter()
                .take(plan.channels as usize)
                .map(|&f| if f.is_finite() { f / (1.0 + f) } else { 1.0 })
                .fold(0.0, f64::max),
            _ => 0.0,
        };
        let weight = plan.order_weight(order);
        progress.order_done(&OrderDone { order, residual, measure, power, seconds, ratio, weight });
        tracing::debug!(order, residual, remaining = remaining.map(|r| r.max), ratio, "order done");
    }
    // Resumed after its last order (killed in the export or the render): no order ran here, so
    // what the orders set up as they went is set up from the checkpoint, for the report to be the
    // uninterrupted solve's: the acceleration grid with its last correction (built at an order's
    // commit, and part of the energy balance), and the last order's remaining error as the loop
    // measured it, which the checkpoint keeps. Measured again in the checkpointed state it would
    // differ: the loop measured before the order's record joined the history, whose last ratios
    // the tail factors' drift reads (issue 57: 6.2e-4 for 5.0e-5). A checkpoint of an earlier
    // version keeps none: measured then in the state the loop measured in (the history less its
    // last record), which gives the same bits.
    if state.orders_done > 0 && state.orders_done == start_orders {
        let (fields, medium) = backend.fields();
        fields.acceleration_due(plan, medium)?;
        remaining = match (state.history.last().and_then(|r| r.remaining_max), state.last_remaining) {
            (None, _) => None,
            (Some(_), Some(kept)) => Some(kept),
            (Some(_), None) => {
                let mut measured_in = state.clone();
                measured_in.history.pop();
                remaining_of(backend, &measured_in)?
            }
        };
    }
    // The balance covers the propagated orders; the tail is reported on its own.
    let (emitted, absorbed) = {
        let (fields, medium) = backend.fields();
        fields.emitted_and_absorbed(medium, plan)
    };
    let emitted = backend.emission_field_power()?.unwrap_or(emitted);
    let emitted: [f64; 3] = std::array::from_fn(|c| emitted[c] + state.uncollided_emitted[c]);
    // A warm start's last source is a residual of either sign: its signed power, not the norm.
    // (What periodic sweeps carry over was counted as out when it left.)
    let last_source: [f64; 3] = std::array::from_fn(|c| state.last_new_power[c] - state.last_carried_power[c]);
    let unpropagated = backend.fields().0.signed_last_power(plan).unwrap_or(last_source);
    let energy = EnergyBalance::new(
        &state.tallies(),
        emitted,
        state.point_light_power,
        state.uncollided_escaped,
        absorbed,
        unpropagated,
        plan.channels as usize,
    );
    let tail = if extrapolate { tail_estimate(plan, &state) } else { None };
    let residual = reported_residual(plan, &state);
    if let Some(t) = &tail {
        let (fields, medium) = backend.fields();
        fields.apply_tail(plan, t.factor);
        remaining = Some(fields.remaining_error(medium, plan, t.uncertainty_factor));
        tracing::info!(ratio = t.ratio[0], power = t.power, "added the geometric tail of the order series");
    }
    Ok(OrderOutcome {
        orders: state.orders_done,
        converged,
        residual,
        remaining,
        history: state.history,
        energy,
        tail,
        elapsed: clock.elapsed(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grey solve's tail writes one entry per per-channel array (not `[x, 0, 0]`).
    #[test]
    fn a_grey_tail_has_one_entry_per_array() {
        let t = TailEstimate {
            ratio: [0.9, 0.0, 0.0],
            drift: [0.01, 0.0, 0.0],
            drift_ratio: 0.5,
            factor: [9.0, 0.0, 0.0],
            power: 2.0,
            uncertainty: 0.1,
            uncertainty_factor: [0.2, 0.0, 0.0],
            face_out: [[1.0, 0.0, 0.0]; 6],
            channels: 1,
        };
        let json = serde_json::to_value(&t).expect("json");
        assert_eq!(json["ratio"], serde_json::json!([0.9]));
        assert_eq!(json["face_out"][5], serde_json::json!([1.0]));
        assert_eq!(json["power"], 2.0);
        let rgb = serde_json::to_value(TailEstimate { channels: 3, ..t }).expect("json");
        assert_eq!(rgb["factor"], serde_json::json!([9.0, 0.0, 0.0]));
    }

    fn history(powers: &[f64]) -> Vec<OrderRecord> {
        powers
            .iter()
            .enumerate()
            .map(|(i, &p)| OrderRecord {
                order: i as u32,
                new_source_power: p,
                total_source_power: 0.0,
                remaining_max: None,
                seconds: 0.0,
            })
            .collect()
    }

    #[test]
    fn an_order_of_infinite_or_undefined_power_stops_the_solve() {
        assert!(check_divergence(3, [1.0, 0.0, 2.5e300], &[]).is_ok());
        for bad in [f64::INFINITY, f64::NAN, f64::NEG_INFINITY] {
            match check_divergence(7, [1.0, bad, 0.0], &[]) {
                Err(SolveError::Diverged { order: 7, why }) => assert!(why.contains("non-finite"), "{why}"),
                other => panic!("expected a divergence error, got {other:?}"),
            }
        }
        let message = SolveError::Diverged { order: 7, why: "x".into() }.to_string();
        assert!(message.contains("order 7") && message.contains("acceleration"), "{message}");
    }

    #[test]
    fn a_series_growing_order_after_order_stops_but_a_converging_one_with_bumps_goes_on() {
        // ×1.18 per order, as the diverging cloud did: stopped once eight rises double it.
        let growing: Vec<f64> = (0..12).map(|i| 85.0 * 1.18f64.powi(i)).collect();
        let stopped =
            (8..12).find(|&n| check_divergence(n as u32, [growing[n], 0.0, 0.0], &history(&growing[..n])).is_err());
        assert_eq!(stopped, Some(8));
        // An accelerated series that rises for an order now and then converges: never stopped.
        let bumpy = [1.0, 8e-3, 5.5e-3, 4.9e-3, 2.2e-3, 2.7e-3, 9.5e-4, 8.8e-4, 3.4e-4, 4.1e-4, 1.5e-4, 7e-5];
        for n in 1..bumpy.len() {
            assert!(check_divergence(n as u32, [bumpy[n], 0.0, 0.0], &history(&bumpy[..n])).is_ok());
        }
        // Eight small rises that do not double (a series stalled at its rounding floor): goes on.
        let creeping: Vec<f64> = (0..10).map(|i| 1e-9 * (1.0 + 0.01 * i as f64)).collect();
        assert!(check_divergence(9, [creeping[9], 0.0, 0.0], &history(&creeping[..9])).is_ok());
        // Warm starts' signed residuals shrinking in magnitude are not growth.
        let signed: Vec<f64> = (0..10).map(|i| -(0.5f64.powi(i))).collect();
        assert!(check_divergence(9, [signed[9], 0.0, 0.0], &history(&signed[..9])).is_ok());
    }
}
