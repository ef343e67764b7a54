//! One camera ray through the volume: box intersection, exact voxel walk, closed-form integration.
//!
//! Along the ray the source is sampled trilinearly in space (between voxel centres) and blended in
//! direction between the storage directions around the ray's direction
//! ([`crate::quadrature::StorageBlend`]), so the image is continuous both across voxels and across
//! storage cells: neighbouring pixels whose rays fall in different storage cells no longer see a
//! jump (a straight seam across a pinhole image, bands on a face lit from the side).
//!
//! The suns' single scattering, when given ([`super::SingleScattering`]), is added per segment as
//! `σs·Σ_b p_HG(g; ω_b·ω)·E_b` with the scene's true σs and g, E_b interpolated between voxel
//! centres in optical depth (kept at the centres, `crate::solver::beam_trace`; render data of
//! format 3 and the sweep's voxel averages: ρ·a·E_b interpolated as the source is) and integrated
//! over each segment with its growth towards the sun, and attenuated towards the camera by the
//! true extinction: under δ-M
//! the march keeps a second transmittance for it (the solved source travels with the scaled σt,
//! as before); without δ-M it joins the source under the one transmittance. Under δ-M the phase
//! becomes the peak's chain sum at τ = ln(E*_b/E_b) and multiplies the scaled irradiance E*_b
//! ([`super::peak`]); its τ = 0 term is the single scattering above. Point lights are scattered
//! alike, their light arriving at x along x − position (so the phase is evaluated per sample).
//! Under δ-M the suns' forward lobes join the single scattering where they exceed what the solve's
//! storage cells hold of them towards the camera (`super::peak`, "The forward lobes"), and travel
//! with it under the true extinction; each sun's cone (`super::cone`) adds how far the light's
//! sideways spread moves the chains' and lobes' light (a thin rim loses some, a core gains).

use super::peak::{chain_phase, PeakChains};
use super::RenderInputs;
use crate::quadrature::Blend;
use crate::store::{Field, BRICK_VOXELS};
use glam::DVec3;

/// A ray stops once every channel's transmittance is below this: what lies behind can change the
/// pixel by at most this fraction of its remaining radiance.
const OPAQUE: f64 = 1e-9;

/// Parametric interval `[t0, t1]` (t0 ≥ 0) where `origin + t·dir` is inside the box `[0, size]`,
/// or `None` when the ray misses it.
pub fn intersect_box(origin: DVec3, dir: DVec3, size: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        if dir[a] != 0.0 {
            let ta = (0.0 - origin[a]) / dir[a];
            let tb = (size[a] - origin[a]) / dir[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        } else if origin[a] < 0.0 || origin[a] > size[a] {
            return None;
        }
    }
    (t0 < t1).then_some((t0, t1))
}

/// Calls `visit(voxel, segment length)` for each voxel the ray crosses between `t0` and `t1`, in order
/// (Amanatides–Woo). `visit` returns false to stop early. Boundaries are recomputed from the voxel
/// index at each step rather than accumulated, so the segment lengths sum to `t1 − t0` without drift.
pub fn walk_voxels(
    origin: DVec3,
    dir: DVec3,
    (t0, t1): (f64, f64),
    dims: [u32; 3],
    h: f64,
    mut visit: impl FnMut([u32; 3], f64) -> bool,
) {
    let p = origin + dir * t0;
    let mut voxel = [0i64; 3];
    let mut step = [0i64; 3];
    let mut t_next = [f64::INFINITY; 3];
    let boundary = |i: i64, s: i64| (if s > 0 { (i + 1) as f64 } else { i as f64 }) * h;
    for a in 0..3 {
        voxel[a] = ((p[a] / h).floor() as i64).clamp(0, dims[a] as i64 - 1);
        if dir[a] != 0.0 {
            step[a] = if dir[a] > 0.0 { 1 } else { -1 };
            t_next[a] = (boundary(voxel[a], step[a]) - origin[a]) / dir[a];
        }
    }
    let mut t = t0;
    loop {
        let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
            0
        } else if t_next[1] <= t_next[2] {
            1
        } else {
            2
        };
        let t_end = t_next[a].min(t1);
        let v = [voxel[0] as u32, voxel[1] as u32, voxel[2] as u32];
        if !visit(v, (t_end - t).max(0.0)) || t_end >= t1 {
            return;
        }
        t = t_end;
        voxel[a] += step[a];
        if voxel[a] < 0 || voxel[a] >= dims[a] as i64 {
            return;
        }
        t_next[a] = (boundary(voxel[a], step[a]) - origin[a]) / dir[a];
    }
}

/// Radiance (per channel) arriving at `origin` along `−dir` from the medium (its in-scattered source
/// and emission, attenuated on the way), and the transmittance of the whole ray per channel: the
/// pixel is `radiance + transmittance·background`.
pub fn march_ray(inputs: &RenderInputs, origin: DVec3, dir: DVec3) -> ([f64; 3], [f64; 3]) {
    let grid = inputs.store.grid();
    let h = inputs.store.voxel_size();
    let size = DVec3::new(grid.dims[0] as f64, grid.dims[1] as f64, grid.dims[2] as f64) * h;
    let mut radiance = [0.0; 3];
    let mut transmittance = [1.0; 3];
    if let Some(span) = intersect_box(origin, dir, size) {
        // The light reaching the camera travels along −dir: J is blended for that direction from
        // the storage directions around it (one with weight 1 for an isotropic medium).
        let last = inputs.storage_dirs.saturating_sub(1);
        let blend = (inputs.storage_lookup)(-dir);
        let m = inputs.medium;
        // The suns' single scattering: the phase function between each sun's light and the
        // light reaching the camera (along −dir) is the same all along the ray.
        let single = inputs.single.map(|s| {
            let phases: Vec<PeakChains> = s
                .beams
                .iter()
                .map(|b| {
                    let mu = b.travel.dot(-dir);
                    if s.peak_chains {
                        PeakChains::new(s.medium.g, mu)
                    } else {
                        PeakChains::single(s.medium.g, mu)
                    }
                })
                .collect();
            // Per sun, how far each forward lobe's sharp shape exceeds its bins towards the camera.
            let excess: Vec<Vec<f64>> = s.lobes.iter().map(|l| l.excess(-dir, &blend)).collect();
            // Per sun with a cone, the cells' phase towards the camera (`super::cone`).
            let cones: Vec<_> = s.cones.iter().map(|c| c.as_ref().map(|c| (c, c.weights(-dir)))).collect();
            (s, phases, excess, cones)
        });
        // Under δ-M the march attenuates the solved source with the scaled extinction; the exact
        // single scattering travels to the camera with the true one.
        let apart = single.as_ref().is_some_and(|(s, ..)| s.medium.sigma_t != m.sigma_t);
        let mut true_transmittance = [1.0f64; 3];
        let mut t = span.0;
        walk_voxels(origin, dir, span, grid.dims, h, |_, s| {
            let segment = s;
            // Density and source are sampled trilinearly (between voxel centres, clamped at the
            // volume's edge) at the segment's midpoint, then held constant along the segment so
            // the segment integral stays exact: smooth images, exact for uniform media.
            let mid = origin + dir * (t + 0.5 * s);
            t += s;
            let corners = trilinear(mid / h, grid.dims);
            let sample = |f: &dyn Fn([u32; 3]) -> f64| corners.iter().map(|&(v, w)| w * f(v)).sum::<f64>();
            let rho = corners.map(|(v, _)| inputs.store.density_at(v) as f64);
            let density = corners.iter().zip(&rho).map(|(&(_, w), r)| w * r).sum::<f64>();
            // The emission factor per channel: a grey field's one component, or r, g, b.
            let glow: [f64; 3] = match inputs.emission {
                None => [1.0; 3],
                Some(e) if e.components() == 1 => [sample(&|v| e.value(v, 0) as f64); 3],
                Some(e) => std::array::from_fn(|ch| sample(&|v| e.value(v, ch as u32) as f64)),
            };
            // The albedo factor a(v) (1 without an albedo grid), sampled like the density.
            let albedo = inputs.albedo.map_or(1.0, |a| sample(&|v| a.value(v, 0) as f64));
            // The source per stored channel (1 or 3), blended over the storage directions.
            let bricks = corner_bricks(inputs.source, &corners);
            let source = blended_source(inputs, &blend, last, &corners, &bricks);
            // σs·Σ_b p_b·E_b per channel with the true medium (zero without suns to scatter): the
            // interpolated ρ·a times E_b interpolated in optical depth ([`beam_irradiance`]; for
            // render data without the centres' irradiance, ρ·a·E taken at the voxel centres and
            // interpolated, as the solved source σs·E is).
            let scattered: [f64; 3] = match &single {
                None => [0.0; 3],
                Some((s, phases, excess, cones)) => {
                    let a = inputs.albedo.map_or([1.0; 8], |a| corners.map(|(v, _)| a.value(v, 0) as f64));
                    let weights: [f64; 8] = std::array::from_fn(|k| corners[k].1 * rho[k] * a[k]);
                    let mut e = [0.0; 3];
                    for (b, (beam, chains)) in s.beams.iter().zip(phases).enumerate() {
                        // (No lobes without δ-M: `lobes` and `excess` are then empty.)
                        let lobe = excess.get(b).filter(|x| !x.is_empty());
                        // Its field's bricks at the corners, located once for E and E*.
                        let at = corner_bricks(beam.irradiance, &corners);
                        let v = beam_irradiance(beam, &at, 0, inputs.channels, &corners, &weights);
                        // Along the segment the sun's light grows towards the sun as e^{κ·u}
                        // (κ = σt·ρ·μ, μ the cosine between the sun's light and the camera's) while
                        // what it scatters is dimmed towards the camera as e^{−σt·u}; the march
                        // multiplies the midpoint's value by the dimming's integral alone, which
                        // overstates the product by sinh(κs/2)/(κs/2) (2.7 % a voxel at σt·ρ = 0.8
                        // looking exactly towards the sun). With the irradiance at the centres
                        // (the render data that has it), the segment's own integral is taken.
                        let grow: [f64; 3] = std::array::from_fn(|ch| {
                            let sigma = density * s.medium.sigma_t[ch];
                            let kappa = sigma * beam.travel.dot(-dir);
                            if !beam.at_centres || !(sigma > 0.0 && segment > 0.0) {
                                return 1.0;
                            }
                            path_integral(sigma - kappa, segment) * (-0.5 * kappa * segment).exp()
                                / path_integral(sigma, segment)
                        });
                        if !s.peak_chains {
                            let p = chains.single_phase();
                            for (ch, e) in e.iter_mut().enumerate() {
                                *e += grow[ch] * p * v[if inputs.channels == 1 { 0 } else { ch }];
                            }
                            continue;
                        }
                        // E*: the scaled irradiance after the true one; τ = ln(E*/E) the peak's
                        // optical depth along the sun's path (∞ where E underflowed and E* did not).
                        let scaled = beam_irradiance(beam, &at, inputs.channels, inputs.channels, &corners, &weights);
                        // With a cone: the chains and lobes below, corrected by how far the cone's
                        // light with the real geometry differs from the same held on the sun's
                        // line (`super::cone`).
                        let lateral = match cones.get(b) {
                            Some(Some((cone, towards))) => cone.lateral(mid / h, towards, scaled[0].max(v[0])),
                            _ => 0.0,
                        };
                        // Per stored channel (a grey scene's one serves r, g and b): the chain
                        // sum and, under δ-M, the forward lobes' excess over the solve's bins
                        // (`super::peak`, "The forward lobes") once each. Both travel to the
                        // camera with the true extinction.
                        let (mut phase_k, mut lobe_k) = ([0.0; 3], [0.0; 3]);
                        for (ch, e) in e.iter_mut().enumerate() {
                            let k = if inputs.channels == 1 { 0 } else { ch };
                            let (true_e, scaled_e) = (v[k], scaled[k].max(v[k]));
                            if scaled_e <= 0.0 {
                                continue;
                            }
                            let tau = if true_e > 0.0 { (scaled_e / true_e).ln() } else { f64::INFINITY };
                            if ch == k {
                                phase_k[k] = chains.phase(tau);
                                // (Lobes exist only with a peak share f > 0: τₛ = τ/f.)
                                if let (Some(excess), true) = (lobe, tau.is_finite()) {
                                    let lobes = &s.lobes[b];
                                    lobe_k[k] = lobes.light(excess, true_e, tau / lobes.peak_share(), tau);
                                }
                            }
                            // The cone carries channel 0's light; a grey medium keeps a sun's
                            // colour, E_k/E_0, everywhere.
                            let colour = if v[0] > 0.0 { v[k] / v[0] } else { 1.0 };
                            *e += phase_k[k] * scaled_e
                                + lobe_k[k]
                                + (grow[ch] - 1.0) * chains.single_phase() * true_e
                                + lateral * colour;
                        }
                    }
                    // The point lights: their light reaches x travelling from the light to x.
                    for point in &s.points {
                        let from = mid / h - point.position;
                        let mu = if from.length_squared() > 0.0 { from.normalize().dot(-dir) } else { 0.0 };
                        let at = corner_bricks(point.irradiance, &corners);
                        let v = sample_channels(&at, 0, inputs.channels, &weights);
                        let scaled = if s.peak_chains {
                            sample_channels(&at, inputs.channels, inputs.channels, &weights)
                        } else {
                            v
                        };
                        for (ch, e) in e.iter_mut().enumerate() {
                            let k = if inputs.channels == 1 { 0 } else { ch };
                            let (true_e, scaled_e) = (v[k], scaled[k].max(v[k]));
                            if scaled_e <= 0.0 {
                                continue;
                            }
                            let tau = if !s.peak_chains {
                                0.0
                            } else if true_e > 0.0 {
                                (scaled_e / true_e).ln()
                            } else {
                                f64::INFINITY
                            };
                            *e += chain_phase(s.medium.g, mu, tau) * scaled_e;
                        }
                    }
                    std::array::from_fn(|ch| s.medium.sigma_t[ch] * s.medium.albedo[ch] * e[ch])
                }
            };
            for ch in 0..3 {
                let sigma_t = density * m.sigma_t[ch];
                let sigma_a = sigma_t * (1.0 - m.albedo[ch] * albedo);
                let j = source[if inputs.channels == 1 { 0 } else { ch }];
                let mut q = j + sigma_a * m.emission[ch] * glow[ch];
                if !apart {
                    q += scattered[ch];
                }
                let x = sigma_t * s;
                radiance[ch] += transmittance[ch] * q * path_integral(sigma_t, s);
                transmittance[ch] *= (-x).exp();
                if let (true, Some((sc, ..))) = (apart, &single) {
                    let sigma_true = density * sc.medium.sigma_t[ch];
                    radiance[ch] += true_transmittance[ch] * scattered[ch] * path_integral(sigma_true, s);
                    true_transmittance[ch] *= (-sigma_true * s).exp();
                }
            }
            transmittance.iter().any(|&t| t >= OPAQUE) || (apart && true_transmittance.iter().any(|&t| t >= OPAQUE))
        });
    }
    (radiance, transmittance)
}

/// ∫₀ˢ e^{−σt·u} du, exact as σt → 0 (where it tends to s).
fn path_integral(sigma_t: f64, s: f64) -> f64 {
    if sigma_t > 0.0 {
        -(-sigma_t * s).exp_m1() / sigma_t
    } else {
        s
    }
}

/// A field's `channels` components (1 or 3) from component `first` on, at the trilinear corners
/// located in `bricks` ([`corner_bricks`]), summed with `weights` (one per corner: the trilinear
/// weight times whatever multiplies the field there); outside the volume and in unstored bricks it
/// reads 0, as `Field::value` has it.
fn sample_channels(bricks: &CornerBricks, first: u32, channels: u32, weights: &[f64; 8]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (brick, &w) in bricks.iter().zip(weights) {
        let Some((data, local)) = *brick else { continue };
        for (ch, o) in out.iter_mut().enumerate().take(channels.min(3) as usize) {
            *o += w * data.get((first as usize + ch) * BRICK_VOXELS + local).map_or(0.0, |&x| x as f64);
        }
    }
    out
}

/// A sun's irradiance at a sample times what multiplies it there: `weights` (per trilinear corner,
/// its weight times ρ·a). Kept at the voxels' centres ([`DirectBeam::at_centres`]), the irradiance
/// is interpolated in optical depth (its logarithm, trilinearly over the corners the field
/// stores) and multiplies the interpolated ρ·a, the sum of `weights`: exact along the sun's line
/// in a uniform medium, where E falls by e^{−σ·ρ} a voxel and a linear interpolation overstates
/// it between the centres (`crate::solver::beam_trace`). A corner whose light underflowed to 0
/// makes it 0. Otherwise (voxel averages, 0 where ρ = 0) the product ρ·a·E is interpolated.
pub(super) fn beam_irradiance(
    beam: &super::DirectBeam,
    bricks: &CornerBricks,
    first: u32,
    channels: u32,
    corners: &[([u32; 3], f64); 8],
    weights: &[f64; 8],
) -> [f64; 3] {
    if !beam.at_centres {
        return sample_channels(bricks, first, channels, weights);
    }
    let (mut log, mut total, mut dark) = ([0.0f64; 3], 0.0, [false; 3]);
    for (&(_, w), brick) in corners.iter().zip(bricks) {
        if w == 0.0 {
            continue;
        }
        let Some((data, local)) = *brick else { continue };
        total += w;
        for (ch, l) in log.iter_mut().enumerate().take(channels.min(3) as usize) {
            let e = data.get((first as usize + ch) * BRICK_VOXELS + local).map_or(0.0, |&x| x as f64);
            if e > 0.0 {
                *l += w * e.ln();
            } else {
                dark[ch] = true;
            }
        }
    }
    let mass: f64 = weights.iter().sum();
    let mut out = [0.0; 3];
    if total > 0.0 && mass > 0.0 {
        for ch in 0..channels.min(3) as usize {
            if !dark[ch] {
                out[ch] = mass * (log[ch] / total).exp();
            }
        }
    }
    out
}

/// Each trilinear corner's brick of a field and the voxel's index in it (`None` outside the volume
/// or in an unstored brick, which read as 0, as `Field::value` has them): located once per sample
/// and field for everything that reads it there (every blend of the source; a light's true and
/// scaled irradiance).
pub(super) type CornerBricks<'a> = [Option<(&'a [f32], usize)>; 8];

pub(super) fn corner_bricks<'a>(field: &'a Field, corners: &[([u32; 3], f64); 8]) -> CornerBricks<'a> {
    let grid = field.grid();
    let mut bricks: CornerBricks = [None; 8];
    for (slot, &(v, _)) in bricks.iter_mut().zip(corners) {
        if grid.contains(v) {
            let (b, l) = grid.locate(v);
            *slot = field.brick(b).map(|d| (d, l));
        }
    }
    bricks
}

/// The source J per stored channel (entries past `inputs.channels` unused) at the trilinear
/// `corners` (their bricks `bricks`), blended over `blend`'s storage directions (indices clamped to
/// `last`). The sums are the ones `Field::value` per component gave (same terms, same order), and
/// the blend starts from its first part rather than from 0.0, so a single weight of 1 gives the
/// stored value bit for bit: an isotropic image is what it was before blending.
#[inline]
fn blended_source(
    inputs: &RenderInputs,
    blend: &Blend,
    last: u32,
    corners: &[([u32; 3], f64); 8],
    bricks: &CornerBricks,
) -> [f64; 3] {
    let channels = inputs.channels.min(3) as usize;
    let mut out = [0.0; 3];
    for (ch, slot) in out.iter_mut().enumerate().take(channels) {
        let mut parts = blend.entries().map(|(d, w)| {
            let c = (d.min(last) * inputs.channels) as usize + ch;
            w * bricks
                .iter()
                .zip(corners)
                .map(|(brick, &(_, cw))| {
                    cw * brick
                        .map_or(0.0, |(data, local)| data.get(c * BRICK_VOXELS + local).map_or(0.0, |&x| x as f64))
                })
                .sum::<f64>()
        });
        let first = parts.next().unwrap_or(0.0);
        *slot = parts.fold(first, |sum, part| sum + part);
    }
    out
}

/// The eight voxels around `p` (in voxel units) with their trilinear weights; voxel centres sit at
/// i + ½, and indices are clamped to the volume, so a value is held constant past the outer centres.
pub(crate) fn trilinear(p: DVec3, dims: [u32; 3]) -> [([u32; 3], f64); 8] {
    let mut lo = [0u32; 3];
    let mut hi = [0u32; 3];
    let mut w = [0.0f64; 3];
    for a in 0..3 {
        let u = p[a] - 0.5;
        let i = u.floor();
        let max = dims[a] as f64 - 1.0;
        lo[a] = i.clamp(0.0, max) as u32;
        hi[a] = (i + 1.0).clamp(0.0, max) as u32;
        w[a] = (u - i).clamp(0.0, 1.0);
    }
    let mut out = [([0u32; 3], 0.0); 8];
    for (k, slot) in out.iter_mut().enumerate() {
        let pick = |a: usize| (k >> a) & 1 == 1;
        let v = [0, 1, 2].map(|a| if pick(a) { hi[a] } else { lo[a] });
        let weight: f64 = (0..3).map(|a| if pick(a) { w[a] } else { 1.0 - w[a] }).product();
        *slot = (v, weight);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trilinear_weights_sum_to_one_and_hit_centres_exactly() {
        let dims = [4, 3, 5];
        for p in [DVec3::new(1.5, 1.5, 2.5), DVec3::new(0.1, 2.9, 4.99), DVec3::new(2.2, 0.7, 3.3)] {
            let c = trilinear(p, dims);
            assert!((c.iter().map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(c.iter().all(|(v, _)| (0..3).all(|a| v[a] < dims[a])));
        }
        let at_centre = trilinear(DVec3::new(1.5, 1.5, 2.5), dims);
        let main = at_centre.iter().find(|(v, _)| *v == [1, 1, 2]).unwrap();
        assert!(
            (at_centre.iter().filter(|(v, _)| *v == [1, 1, 2]).map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12,
            "{main:?}"
        );
    }

    #[test]
    fn walk_visits_neighbouring_voxels_and_sums_to_the_chord() {
        let (dims, h) = ([7u32, 5, 9], 0.3);
        let size = DVec3::new(7.0, 5.0, 9.0) * h;
        for (origin, dir) in [
            (DVec3::new(-1.0, 0.2, 0.4), DVec3::new(1.0, 0.3, 0.5).normalize()),
            (DVec3::new(1.5, 1.4, 2.0), DVec3::new(-0.2, -0.9, 0.1).normalize()),
            (DVec3::new(0.9, 0.6, -2.0), DVec3::Z),
        ] {
            let span = intersect_box(origin, dir, size).expect("hits");
            let mut total = 0.0;
            let mut last: Option<[u32; 3]> = None;
            walk_voxels(origin, dir, span, dims, h, |v, s| {
                if let Some(p) = last {
                    let moved: u32 = (0..3).map(|a| p[a].abs_diff(v[a])).sum();
                    assert_eq!(moved, 1, "{p:?} → {v:?}");
                }
                // The segment's midpoint lies in the voxel.
                let mid = origin + dir * (span.0 + total + 0.5 * s);
                for a in 0..3 {
                    assert!(mid[a] >= v[a] as f64 * h - 1e-12 && mid[a] <= (v[a] + 1) as f64 * h + 1e-12);
                }
                last = Some(v);
                total += s;
                true
            });
            assert!((total - (span.1 - span.0)).abs() < 1e-12, "{total} vs {span:?}");
        }
        assert!(intersect_box(DVec3::new(-1.0, 10.0, 0.0), DVec3::X, size).is_none());
        assert!(intersect_box(DVec3::new(5.0, 0.5, 0.5), DVec3::X, size).is_none(), "box behind the ray");
    }
}
