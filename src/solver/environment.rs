//! What the plan makes of an environment map: the boundary radiance of every propagation
//! direction, and the map's sun-like peak as a beam.
//!
//! # Boundary radiance: the map averaged over each direction's cell
//!
//! A ray travelling along ω carries the radiance that arrives from −ω. Sampling the map at −ω would
//! alias (a bright pixel between two direction centres would be missed, or taken for a whole cell),
//! so each propagation direction gets the map's mean over its whole cube-face cell instead. The map
//! is constant over each pixel's cell of solid angle; every pixel is cut into s×s sub-pixels (s
//! chosen so a sub-pixel is under a quarter of the narrowest direction cell, 1 for maps finer than
//! the direction set), each sub-pixel goes whole to the direction cell its centre falls in, and a
//! cell's radiance is Σ L·Ω_sub / Σ Ω_sub over the sub-pixels it received: every pixel counts, a
//! constant map gives exactly its value, and the sum over cells of radiance × cell solid angle is
//! the map's power up to the sub-pixel quantisation of the cells' edges.
//!
//! # The sun-like peak
//!
//! A sun in an HDR map is a few pixels thousands of times brighter than the sky. Averaged into one
//! direction cell it would light the volume from that cell's centre, with ray effects (streaks) in
//! the direct light. The rule, on the luminance Y = (r + g + b)/3 of the scaled map:
//!
//! 1. the peak region is the pixels 8-connected to the brightest pixel (columns wrap around) whose Y
//!    is at least [`PEAK_FRACTION`] of the brightest;
//! 2. it is extracted when it is small — solid angle at most [`MAX_PEAK_SOLID_ANGLE`] (a cone of
//!    about 3.2°; the sun's disk is 6.8e-5 sr) — and stands out — its mean Y at least
//!    [`MIN_PEAK_CONTRAST`] times the mean Y of the rest of the map;
//! 3. its pixels are then set to the mean of the pixels bordering it (the sky around the sun), and
//!    what they held above that becomes a sun light: direction the Y-weighted mean of the region's
//!    pixel directions, irradiance per channel the flux of the excess through a plane
//!    perpendicular to it (Σ (L − L_border)·Ω·d · direction), so the light removed from the map is
//!    the light the beam brings (exactly for a grey map).
//!
//! The beam is then swept along its exact direction like any sun: no ray effects.

use crate::quadrature::PropagationSet;
use crate::scene::EnvironmentLight;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// A pixel belongs to the peak region when its luminance is at least this fraction of the
/// brightest pixel's.
pub const PEAK_FRACTION: f64 = 0.01;
/// Largest solid angle (sr) of a peak region extracted as a sun.
pub const MAX_PEAK_SOLID_ANGLE: f64 = 0.01;
/// Smallest ratio of the peak region's mean luminance to the rest of the map's for extraction.
pub const MIN_PEAK_CONTRAST: f64 = 100.0;

/// A sun-like peak taken out of a map.
#[derive(Clone, Debug, PartialEq)]
pub struct ExtractedSun {
    /// Unit direction toward the peak (world frame).
    pub direction: DVec3,
    /// Irradiance on a plane perpendicular to `direction`, per channel.
    pub irradiance: [f64; 3],
    /// Pixels and solid angle (sr) of the region.
    pub pixels: usize,
    pub solid_angle: f64,
    /// The region's share of the map's power (luminance), in [0, 1].
    pub share: f64,
}

/// The map as the solver sees it: the boundary radiance per propagation direction and the
/// extracted sun, if any.
#[derive(Clone, Debug)]
pub struct EnvironmentBoundary {
    /// Per propagation direction (the set's order), the mean radiance over its cell of the light
    /// travelling in it, per channel (sun removed when one was extracted).
    pub radiance: Vec<[f64; 3]>,
    pub sun: Option<ExtractedSun>,
}

/// The scaled map (intensity × pixel), with the extracted peak's pixels replaced by their border's
/// mean.
struct Scaled {
    width: usize,
    height: usize,
    rgb: Vec<[f64; 3]>,
}

impl Scaled {
    fn new(env: &EnvironmentLight) -> Scaled {
        let m = &env.map;
        let rgb = m.rgb.iter().map(|p| [0, 1, 2].map(|c| env.intensity[c] * p[c] as f64)).collect();
        Scaled { width: m.width, height: m.height, rgb }
    }

    fn luminance(&self, i: usize) -> f64 {
        let p = self.rgb[i];
        (p[0] + p[1] + p[2]) / 3.0
    }

    /// The 8 neighbours of pixel i (columns wrap, rows do not).
    fn neighbours(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let (w, h) = (self.width as i64, self.height as i64);
        let (x, y) = ((i as i64) % w, (i as i64) / w);
        (-1..=1i64).flat_map(move |dy| (-1..=1i64).map(move |dx| (dx, dy))).filter_map(move |(dx, dy)| {
            let ny = y + dy;
            ((dx, dy) != (0, 0) && (0..h).contains(&ny)).then(|| (ny * w + (x + dx).rem_euclid(w)) as usize)
        })
    }
}

/// Boundary radiance and extracted sun for `env` over the propagation directions.
pub fn environment_boundary(env: &EnvironmentLight, propagation: &PropagationSet) -> EnvironmentBoundary {
    let mut map = Scaled::new(env);
    let sun = extract_sun(env, &mut map);
    let sums = cell_sums(env, &map, propagation);
    EnvironmentBoundary { radiance: EnvironmentBoundary::from_sums(env, propagation, &sums), sun }
}

/// Applies the peak rule (module docs) to `map`; on extraction, fills the region in `map`.
fn extract_sun(env: &EnvironmentLight, map: &mut Scaled) -> Option<ExtractedSun> {
    let (w, h) = (map.width, map.height);
    let omega = |i: usize| env.map.pixel_solid_angle(i / w);
    let centre = |i: usize| env.direction_at((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
    // The brightest pixel (the first in row order among equals, so the rule is deterministic).
    let (peak, peak_y) =
        (0..w * h).map(|i| (i, map.luminance(i))).fold(
            (0, f64::NEG_INFINITY),
            |best, c| {
                if c.1 > best.1 {
                    c
                } else {
                    best
                }
            },
        );
    if !(peak_y > 0.0) {
        return None;
    }
    // Flood fill from the peak, giving up as soon as the region is too large to be a sun.
    let threshold = PEAK_FRACTION * peak_y;
    let mut inside = vec![false; w * h];
    let mut region = vec![peak];
    inside[peak] = true;
    let mut solid_angle = omega(peak);
    let mut next = 0;
    while next < region.len() {
        let i = region[next];
        next += 1;
        for n in map.neighbours(i).collect::<Vec<_>>() {
            if !inside[n] && map.luminance(n) >= threshold {
                inside[n] = true;
                region.push(n);
                solid_angle += omega(n);
                if solid_angle > MAX_PEAK_SOLID_ANGLE {
                    return None;
                }
            }
        }
    }
    region.sort_unstable();
    let (mut region_power, mut total_power) = (0.0, 0.0);
    for i in 0..w * h {
        let p = map.luminance(i) * omega(i);
        total_power += p;
        if inside[i] {
            region_power += p;
        }
    }
    let rest_mean = (total_power - region_power) / (4.0 * PI - solid_angle).max(f64::MIN_POSITIVE);
    let region_mean = region_power / solid_angle;
    if region_mean < MIN_PEAK_CONTRAST * rest_mean {
        return None;
    }
    // The sky around the peak: the solid-angle-weighted mean of the pixels bordering it.
    let mut border = vec![false; w * h];
    let (mut fill, mut fill_weight) = ([0.0; 3], 0.0);
    for &i in &region {
        for n in map.neighbours(i).collect::<Vec<_>>() {
            if !inside[n] && !border[n] {
                border[n] = true;
                (0..3).for_each(|c| fill[c] += map.rgb[n][c] * omega(n));
                fill_weight += omega(n);
            }
        }
    }
    if fill_weight > 0.0 {
        fill.iter_mut().for_each(|f| *f /= fill_weight);
    }
    let fill_y = (fill[0] + fill[1] + fill[2]) / 3.0;
    let (mut mean_dir, mut flux) = (DVec3::ZERO, [DVec3::ZERO; 3]);
    for &i in &region {
        let (d, o) = (centre(i), omega(i));
        mean_dir += d * ((map.luminance(i) - fill_y).max(0.0) * o);
        for c in 0..3 {
            flux[c] += d * ((map.rgb[i][c] - fill[c]) * o);
        }
        map.rgb[i] = fill;
    }
    let direction = mean_dir.try_normalize()?;
    let irradiance = [0, 1, 2].map(|c| flux[c].dot(direction).max(0.0));
    Some(ExtractedSun {
        direction,
        irradiance,
        pixels: region.len(),
        solid_angle,
        share: if total_power > 0.0 { region_power / total_power } else { 0.0 },
    })
}

/// Sub-pixels per pixel edge: a sub-pixel spans under a quarter of the narrowest direction cell.
fn subdivision(height: usize, k: u32) -> usize {
    // The narrowest cube-face cell (at a face's corner) spans about 2/(3k) radians; a pixel π/height.
    let s = (PI / height as f64 / (1.0 / (6.0 * k as f64))).ceil();
    (s as usize).clamp(1, 256)
}

/// Rows of the map per parallel block (each block's sums are added in block order: the result does
/// not depend on the thread count).
const BLOCK_ROWS: usize = 16;

/// Per propagation direction, Σ L·Ω_sub (r, g, b) and Σ Ω_sub over the sub-pixels whose light
/// travels in its cell (module docs).
fn cell_sums(env: &EnvironmentLight, map: &Scaled, propagation: &PropagationSet) -> Vec<[f64; 4]> {
    let (w, h) = (map.width, map.height);
    let n = propagation.len();
    let s = subdivision(h, propagation.k);
    let (sw, sh) = (w * s, h * s);
    // Sub-pixel columns: cos φ and sin φ of their centres (map frame; φ = π − 2π·column/width).
    let columns: Vec<(f64, f64)> = (0..sw)
        .map(|j| {
            let phi = PI - 2.0 * PI * (j as f64 + 0.5) / sw as f64;
            (phi.cos(), phi.sin())
        })
        .collect();
    let dphi = 2.0 * PI / sw as f64;
    let blocks: Vec<Vec<[f64; 4]>> = (0..h.div_ceil(BLOCK_ROWS))
        .into_par_iter()
        .map(|b| {
            let mut acc = vec![[0.0; 4]; n];
            for y in b * BLOCK_ROWS..((b + 1) * BLOCK_ROWS).min(h) {
                for sy in 0..s {
                    let row = y * s + sy;
                    let (t0, t1) = (PI * row as f64 / sh as f64, PI * (row + 1) as f64 / sh as f64);
                    let sub_omega = dphi * (t0.cos() - t1.cos());
                    let theta = PI * (row as f64 + 0.5) / sh as f64;
                    let (st, ct) = theta.sin_cos();
                    for (j, &(cp, sp)) in columns.iter().enumerate() {
                        let toward = env.from_map(DVec3::new(st * cp, st * sp, ct));
                        let cell = propagation.containing(-toward);
                        let l = map.rgb[y * w + j / s];
                        let a = &mut acc[cell];
                        for c in 0..3 {
                            a[c] += l[c] * sub_omega;
                        }
                        a[3] += sub_omega;
                    }
                }
            }
            acc
        })
        .collect();
    let mut sums = vec![[0.0; 4]; n];
    for block in blocks {
        for (t, a) in sums.iter_mut().zip(block) {
            for c in 0..4 {
                t[c] += a[c];
            }
        }
    }
    sums
}

impl EnvironmentBoundary {
    /// Radiance per direction from the cell sums: Σ L·Ω / Σ Ω, the pixel a cell's centre sees
    /// where (impossibly, by the choice of the subdivision) no sub-pixel fell in it.
    fn from_sums(env: &EnvironmentLight, propagation: &PropagationSet, sums: &[[f64; 4]]) -> Vec<[f64; 3]> {
        sums.iter()
            .zip(&propagation.directions)
            .map(|(a, d)| if a[3] > 0.0 { [a[0] / a[3], a[1] / a[3], a[2] / a[3]] } else { env.radiance(-d.omega) })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{EnvironmentMap, MapUp};
    use std::sync::Arc;

    fn light(w: usize, f: impl Fn(usize, usize) -> f32) -> EnvironmentLight {
        let h = w / 2;
        let rgb = (0..w * h).map(|i| [f(i % w, i / w); 3]).collect();
        let map = EnvironmentMap { path: "m.exr".into(), width: w, height: h, rgb };
        EnvironmentLight { map: Arc::new(map), intensity: [1.0; 3], up: MapUp::Z, rotation_degrees: 0.0 }
    }

    /// Σ over cells of radiance × cell solid angle, and the map's Σ L·Ω.
    fn powers(env: &EnvironmentLight, b: &EnvironmentBoundary, prop: &PropagationSet) -> (f64, f64) {
        let cells: f64 = b.radiance.iter().zip(&prop.directions).map(|(r, d)| r[0] * d.solid_angle).sum();
        let m = &env.map;
        let map: f64 = (0..m.width * m.height).map(|i| m.rgb[i][0] as f64 * m.pixel_solid_angle(i / m.width)).sum();
        (cells, map)
    }

    #[test]
    fn one_bright_pixel_lands_in_the_cell_its_light_travels_in_with_its_power() {
        // A pixel far smaller than a cell, between direction centres: sampling the map at the
        // centres would miss it; the cell average keeps its power.
        for k in [2, 5] {
            let prop = PropagationSet::new(k);
            let env = light(128, |x, y| if (x, y) == (37, 21) { 1.0 } else { 0.0 });
            // (Not through `environment_boundary`: a lone pixel on black is a perfect sun.)
            let sums = cell_sums(&env, &Scaled::new(&env), &prop);
            let b = EnvironmentBoundary { radiance: EnvironmentBoundary::from_sums(&env, &prop, &sums), sun: None };
            let lit: Vec<usize> = (0..prop.len()).filter(|&i| b.radiance[i][0] > 0.0).collect();
            let travel = -env.direction_at(37.5, 21.5);
            assert!(lit.contains(&prop.containing(travel)), "k={k}: {lit:?}");
            let (cells, pixels) = powers(&env, &b, &prop);
            // (The pixel's light is averaged over the cell's received sub-pixels, whose solid
            // angle approximates the cell's: the power is kept to the quantisation of its edges.)
            assert!((cells / pixels - 1.0).abs() < 0.05, "k={k}: cells {cells}, map {pixels}");
        }
    }

    #[test]
    fn a_smooth_map_keeps_its_power_and_a_sun_is_taken_out_whole() {
        let prop = PropagationSet::new(4);
        let smooth = light(64, |x, y| 1.0 + (x as f32 * 0.1).sin().abs() + y as f32 * 0.05);
        let b = environment_boundary(&smooth, &prop);
        assert!(b.sun.is_none(), "no sun in a smooth map");
        let (cells, pixels) = powers(&smooth, &b, &prop);
        assert!((cells / pixels - 1.0).abs() < 2e-3, "cells {cells}, map {pixels}");

        // A 2×2 sun of 1e4 on a sky of 1: the excess over 1 becomes the beam, the sky stays.
        let sunny = light(512, |x, y| if (200..202).contains(&x) && (100..102).contains(&y) { 1e4 } else { 1.0 });
        let b = environment_boundary(&sunny, &prop);
        let sun = b.sun.expect("a sun");
        let excess: f64 = (100..102).map(|y| 2.0 * (1e4 - 1.0) * sunny.map.pixel_solid_angle(y)).sum();
        assert_eq!(sun.pixels, 4);
        // The irradiance is the excess's flux through a plane facing the mean direction: its
        // pixels' cosines to it (within 0.5°) make it a few 1e-5 less than Σ (L − 1)·Ω.
        assert!((sun.irradiance[0] / excess - 1.0).abs() < 1e-4, "{:?} against {excess}", sun.irradiance);
        assert!(sun.direction.angle_between(sunny.direction_at(201.0, 101.0)) < 1e-3);
        assert!(b.radiance.iter().all(|r| (r[0] - 1.0).abs() < 1e-12));
        // Too dim to stand out (20 times the sky): left in the map.
        let dim = light(512, |x, y| if (200..202).contains(&x) && (100..102).contains(&y) { 20.0 } else { 1.0 });
        assert!(environment_boundary(&dim, &prop).sun.is_none());
    }
}
