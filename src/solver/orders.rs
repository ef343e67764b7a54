//! The order loop, shared by both backends: propagate an order, fold its new source into the
//! total, and stop when the newest order's scattered power falls below the tolerance.

use super::energy::{EnergyBalance, Tallies};
use super::fields::LoopState;
use super::plan::Plan;
use super::SolveError;
use serde::Serialize;
use std::time::{Duration, Instant};

/// What a backend must do. Order 0 sweeps the sun beams and carries the boundary light (and the
/// emission); every order deposits fluence and the next order's source.
pub trait Backend {
    /// Propagates one order (the beams first when `order == 0`) and returns its boundary tallies.
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError>;
    /// Adds the order's fluence and new source to the totals, makes the new source the next
    /// order's, and returns its scattered power per channel (Σ_x Σ_d Ω_d·J^d·h³).
    fn finish_order(&mut self) -> Result<[f64; 3], SolveError>;
    /// Records the state after a completed order so that a killed solve can resume from it.
    fn checkpoint(&mut self, _state: &LoopState) -> Result<(), SolveError> {
        Ok(())
    }
    /// Power emitted (order 0) and absorbed (all orders so far), per channel.
    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError>;
}

#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct OrderRecord {
    pub order: u32,
    /// Scattered power of the source this order produced (summed over channels).
    pub new_source_power: f64,
    /// Scattered power of all sources so far.
    pub total_source_power: f64,
    pub seconds: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct OrderOutcome {
    /// Orders propagated (order 0 is the light straight from the boundary and the beams).
    pub orders: u32,
    pub converged: bool,
    /// New source power over total source power after the last order (0 when nothing scatters).
    pub residual: f64,
    pub history: Vec<OrderRecord>,
    pub energy: EnergyBalance,
    #[serde(skip)]
    pub elapsed: Duration,
}

/// Runs orders until the tolerance or the cap, from `start` (a fresh solve passes the default
/// state; a resumed one the state of its checkpoint). `progress(order, residual)` is called after
/// each order.
pub fn run_orders(
    plan: &Plan,
    backend: &mut dyn Backend,
    start: LoopState,
    mut progress: impl FnMut(u32, f64),
) -> Result<OrderOutcome, SolveError> {
    let clock = Instant::now();
    let mut state = start;
    let residual_of = |s: &LoopState| {
        let total: f64 = s.total_power.iter().sum();
        if total > 0.0 {
            s.last_new_power.iter().sum::<f64>() / total
        } else {
            0.0
        }
    };
    let mut converged = state.orders_done > 0 && residual_of(&state) <= plan.tolerance;
    while !converged && state.orders_done < plan.max_orders {
        let order = state.orders_done;
        let t = Instant::now();
        let mut tallies = state.tallies();
        tallies.add(&backend.propagate_order(order)?);
        let new = backend.finish_order()?;
        (0..3).for_each(|c| state.total_power[c] += new[c]);
        state.last_new_power = new;
        state.tallies = [tallies.boundary_in, tallies.boundary_out];
        state.orders_done += 1;
        let residual = residual_of(&state);
        state.history.push(OrderRecord {
            order,
            new_source_power: new.iter().sum(),
            total_source_power: state.total_power.iter().sum(),
            seconds: t.elapsed().as_secs_f64(),
        });
        backend.checkpoint(&state)?;
        progress(order, residual);
        tracing::debug!(order, residual, "order done");
        converged = residual <= plan.tolerance;
    }
    let (emitted, absorbed) = backend.emitted_and_absorbed()?;
    let energy = EnergyBalance::new(&state.tallies(), emitted, absorbed, state.last_new_power, plan.channels as usize);
    Ok(OrderOutcome {
        orders: state.orders_done,
        converged,
        residual: residual_of(&state),
        history: state.history,
        energy,
        elapsed: clock.elapsed(),
    })
}
