//! The order loop, shared by both backends: propagate an order, fold its new source into the
//! total, and stop when the newest order's scattered power falls below the tolerance.

use super::energy::{EnergyBalance, Tallies};
use super::plan::Plan;
use super::SolveError;
use serde::Serialize;
use std::time::{Duration, Instant};

/// What a backend must do. Order 0 sweeps the sun beams and carries the boundary light (and the
/// emission); every order deposits fluence and the next order's source.
pub trait Backend {
    /// Propagates one order (the beams first when `order == 0`) and returns its boundary tallies.
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError>;
    /// Adds the new source to the total, makes it the source of the next order, clears the new
    /// source, and returns its scattered power per channel (Σ_x Σ_d Ω_d·J^d·h³).
    fn finish_order(&mut self) -> Result<[f64; 3], SolveError>;
    /// Power emitted (order 0) and absorbed (all orders so far), per channel.
    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError>;
}

#[derive(Clone, Debug, Serialize)]
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

/// Runs orders until the tolerance or the cap. `progress(order, residual)` is called after each.
pub fn run_orders(
    plan: &Plan,
    backend: &mut dyn Backend,
    mut progress: impl FnMut(u32, f64),
) -> Result<OrderOutcome, SolveError> {
    let start = Instant::now();
    let mut tallies = Tallies::default();
    let mut total = [0.0; 3];
    let mut history = Vec::new();
    let mut residual = 0.0;
    let mut converged = false;
    let mut last_new = [0.0; 3];
    for order in 0..plan.max_orders {
        let t = Instant::now();
        tallies.add(&backend.propagate_order(order)?);
        last_new = backend.finish_order()?;
        (0..3).for_each(|c| total[c] += last_new[c]);
        let new_sum: f64 = last_new.iter().sum();
        let total_sum: f64 = total.iter().sum();
        residual = if total_sum > 0.0 { new_sum / total_sum } else { 0.0 };
        history.push(OrderRecord {
            order,
            new_source_power: new_sum,
            total_source_power: total_sum,
            seconds: t.elapsed().as_secs_f64(),
        });
        progress(order, residual);
        tracing::debug!(order, residual, "order done");
        if residual <= plan.tolerance {
            converged = true;
            break;
        }
    }
    let (emitted, absorbed) = backend.emitted_and_absorbed()?;
    let energy = EnergyBalance::new(&tallies, emitted, absorbed, last_new, plan.channels as usize);
    Ok(OrderOutcome {
        orders: history.len() as u32,
        converged,
        residual,
        history,
        energy,
        elapsed: start.elapsed(),
    })
}
