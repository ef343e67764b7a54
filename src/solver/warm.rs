//! Warm start: a solve that begins from a guess of its answer — the previous frame's solution in
//! an animation — instead of from nothing, and still converges to the answer of a cold solve.
//!
//! # The formulation
//!
//! Write the solve for the in-scattered source J (summed over orders) as J = b + K J: b is the
//! source the unscattered light produces (order 0: boundary, sun beams, emission) and K is one
//! transport-and-scatter step (a sweep gaining from a source, then collect). Source iteration is
//! J = Σ_k K^k b. From a guess x0 write J = x0 + e; then e = r + K e with the residual
//!
//! ```text
//!   r = b + K x0 − x0,        e = Σ_n K^n r,        J = x0 + e
//! ```
//!
//! so e is found by plain source iteration from r. The order loop does exactly this without new
//! passes: x0 is placed in the source field that order 0 gains from (order 0's sweeps always gain
//! from `source_prev`, which is zero in a cold solve), so order 0 transports the boundary light
//! and x0 together: its new source is b + K x0, its fluence φ(L⁰) + T x0 (T: transport to
//! fluence). The end-of-order pass then commits the new source to the total as usual (total =
//! b + K x0 = x0 + r) and takes x0 back off what the next order propagates (`source_prev` = r),
//! see [`super::fields::StoreFields::commit_order`]. Every later order is plain source iteration
//! on r: the totals become x0 + Σ K^n r = J and φ(L⁰) + T J, the very quantities a cold solve
//! converges to.
//!
//! # What changes with a residual of either sign
//!
//! r is positive where the new frame holds more light than the guess and negative where it holds
//! less; transport is linear, so the sweeps need no change. The order loop's measures do: the
//! power of an order (what the ratio ρ and the tail are estimated from) is the norm Σ|J|·Ω·h³
//! rather than the signed sum (which cancels), and the stop rule's per-voxel remaining error uses
//! |φ_k| (see [`super::remaining`]). For a cold solve every value is ≥ 0 and both are unchanged,
//! bit for bit. The energy balance closes with the signed power of the last, unpropagated residual
//! (in + emitted = out + absorbed + Σ signed r_last): the guess's own power cancels between order
//! 0's gain and the commit.
//!
//! # Precision
//!
//! Where the plan stores the previous source as f16, order 0 reads x0 rounded to f16 (scaled per
//! order by a power of two): the guess is rounded the same way before it is placed, so the x0
//! transported and the x0 taken back off are the same numbers and the residual is exact.
//!
//! Only the GPU backend takes a warm start (the CPU twin keeps its fields in memory).

use super::fields::StoreFields;
use super::plan::{half_scale_exponent, power_of_two, Plan, Precision};
use super::SolveError;
use crate::store::{BrickStore, BRICK_EDGE, BRICK_VOXELS};
use std::path::{Path, PathBuf};

/// How far below zero, relative to the guess's largest value, a warm start's source may read and
/// still be taken (as 0): the rounding of f16 residual orders, never a real negative source.
pub const NEGATIVE_ROUNDING: f32 = 1e-3;

/// Why a warm start cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum WarmStartError {
    #[error("warm start from {}: {message}", .dir.display())]
    Unusable { dir: PathBuf, message: String },
    #[error("warm start needs the GPU backend (the CPU twin keeps its fields in memory)")]
    NeedsGpu,
    #[error("warm start does not yet combine with a per-voxel emission (an emission or temperature grid, or emission over a per-voxel albedo): solve this frame cold")]
    WithEmissionGrid,
}

/// Places the solution in the output directory `dir` (its exported `source.raw` and
/// `source.json`) into `fields` as the guess x0, for the scene of `plan` over `store`. Voxels
/// without medium get 0 (nothing scatters there). Returns the guess's scattered power.
pub fn seed(store: &BrickStore, plan: &Plan, fields: &mut StoreFields, dir: &Path) -> Result<f64, SolveError> {
    let unusable =
        |message: String| SolveError::WarmStart(WarmStartError::Unusable { dir: dir.to_path_buf(), message });
    let info = crate::output::read_field_json(&dir.join("source.json")).map_err(|e| unusable(e.to_string()))?;
    let comps = plan.source_components();
    if info.dims != plan.dims {
        return Err(unusable(format!("its source has {:?} voxels, this scene {:?}", info.dims, plan.dims)));
    }
    if info.components != comps {
        return Err(unusable(format!(
            "its source has {} components per voxel, this solve's plan {} (channels or storage directions differ)",
            info.components, comps
        )));
    }
    let raw_path = dir.join(&info.file);
    let file = std::fs::File::open(&raw_path).map_err(|e| unusable(format!("{}: {e}", raw_path.display())))?;
    // SAFETY: the file is an output of a finished solve, mapped read-only; it is only read here.
    let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| unusable(format!("{}: {e}", raw_path.display())))?;
    let [nx, ny, nz] = plan.dims.map(|d| d as usize);
    let c = comps as usize;
    if map.len() != nx * ny * nz * c * 4 {
        return Err(unusable(format!(
            "{}: {} bytes, expected {}",
            raw_path.display(),
            map.len(),
            nx * ny * nz * c * 4
        )));
    }
    let value = |i: usize| f32::from_le_bytes([map[4 * i], map[4 * i + 1], map[4 * i + 2], map[4 * i + 3]]);

    let guess = &mut fields.source_prev;
    let grid = *store.grid();
    let mut max_abs = 0.0f32;
    // The most negative value and where: an in-scattered source is ≥ 0, and a guess below zero
    // would be refused (see below the loop).
    let mut worst: Option<(f32, [usize; 3], usize)> = None;
    for brick in store.occupied_bricks() {
        let origin = grid.brick_origin(grid.brick_coords(brick)).map(|o| o as usize);
        let density = store.density_brick(brick);
        let Some(out) = guess.brick_mut(brick) else { continue };
        for local in 0..BRICK_VOXELS {
            let e = BRICK_EDGE as usize;
            let (x, y, z) = (origin[0] + local % e, origin[1] + (local / e) % e, origin[2] + local / (e * e));
            let inside = x < nx && y < ny && z < nz;
            let has_medium = density.as_ref().is_some_and(|d| d[local] > 0.0);
            for k in 0..c {
                let v = if inside && has_medium { value(((z * ny + y) * nx + x) * c + k) } else { 0.0 };
                if !v.is_finite() {
                    return Err(unusable(format!(
                        "{}: `source` is not finite ({v}) at voxel ({x}, {y}, {z}), component {k}",
                        raw_path.display()
                    )));
                }
                if v < 0.0 && worst.is_none_or(|w| v < w.0) {
                    worst = Some((v, [x, y, z], k));
                }
                let v = v.max(0.0);
                out[k * BRICK_VOXELS + local] = v;
                max_abs = max_abs.max(v.abs());
            }
        }
    }
    store.release_all_density();
    // A finished solve's source is ≥ 0 up to the rounding of a warm-started f16 chain (its
    // residual orders carry either sign): values below zero by at most NEGATIVE_ROUNDING of the
    // largest are that rounding and taken as 0; anything more is not a solution of this kind and
    // is refused (issue 57: a guess of −1e6 everywhere was accepted and reported converged).
    if let Some((v, [x, y, z], k)) = worst {
        if -v > NEGATIVE_ROUNDING * max_abs {
            return Err(unusable(format!(
                "{}: `source` is negative ({v:e}) at voxel ({x}, {y}, {z}), component {k}: a warm start's \
                 guess is an in-scattered source, finite and ≥ 0 (the source.raw of a finished solve of this scene)",
                raw_path.display()
            )));
        }
    }
    if plan.source_precision == Precision::F16 {
        // Exactly what order 0 will read (see the module docs). Rounding may carry the largest
        // value over a power of two, and order 0 then picks a scale half as large: round again at
        // that scale (halving keeps f16 values exact but for the tiniest), until it stays put.
        let mut exponent = half_scale_exponent(max_abs);
        loop {
            let scale = power_of_two(exponent);
            for v in guess.as_mut_slice() {
                *v = half::f16::from_f32(*v * scale).to_f32() / scale;
            }
            let again = half_scale_exponent(guess.max_abs());
            if again == exponent {
                break;
            }
            exponent = again;
        }
    }
    fields.mark_initial_guess();
    let h3 = plan.voxel_size.powi(3);
    let mut power = 0.0;
    for brick in store.occupied_bricks() {
        if let Some(b) = fields.source_prev.brick(brick) {
            for (k, block) in b.chunks(BRICK_VOXELS).enumerate() {
                let weight = plan.storage.solid_angle[k / plan.channels as usize] * h3;
                power += weight * block.iter().map(|&v| v as f64).sum::<f64>();
            }
        }
    }
    fields.source_prev.release_all();
    fields.source_prev.flush()?;
    Ok(power)
}
