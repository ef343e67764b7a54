//! Temperature → blackbody radiance per channel (`volume.temperature_raw` /
//! `volume.temperature_grid`), as renderers colour fire.
//!
//! # What a voxel emits
//!
//! A voxel whose temperature grid holds `t` is at `T = medium.temperature_scale · t` kelvin. It
//! emits, in channel `c`,
//!
//! ```text
//! Le_c = medium.emission[c] · f_c(T),   f_c(T) = rgb_c(T) / Y(T_ref)   (T ≥ medium.temperature_cutoff)
//!                                        f_c(T) = 0                     (T <  medium.temperature_cutoff)
//! ```
//!
//! where `rgb(T)` is the colour of Planck's spectral radiance `B(λ, T)` (below) and `Y(T_ref)` the
//! Rec. 709 luminance of `rgb` at the reference temperature `T_ref = medium.temperature_reference`.
//! So a voxel at the reference temperature emits radiance of luminance exactly `medium.emission`
//! (grey `emission`: its colour is the blackbody's), and every other temperature keeps Planck's
//! law relative to it: hotter voxels are brighter (roughly `T⁴` overall, far faster in the
//! visible at fire temperatures) and whiter, colder ones dimmer and redder. This is how a VFX user
//! drives fire: Blender's Principled Volume takes a temperature attribute (times its `Temperature`
//! input: here `temperature_scale`) and a `Blackbody Intensity` (here `emission`); Houdini's pyro
//! shader a temperature field with a kelvin scale and an intensity. Fixing the brightness at a
//! reference temperature rather than in absolute W·m⁻²·sr⁻¹ keeps scene units free (lpm's
//! lights are in whatever units the scene uses) and makes `emission` mean "how bright a
//! `T_ref` voxel glows", the knob an artist turns.
//!
//! The cutoff (default [`DEFAULT_CUTOFF`] = 500 K) makes cold voxels (ambient smoke, a grid's
//! background 0) emit exactly nothing; physically they already emit ~10⁻¹⁴ of a 1500 K voxel in
//! the visible, so the default changes no image, but it keeps the emission field sparse and
//! exact zeros exact.
//!
//! # The colour of a temperature
//!
//! `rgb(T)` integrates Planck's law against the CIE 1931 2° colour-matching functions and maps
//! the resulting XYZ to linear Rec. 709 / sRGB primaries (D65 white), the working space of lpm's
//! images (what Blender's and Cycles' blackbody nodes do):
//!
//! ```text
//! XYZ(T) = ∫ (x̄, ȳ, z̄)(λ) · B(λ, T) dλ,   B(λ, T) = 2hc² / λ⁵ / (exp(hc / (λkT)) − 1)
//! rgb(T) = max(0, M · XYZ(T))             (M: XYZ → linear Rec. 709)
//! ```
//!
//! - The colour-matching functions are the multi-lobe Gaussian fit of Wyman, Sloan and Shirley
//!   ("Simple Analytic Approximations to the CIE XYZ Color Matching Functions", JCGT 2(2), 2013),
//!   whose error is below the spread between CIE data sets: a dozen constants instead of a
//!   471-row table. The chromaticities it gives follow the published Planckian locus to ~10⁻³
//!   (tested against Kim et al.'s cubic fit of it).
//! - The integral runs over 360–830 nm (the CIE range) at 5 nm steps (trapezoid rule): the
//!   integrand is smooth on that scale (the narrowest lobe has σ = 11.8 nm), so the sum agrees
//!   with a 0.25 nm Simpson integration to ~10⁻⁶ (tested).
//! - Three representative wavelengths (e.g. `B(610 nm)`, `B(550 nm)`, `B(465 nm)`) were the
//!   cheaper alternative, rejected: a channel responds to a broad band, and point samples give the
//!   wrong hue and saturation (a 6500 K body is not near white through them).
//! - Below about 1900 K the blackbody's chromaticity lies outside the Rec. 709 gamut and `M`
//!   gives a slightly negative blue (or, far down, green): those components are clamped to 0, as
//!   renderers do. Red is positive at every temperature, so `Y(T_ref) > 0`.
//!
//! `B` is evaluated in W·m⁻²·sr⁻¹·nm⁻¹ and the CMFs are dimensionless, so `rgb` is in
//! W·m⁻²·sr⁻¹ (a radiance): only ratios of it reach the solver. 95 exponentials per voxel are
//! cheap next to the solve (about a microsecond), and voxels below the cutoff cost nothing.

use super::Blackbody;
use std::sync::OnceLock;

/// Default `medium.temperature_reference` (K): a fire's glow; a voxel at this temperature emits
/// luminance `medium.emission`.
pub const DEFAULT_REFERENCE: f64 = 1500.0;
/// Default `medium.temperature_cutoff` (K): voxels colder than this emit nothing.
pub const DEFAULT_CUTOFF: f64 = 500.0;
/// Range accepted for `medium.temperature_reference` (K): low enough for embers, high enough for
/// hot stars; inside it `Y(T_ref)` is a normal f64 (≥ 1e−230).
pub const REFERENCE_RANGE: (f64, f64) = (100.0, 1.0e6);

/// Planck's constant (J·s), the speed of light (m/s) and Boltzmann's constant (J/K): exact SI values.
const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const K: f64 = 1.380_649e-23;
/// First wavelength, last wavelength and step of the integration (nm).
const LAMBDA_FIRST: f64 = 360.0;
const LAMBDA_LAST: f64 = 830.0;
const LAMBDA_STEP: f64 = 5.0;

/// XYZ → linear Rec. 709 (sRGB primaries, D65 white), rows r, g, b (IEC 61966-2-1).
pub const XYZ_TO_REC709: [[f64; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266_0, 1.876_010_8, 0.041_556_0],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];
/// Rec. 709 luminance of linear r, g, b (the Y row of the inverse of [`XYZ_TO_REC709`]).
pub const REC709_LUMINANCE: [f64; 3] = [0.212_671, 0.715_160, 0.072_169];

/// One piecewise Gaussian lobe of the colour-matching-function fit: `a·exp(−½((λ − μ)/σ)²)`, σ
/// on the left of μ and σ' on its right.
fn lobe(lambda: f64, a: f64, mu: f64, sigma_left: f64, sigma_right: f64) -> f64 {
    let s = if lambda < mu { sigma_left } else { sigma_right };
    let t = (lambda - mu) / s;
    a * (-0.5 * t * t).exp()
}

/// CIE 1931 2° colour-matching functions x̄, ȳ, z̄ at `lambda` nm (Wyman, Sloan & Shirley 2013,
/// multi-lobe fit).
pub fn cie_xyz_bar(lambda: f64) -> [f64; 3] {
    let x = lobe(lambda, 1.056, 599.8, 37.9, 31.0) + lobe(lambda, 0.362, 442.0, 16.0, 26.7)
        - lobe(lambda, 0.065, 501.1, 20.4, 26.2);
    let y = lobe(lambda, 0.821, 568.8, 46.9, 40.5) + lobe(lambda, 0.286, 530.9, 16.3, 31.1);
    let z = lobe(lambda, 1.217, 437.0, 11.8, 36.0) + lobe(lambda, 0.681, 459.0, 26.0, 13.8);
    [x, y, z]
}

/// Planck's spectral radiance B(λ, T) in W·m⁻²·sr⁻¹·nm⁻¹, λ in nm, T in kelvin.
pub fn planck(lambda_nm: f64, kelvin: f64) -> f64 {
    let l = lambda_nm * 1e-9;
    // exp_m1 keeps the Rayleigh–Jeans end (hc/λkT ≪ 1) accurate; an overflowing exp (very cold)
    // gives +∞ and so B = 0, as it should.
    2.0 * H * C * C / l.powi(5) / (H * C / (l * K * kelvin)).exp_m1() * 1e-9
}

/// Per integration wavelength: hc/(λk) (K), and the trapezoid weight times the colour-matching
/// functions times 2hc²/λ⁵, already mapped to r, g, b: `rgb(T) = Σ w / (exp(c/T) − 1)`.
struct Node {
    c: f64,
    w: [f64; 3],
}

fn nodes() -> &'static [Node] {
    static NODES: OnceLock<Vec<Node>> = OnceLock::new();
    NODES.get_or_init(|| {
        let n = ((LAMBDA_LAST - LAMBDA_FIRST) / LAMBDA_STEP).round() as usize;
        (0..=n)
            .map(|i| {
                let lambda = LAMBDA_FIRST + i as f64 * LAMBDA_STEP;
                let l = lambda * 1e-9;
                let end = if i == 0 || i == n { 0.5 } else { 1.0 };
                let scale = end * LAMBDA_STEP * 2.0 * H * C * C / l.powi(5) * 1e-9;
                let xyz = cie_xyz_bar(lambda);
                let w = XYZ_TO_REC709.map(|row| scale * (row[0] * xyz[0] + row[1] * xyz[1] + row[2] * xyz[2]));
                Node { c: H * C / (l * K), w }
            })
            .collect()
    })
}

/// The blackbody's colour at `kelvin` in linear Rec. 709, unclamped (`M·XYZ(T)`, W·m⁻²·sr⁻¹).
fn rgb_unclamped(kelvin: f64) -> [f64; 3] {
    let mut rgb = [0.0; 3];
    if !(kelvin > 0.0) {
        return rgb;
    }
    for node in nodes() {
        let b = 1.0 / (node.c / kelvin).exp_m1();
        if b == 0.0 {
            continue;
        }
        for (o, w) in rgb.iter_mut().zip(node.w) {
            *o += w * b;
        }
    }
    rgb
}

/// The blackbody's colour at `kelvin`: `max(0, M·XYZ(T))` in linear Rec. 709 (W·m⁻²·sr⁻¹);
/// 0 for T ≤ 0.
pub fn blackbody_rgb(kelvin: f64) -> [f64; 3] {
    rgb_unclamped(kelvin).map(|v| v.max(0.0))
}

/// Rec. 709 luminance of linear `rgb`.
pub fn luminance(rgb: [f64; 3]) -> f64 {
    rgb.iter().zip(REC709_LUMINANCE).map(|(c, w)| c * w).sum()
}

/// A scene's temperature → emission factor map, with its normalisation computed once.
#[derive(Clone, Copy, Debug)]
pub struct BlackbodyMap {
    scale: f64,
    cutoff: f64,
    /// 1 / Y(T_ref).
    inv_reference: f64,
}

impl BlackbodyMap {
    pub fn new(b: &Blackbody) -> BlackbodyMap {
        BlackbodyMap { scale: b.scale, cutoff: b.cutoff, inv_reference: 1.0 / luminance(blackbody_rgb(b.reference)) }
    }

    /// The emission factors `f_c(T)` of a voxel whose grid value is `t` (T = scale·t kelvin):
    /// what `medium.emission` is multiplied by, per channel. `t` must be finite and ≥ 0.
    pub fn factors(&self, t: f32) -> [f64; 3] {
        let kelvin = self.scale * t as f64;
        if !(kelvin >= self.cutoff) || kelvin <= 0.0 {
            return [0.0; 3];
        }
        blackbody_rgb(kelvin).map(|v| v * self.inv_reference)
    }

    /// The temperature in kelvin of grid value `t`.
    pub fn kelvin(&self, t: f32) -> f64 {
        self.scale * t as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(reference: f64) -> BlackbodyMap {
        BlackbodyMap::new(&Blackbody { scale: 1.0, reference, cutoff: DEFAULT_CUTOFF })
    }

    #[test]
    fn the_reference_temperature_has_unit_luminance() {
        for reference in [800.0, 1500.0, 6500.0] {
            let f = map(reference).factors(reference as f32);
            assert!((luminance(f) - 1.0).abs() < 1e-12, "{reference}: {f:?}");
        }
    }

    #[test]
    fn below_the_cutoff_nothing_is_emitted_and_hotter_is_brighter() {
        let m = map(1500.0);
        assert_eq!(m.factors(499.0), [0.0; 3]);
        assert_eq!(m.factors(0.0), [0.0; 3]);
        let mut last = 0.0;
        for t in [500.0, 800.0, 1200.0, 2000.0, 4000.0, 10000.0, 1e6] {
            let y = luminance(m.factors(t));
            assert!(y > last && y.is_finite(), "{t}: {y}");
            last = y;
        }
        // Fire is red: at 1200 K red dominates, blue is (clamped) nothing.
        let f = m.factors(1200.0);
        assert!(f[0] > 10.0 * f[1] && f[2] == 0.0, "{f:?}");
    }

    #[test]
    fn planck_peaks_where_wien_says() {
        // Wien's displacement law: λ_max·T = 2.897771955e6 nm·K.
        let t = 5000.0;
        let peak = (2000..8000).map(|i| i as f64 * 0.1).max_by(|a, b| planck(*a, t).total_cmp(&planck(*b, t)));
        assert!((peak.unwrap_or(0.0) - 2.897_771_955e6 / t).abs() < 0.2, "{peak:?}");
    }
}
