//! A sun's uncollided irradiance per voxel traced along its exact direction: what the image's
//! exact single scattering multiplies ([`super::direct`], [`crate::render::march`]).
//!
//! **Why not the sweep's.** Order 0's beam sweep (the twin's `cpu_sweep`, [`super::sweep`])
//! carries a beam plane by plane over the lattice of voxel columns: one ray per column, and with
//! `spatial = "constant"` (the default where the medium scatters) each ray takes, in each plane,
//! the column nearest to it, a staircase up to half a voxel off its line. That is the solve's
//! discretisation and what its first scattering holds; for the image it is too coarse where the light grazes the medium. Seen
//! towards the sun, a cloud's rim is the edge of its own shadow, where half a voxel sideways
//! changes the optical depth to the sun a lot: on the 48³ cloud of `tools/forward_image_table.sh`
//! (σt 0.8 per voxel) the swept and the traced irradiance differ by 23 % rms over the scattering
//! voxels (weighted by ρ·E), and its four backlit views came out 5.2–8.1 % from Monte Carlo with
//! the swept irradiance, 4.1–6.6 % with the traced one (against 1024-path references, the lobes of
//! the time); side- and front-lit views, lit where the staircase averages out, are unchanged
//! (benches/RESULTS.md, "Render: the suns' single scattering exact"). Tracing through the voxels'
//! centres alone, or averaging 27 points per voxel, gave the same images within the reference's
//! noise: the chord average is the cheap one.
//!
//! **What.** For every voxel that scatters (ρ > 0: the image weighs the irradiance by ρ, so the
//! others are left at 0), the chord through the voxel's centre along the beam: ∫ρ ds from the
//! centre to the volume's boundary towards the sun by an exact 3-D DDA through the
//! piecewise-constant densities ([`super::point::optical_path`]), less the half chord inside the
//! voxel itself, is the optical path ρτ to where the chord enters the voxel. The voxel's value is
//! the chord's average, `B·e^{−σ·ρτ}·(1 − e^{−σ·ρ·s})/(σ·ρ·s)` (B the beam's irradiance at the
//! boundary, s the chord's length, σ the extinction per unit density and voxel): the sweep's own
//! segment average, along the true line. One walk serves every component (channels, and the true
//! and the δ-M scaled extinction). Each voxel is computed alone, so the result is bitwise the same
//! on any number of threads (rayon).
//!
//! **Cost.** One walk per scattering voxel, as many steps as voxels lie between it and the
//! boundary: O(N^{4/3}) for N voxels where the sweep is O(N). The split estimates the steps first
//! and keeps the sweep's irradiance past [`TRACE_LIMIT_STEPS`] (logged, and said in
//! `report.json`'s reasons, as is the trace's time when it runs). On the 2-core VM the table's 48³
//! cloud takes under 0.01 s; a 160³ cloud (275,000 scattering voxels, 6.6·10⁷ estimated steps)
//! 0.41 s, beside 22 s for one order of its solve.

use super::point::optical_path;
use super::segment::e1;
use glam::DVec3;
use rayon::prelude::*;

/// Most DDA steps (estimated: scattering voxels × half the volume's dims summed) the trace may
/// take; beyond, the image keeps the sweep's irradiance. About a minute on two cores (1.6·10⁸
/// estimated steps a second, measured on a 160³ cloud), less on more.
pub const TRACE_LIMIT_STEPS: u64 = 10_000_000_000;

/// The estimated DDA steps of [`trace_beam`] over `density` (see [`TRACE_LIMIT_STEPS`]): a walk
/// from a voxel to the boundary crosses at most the dims summed, on average about half.
pub fn estimated_steps(dims: [u32; 3], density: &[f64]) -> u64 {
    let scattering = density.iter().filter(|&&r| r > 0.0).count() as u64;
    scattering.saturating_mul(dims.iter().map(|&d| u64::from(d)).sum::<u64>() / 2)
}

/// Per voxel of a `dims` volume (x fastest, `density` ρ per voxel as the twin holds it), the
/// chord-average irradiance of a beam travelling along `travel` (unit, voxel frame), one value per
/// component k: `boundary[k]·…` with extinction `sigma[k]` per unit density and voxel length
/// (σt·h). Written to `out[voxel·K + k]`, K = `sigma.len()`; 0 where ρ = 0.
pub fn trace_beam(dims: [u32; 3], density: &[f64], travel: DVec3, boundary: &[f64], sigma: &[f64], out: &mut [f64]) {
    let k = sigma.len();
    assert_eq!(boundary.len(), k, "one boundary irradiance per component");
    let [nx, ny, _] = dims.map(|d| d as usize);
    let index = |v: [u32; 3]| v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize);
    let rho_at = |v: [u32; 3]| density[index(v)] as f32;
    // Far enough towards the sun to leave the volume from anywhere in it (the walk is clipped).
    let beyond = dims.iter().map(|&d| d as f64).sum::<f64>() + 1.0;
    // The chord through a unit voxel's centre along `travel`.
    let chord = 1.0 / travel.abs().max_element();
    out.par_chunks_mut(k).enumerate().for_each(|(i, values)| {
        let rho = density[i];
        if !(rho > 0.0) {
            values.iter_mut().for_each(|v| *v = 0.0);
            return;
        }
        let v = [i % nx, (i / nx) % ny, i / (nx * ny)].map(|c| c as f64);
        let centre = DVec3::new(v[0] + 0.5, v[1] + 0.5, v[2] + 0.5);
        let to_centre = optical_path(dims, &rho_at, centre, centre - travel * beyond);
        let entry = (to_centre - 0.5 * rho * chord).max(0.0);
        for ((value, &b), &s) in values.iter_mut().zip(boundary).zip(sigma) {
            // The chord's average of e^{−σ·ρ·u} over its length: the sweep's own segment average.
            *value = b * (-s * entry).exp() * e1(s * rho * chord);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A uniform slab lit obliquely, at a slope the sweep's staircase gets wrong (half a voxel per
    /// plane): every voxel's value is the closed-form chord average, e^{−σ·depth/μ} over the
    /// chord, to round-off.
    #[test]
    fn a_uniform_slab_gets_the_closed_form_chord_average() {
        let dims = [12u32, 12, 10];
        let density = vec![0.5; 12 * 12 * 10];
        let travel = DVec3::new(0.0, 0.5, 1.0).normalize();
        let (b, sigma) = ([2.0, 3.0], [0.8, 0.3]);
        let mut out = vec![0.0; density.len() * 2];
        trace_beam(dims, &density, travel, &b, &sigma, &mut out);
        let chord = 1.0 / travel.z;
        let mut checked = 0;
        for z in 0..10usize {
            for y in 0..12usize {
                for x in 0..12usize {
                    // Only voxels whose chord towards the sun leaves through the top face (z = 0).
                    let reach = (z as f64 + 0.5) * travel.y / travel.z;
                    if (y as f64 + 0.5) - reach < 0.0 {
                        continue;
                    }
                    let i = x + 12 * (y + 12 * z);
                    for k in 0..2 {
                        let entry = 0.5 * (z as f64) * chord;
                        let inside = sigma[k] * 0.5 * chord;
                        let want = b[k] * (-sigma[k] * entry).exp() * (1.0 - (-inside).exp()) / inside;
                        let got = out[i * 2 + k];
                        assert!((got / want - 1.0).abs() < 1e-12, "voxel {x},{y},{z} k {k}: {got} vs {want}");
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 1000, "{checked}");
    }

    /// Empty voxels read 0 (the image weighs the irradiance by ρ); light crossing empty voxels
    /// on its way is not dimmed by them.
    #[test]
    fn empty_voxels_are_zero_and_do_not_dim() {
        let dims = [4u32, 4, 4];
        let mut density = vec![0.0; 64];
        density[1 + 4 * (1 + 4 * 3)] = 1.0; // one voxel at z = 3, lit from z = 0 through empty space
        let mut out = vec![0.0; 64];
        trace_beam(dims, &density, DVec3::Z, &[1.0], &[0.4], &mut out);
        assert!(out.iter().enumerate().all(|(i, &v)| (density[i] > 0.0) == (v > 0.0)));
        let want = (1.0 - (-0.4f64).exp()) / 0.4;
        assert!((out[1 + 4 * (1 + 4 * 3)] - want).abs() < 1e-15);
    }
}
