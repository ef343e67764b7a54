//! What the medium says, before any order runs, about how slowly the order series will decay: the
//! progress estimate's prior ([`crate::progress::DecayPrior`]).
//!
//! The orders shrink, eventually, by the spectral radius of one scattering-and-transport step. The
//! first orders do not show it: their ratio creeps up for tens of orders where light has to build
//! up deep inside a thick region (`tools/scenes/dense_core_cloud_16.toml`: 0.44 after order 1,
//! 0.85 at the end), so the ETA after order 1 needs it from elsewhere. Where the diffusion
//! acceleration works ([`super::acceleration`]) the slow, diffusive modes are taken out and the
//! corrected series decays fast; what stays slow is the plain series in the part of the medium the
//! acceleration does not cover: all of it when the acceleration is off, else the voxels too thick
//! for its grid ([`super::acceleration::in_grid`]).
//!
//! For that part, diffusion theory gives the plain series' ratio: its fundamental mode φ with
//! −∇·D∇φ = −D·B²φ satisfies σs·φ/ρ = σt·φ + D·B²φ, so
//!
//! ```text
//!   ρ = σs / (σt + B²/(3 σtr)),   σtr = σt − ḡ σs,   B = π / (R + 0.7104/σtr)
//! ```
//!
//! for a sphere of radius R (the part's voxels gathered into one ball: the shape that keeps light
//! longest, so the ratio errs high, toward more orders), its extrapolated boundary 0.7104 transport
//! mean free paths out (Milne's problem). The coefficients are the part's σt-weighted means: the
//! fundamental mode lives where the medium is dense, not in its thin fringe. The largest ratio
//! over the channels is the prior. Measured against the ratios the series reached
//! (benches/RESULTS.md, "Progress and ETA").

use super::acceleration::in_grid;
use super::plan::Plan;
use crate::store::BrickStore;

/// Milne's extrapolation distance, in transport mean free paths.
const EXTRAPOLATION: f64 = 0.7104;

/// Running sums over the voxels of the part the acceleration leaves to the plain series, per
/// channel, in units of the voxel (σ·h).
#[derive(Clone, Copy, Debug, Default)]
struct Sums {
    voxels: f64,
    /// Σ σt, Σ σt², Σ σt·σs, Σ σt·σtr.
    t: [f64; 3],
    tt: [f64; 3],
    ts: [f64; 3],
    ttr: [f64; 3],
}

/// The plain series' ratio in the medium's slow part (see the module docs), from the densities of
/// its voxels; `covered` says which densities the acceleration covers (never, when it is off).
/// `extinction[ch]`, `scattering[ch]`: per unit density and unit length; `voxel_size` the voxel's
/// edge; `g` the mean cosine of the scattering the solver does. `None` when no voxel is left to
/// the plain series or nothing scatters there.
pub fn plain_ratio(
    densities: impl Iterator<Item = f64>,
    covered: impl Fn(f64) -> bool,
    extinction: &[f64],
    scattering: &[f64],
    voxel_size: f64,
    g: f64,
) -> Option<f64> {
    let channels = extinction.len().min(scattering.len()).min(3);
    let mut s = Sums::default();
    for rho in densities {
        if !(rho > 0.0 && rho.is_finite()) || covered(rho) {
            continue;
        }
        s.voxels += 1.0;
        for ch in 0..channels {
            let t = rho * extinction[ch] * voxel_size;
            let sc = rho * scattering[ch] * voxel_size;
            s.t[ch] += t;
            s.tt[ch] += t * t;
            s.ts[ch] += t * sc;
            s.ttr[ch] += t * (t - g * sc);
        }
    }
    if s.voxels == 0.0 {
        return None;
    }
    // The ball's radius in voxels.
    let radius = (3.0 * s.voxels / (4.0 * std::f64::consts::PI)).cbrt();
    (0..channels)
        .filter(|&ch| s.t[ch] > 0.0)
        .map(|ch| {
            let (st, ss, str_) = (s.tt[ch] / s.t[ch], s.ts[ch] / s.t[ch], s.ttr[ch] / s.t[ch]);
            let b = std::f64::consts::PI / (radius + EXTRAPOLATION / str_);
            ss / (st + b * b / (3.0 * str_))
        })
        .filter(|r| r.is_finite() && *r > 0.0)
        .fold(None, |best: Option<f64>, r| Some(best.map_or(r, |b| b.max(r))))
}

/// The prior for a solve of `plan` over `store`'s medium: whether the acceleration corrects the
/// orders, and the plain series' ratio where it does not ([`plain_ratio`]). One pass over the
/// occupied bricks' densities.
pub fn prior(plan: &Plan, store: &BrickStore) -> crate::progress::DecayPrior {
    let channels = plan.channels as usize;
    let extinction: Vec<f64> = (0..channels).map(|ch| plan.coefficients(ch).0).collect();
    let scattering: Vec<f64> = (0..channels).map(|ch| plan.coefficients(ch).1).collect();
    let densities =
        store.occupied_bricks().filter_map(|b| store.density_brick(b)).flat_map(|d| d.iter().map(|&v| f64::from(v)));
    let plain = plain_ratio(
        densities,
        |rho| plan.acceleration && in_grid(plan, rho),
        &extinction,
        &scattering,
        plan.voxel_size,
        plan.effective_g,
    );
    crate::progress::DecayPrior { accelerated: Some(plan.acceleration), plain_ratio: plain }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The dense core of `tools/scenes/dense_core_cloud_16.toml`: 108 voxels at σt·h = 3.2 (too
    /// thick for the acceleration's grid), albedo 0.9, isotropic. Its series' ratio reached 0.851.
    #[test]
    fn the_dense_core_left_to_the_plain_series() {
        let core = std::iter::repeat_n(1.0, 108);
        let rho = plain_ratio(core, |_| false, &[0.8], &[0.72], 4.0, 0.0).expect("a ratio");
        assert!((rho - 0.872).abs() < 0.002, "{rho}");
    }

    #[test]
    fn a_covered_or_empty_medium_has_no_plain_part() {
        let thin = std::iter::repeat_n(0.5, 1000);
        assert_eq!(plain_ratio(thin, |_| true, &[0.8], &[0.72], 1.0, 0.0), None);
        assert_eq!(plain_ratio(std::iter::repeat_n(0.0, 10), |_| false, &[0.8], &[0.72], 1.0, 0.0), None);
    }

    /// Bigger and thicker parts keep light longer: the ratio rises toward the albedo; the densest
    /// channel decides.
    #[test]
    fn the_ratio_rises_with_the_optical_size_toward_the_albedo() {
        let ratio = |n: usize, rho: f64| {
            plain_ratio(std::iter::repeat_n(rho, n), |_| false, &[1.0, 2.0], &[0.9, 1.8], 1.0, 0.0).expect("a ratio")
        };
        assert!(ratio(1000, 0.5) < ratio(8000, 0.5));
        assert!(ratio(1000, 0.5) < ratio(1000, 1.0));
        assert!(ratio(100_000, 10.0) < 0.9 && ratio(100_000, 10.0) > 0.899);
        let grey = plain_ratio(std::iter::repeat_n(0.5, 1000), |_| false, &[2.0], &[1.8], 1.0, 0.0);
        assert_eq!(grey, Some(ratio(1000, 0.5)));
    }
}
