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
//!
//! Where the plan traces the emission's uncollided light instead (`solver.emission_uncollided`,
//! [`super::uncollided`]), none of this is written: the trace reads the same per-voxel source
//! (`Factors`) and hands the sweeps only its first scattering.
//!
//! With a per-voxel albedo (`volume.albedo_*`, [`crate::store::albedo`]) σa varies per voxel,
//! `σa(v) = ρ·(σt − σs·a(v))`, so a uniform emission takes this path too (with e = 1): the kernels'
//! `FLAG_EMIT` only knows the medium's σa.

use super::plan::{half_scale_exponent, power_of_two, Plan, Precision};
use super::SolveError;
use crate::store::albedo::open_albedo;
use crate::store::emission::{channel_block, open_emission};
use crate::store::{BrickStore, Field, BRICK_VOXELS};

/// (σt·Le, σs·Le) per channel: a voxel of density 1, emission factor 1 and albedo factor a has
/// the order-0 source σt·Le − σs·Le·a = σa·Le (a = 1 without an albedo grid).
pub(crate) fn scales(plan: &Plan) -> [(f64, f64); 3] {
    std::array::from_fn(|ch| {
        if ch < plan.channels as usize {
            let (st, ss, _) = plan.coefficients(ch);
            let le = plan.medium.emission[ch];
            (st * le, ss * le)
        } else {
            (0.0, 0.0)
        }
    })
}

/// A voxel's order-0 source `ρ·(σt − σs·a)·Le·e` as stored (f32): the one formula for what is
/// written and for the power counted. Without an albedo grid (a = 1) this is `ρ·σa·Le·e` exactly
/// as before the albedo grid existed.
fn source_value(rho: f32, (st_le, ss_le): (f64, f64), a: f32, e: f32) -> f32 {
    (rho as f64 * (st_le - ss_le * a as f64) * e as f64) as f32
}

/// The per-voxel fields the emission's source is formed from: the emission factor (when the
/// scene has an emission grid) and the albedo factor (when it has an albedo grid).
pub(crate) struct Factors {
    emission: Option<Field>,
    albedo: Option<Field>,
}

impl Factors {
    pub(crate) fn open(store: &BrickStore, plan: &Plan) -> Result<Factors, SolveError> {
        Ok(Factors {
            emission: if plan.emission_grid { Some(open_emission(store)?) } else { None },
            albedo: if plan.albedo_field { Some(open_albedo(store)?) } else { None },
        })
    }

    /// Calls `visit(local, source)` for every voxel of `brick` in channel `ch` (density `density`).
    pub(crate) fn each(
        &self,
        brick: usize,
        density: &[f32],
        ch: usize,
        scale: (f64, f64),
        visit: &mut dyn FnMut(usize, f32),
    ) {
        let e = self.emission.as_ref().and_then(|f| f.brick(brick)).map(|b| channel_block(b, ch));
        let a = self.albedo.as_ref().and_then(|f| f.brick(brick));
        for (l, &rho) in density.iter().enumerate() {
            let e = e.map_or(1.0, |e| e[l]);
            let a = a.map_or(1.0, |a| a[l]);
            visit(l, source_value(rho, scale, a, e));
        }
    }
}

/// Writes the order-0 source of the per-voxel emission into `source` (fresh: all zero).
pub fn write_initial_source(store: &BrickStore, plan: &Plan, source: &mut Field) -> Result<(), SolveError> {
    let factors = Factors::open(store, plan)?;
    let c = plan.channels as usize;
    let storage = plan.storage.solid_angle.len();
    let scale = scales(plan);
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    for brick in bricks {
        let (Some(density), Some(dst)) = (store.density_brick(brick), source.brick_mut(brick)) else {
            continue;
        };
        // Component d·C + ch: channel ch's block, the same for every storage direction d.
        for ch in 0..c {
            let (first, rest) = dst.split_at_mut(c * BRICK_VOXELS);
            let block = &mut first[ch * BRICK_VOXELS..(ch + 1) * BRICK_VOXELS];
            factors.each(brick, density, ch, scale[ch], &mut |l, v| block[l] = v);
            for d in 1..storage {
                let k = (d - 1) * c + ch;
                rest[k * BRICK_VOXELS..(k + 1) * BRICK_VOXELS].copy_from_slice(block);
            }
        }
    }
    source.flush()?;
    Ok(())
}

/// Power the per-voxel emission emits, per channel: Σ 4π·ρσa(v)·Le·e·h³, with the source values as
/// the rays gain them, so that the energy balance closes to round-off: the f32 values written, or,
/// where the plan stores the gained source in f16, those values rounded as both backends round
/// them before order 0 (scaled by the power of two [`half_scale_exponent`] picks from the largest,
/// rounded to f16, scaled back). Counting the f32 values there left the balance off by the
/// rounding, ~2·10⁻⁵ for a fire whose temperatures span a wide range of radiance.
pub fn emitted_power(store: &BrickStore, plan: &Plan) -> Result<[f64; 3], SolveError> {
    let factors = Factors::open(store, plan)?;
    let c = plan.channels as usize;
    let h3 = plan.voxel_size.powi(3);
    let four_pi: f64 = plan.storage.solid_angle.iter().sum();
    let scale = scales(plan);
    // Each voxel's source value per channel, brick by brick, for `visit`.
    let each = |visit: &mut dyn FnMut(usize, f32)| {
        for brick in store.occupied_bricks() {
            let Some(density) = store.density_brick(brick) else {
                continue;
            };
            for (ch, &s) in scale.iter().enumerate().take(c) {
                factors.each(brick, density, ch, s, &mut |_, v| visit(ch, v));
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
