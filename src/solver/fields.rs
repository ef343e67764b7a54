//! The solver's fields in the brick store, and the host passes over them between orders.
//!
//! `source_prev`/`source_next`/`source_total` hold the in-scattered source (storage directions ×
//! channels per voxel) for occupied bricks only: empty bricks neither scatter nor hold a source.
//! `fluence` (channels per voxel) covers every brick, since light crosses vacuum too.

use super::plan::Plan;
use super::SolveError;
use crate::store::{BrickStore, Coverage, Field, BRICK_VOXELS};

pub struct StoreFields {
    pub source_prev: Field,
    pub source_next: Field,
    pub source_total: Field,
    pub fluence: Field,
}

impl StoreFields {
    pub fn create(store: &BrickStore, plan: &Plan) -> Result<Self, SolveError> {
        let comps = plan.source_components();
        Ok(StoreFields {
            source_prev: store.create_field("source_prev", comps, Coverage::Occupied)?,
            source_next: store.create_field("source_next", comps, Coverage::Occupied)?,
            source_total: store.create_field("source_total", comps, Coverage::Occupied)?,
            fluence: store.create_field("fluence", plan.channels, Coverage::Dense)?,
        })
    }

    /// Adds the new source to the total, makes it the next order's previous source, clears it, and
    /// returns its scattered power per channel.
    pub fn finish_order(&mut self, plan: &Plan) -> [f64; 3] {
        let c = plan.channels as usize;
        let h3 = plan.voxel_size.powi(3);
        let mut power = [0.0; 3];
        let next = self.source_next.as_slice();
        let total = self.source_total.as_mut_slice();
        for (component_block, (n, t)) in next.chunks(BRICK_VOXELS).zip(total.chunks_mut(BRICK_VOXELS)).enumerate() {
            let k = component_block % plan.source_components() as usize;
            let weight = plan.storage.solid_angle[k / c] * h3;
            let mut sum = 0.0;
            for (t, &n) in t.iter_mut().zip(n) {
                *t += n;
                sum += n as f64;
            }
            power[k % c] += weight * sum;
        }
        std::mem::swap(&mut self.source_prev, &mut self.source_next);
        self.source_next.fill_zero();
        power
    }

    /// Power emitted in order 0 and absorbed over all orders so far, per channel.
    pub fn emitted_and_absorbed(&self, store: &BrickStore, plan: &Plan) -> ([f64; 3], [f64; 3]) {
        let c = plan.channels as usize;
        let h3 = plan.voxel_size.powi(3);
        let four_pi: f64 = plan.storage.solid_angle.iter().sum();
        let (mut emitted, mut absorbed) = ([0.0; 3], [0.0; 3]);
        for brick in 0..store.grid().brick_count() {
            let (Some(density), Some(phi)) = (store.density_brick(brick), self.fluence.brick(brick)) else {
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
        (emitted, absorbed)
    }
}
