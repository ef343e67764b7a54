//! Per-voxel emission (`volume.emission_raw` / `emission_grid`, or a temperature grid's blackbody
//! emission): the source it gives the first order, and the power it emits.
//!
//! A uniformly emitting medium adds `ρ·σa·Le` to what the rays gain in order 0 inside the kernel
//! (`FLAG_EMIT`). A per-voxel emission `e(v)` (`volume.emission_*` or `volume.temperature_*`)
//! needs no kernel of its own: emission is isotropic, so it *is* an order-0 source,
//! `J_d(v) = ρ(v)·σa·Le·e(v)` in every storage direction d, and it is written into the source the
//! first order gains before the order loop starts. Both backends
//! then propagate it exactly as they propagate a scattered source (and the GPU stores it in f16
//! where the plan stores sources in f16), and the twin reads the very same f32 values.
//!
//! The field's factor is grey (one component) or per channel (three: a temperature grid's
//! blackbody colour, see [`crate::store::emission`]); channel `ch` reads
//! [`channel_block`]`(brick, ch)` either way.

use super::plan::{half_scale_exponent, power_of_two, Plan, Precision};
use super::SolveError;
use crate::store::emission::{channel_block, open_emission};
use crate::store::{BrickStore, Field, BRICK_VOXELS};

/// σa·Le per channel: the order-0 source of a voxel of density 1 and emission factor 1.
fn scales(plan: &Plan) -> [f64; 3] {
    std::array::from_fn(|ch| {
        if ch < plan.channels as usize {
            plan.coefficients(ch).2 * plan.medium.emission[ch]
        } else {
            0.0
        }
    })
}

/// A voxel's order-0 source `ρ·σa·Le·e` as stored (f32): the one formula for what is written and
/// for the power counted.
fn source_value(rho: f32, scale: f64, e: f32) -> f32 {
    (rho as f64 * scale * e as f64) as f32
}

/// Writes the order-0 source of the emission field into `source` (fresh: all zero).
pub fn write_initial_source(store: &BrickStore, plan: &Plan, source: &mut Field) -> Result<(), SolveError> {
    let emission = open_emission(store)?;
    let c = plan.channels as usize;
    let storage = plan.storage.solid_angle.len();
    let scale = scales(plan);
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    for brick in bricks {
        let (Some(density), Some(e), Some(dst)) =
            (store.density_brick(brick), emission.brick(brick), source.brick_mut(brick))
        else {
            continue;
        };
        // Component d·C + ch: channel ch's block, the same for every storage direction d.
        for ch in 0..c {
            let (first, rest) = dst.split_at_mut(c * BRICK_VOXELS);
            let block = &mut first[ch * BRICK_VOXELS..(ch + 1) * BRICK_VOXELS];
            for ((o, &rho), &e) in block.iter_mut().zip(density).zip(channel_block(e, ch)) {
                *o = source_value(rho, scale[ch], e);
            }
            for d in 1..storage {
                let k = (d - 1) * c + ch;
                rest[k * BRICK_VOXELS..(k + 1) * BRICK_VOXELS].copy_from_slice(block);
            }
        }
    }
    source.flush()?;
    Ok(())
}

/// Power the emission field emits, per channel: Σ 4π·ρσa·Le·e·h³, with the source values as the
/// rays gain them, so that the energy balance closes to round-off: the f32 values written, or,
/// where the plan stores the gained source in f16, those values rounded as both backends round
/// them before order 0 (scaled by the power of two [`half_scale_exponent`] picks from the largest,
/// rounded to f16, scaled back). Counting the f32 values there left the balance off by the
/// rounding, ~2·10⁻⁵ for a fire whose temperatures span a wide range of radiance.
pub fn emitted_power(store: &BrickStore, plan: &Plan) -> Result<[f64; 3], SolveError> {
    let emission = open_emission(store)?;
    let c = plan.channels as usize;
    let h3 = plan.voxel_size.powi(3);
    let four_pi: f64 = plan.storage.solid_angle.iter().sum();
    let scale = scales(plan);
    // Each voxel's source value per channel, brick by brick, for `visit`.
    let each = |visit: &mut dyn FnMut(usize, f32)| {
        for brick in store.occupied_bricks() {
            let (Some(density), Some(e)) = (store.density_brick(brick), emission.brick(brick)) else {
                continue;
            };
            for (ch, &s) in scale.iter().enumerate().take(c) {
                for (&rho, &e) in density.iter().zip(channel_block(e, ch)) {
                    visit(ch, source_value(rho, s, e));
                }
            }
        }
    };
    let gained: Box<dyn Fn(f32) -> f64> = if plan.source_precision == Precision::F16 {
        let mut largest = 0f32;
        each(&mut |_, v| largest = largest.max(v.abs()));
        let e = half_scale_exponent(largest);
        let (up, down) = (power_of_two(e), power_of_two(-e));
        Box::new(move |v| (half::f16::from_f32(v * up).to_f32() * down) as f64)
    } else {
        Box::new(|v| v as f64)
    };
    let mut sums = [0.0f64; 3];
    each(&mut |ch, v| sums[ch] += gained(v));
    Ok(sums.map(|s| four_pi * s * h3))
}
