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
//! - The colour-matching functions are the CIE 1931 2° standard observer's table at 5 nm
//!   ([`CIE_1931_2DEG_5NM`], 360–830 nm: the CIE's own 5 nm values, which its 1 nm table
//!   interpolates). An analytic fit (Wyman, Sloan & Shirley 2013) was tried first and rejected:
//!   its red tail is off enough that at 1000 K, where that tail is all a flame emits, it gave three
//!   times the true green. With the table the chromaticities follow the published Planckian locus
//!   to ~10⁻⁴ (1000 K: x = 0.6528, y = 0.3445; tested against it and Kim et al.'s fit of it).
//! - The integral is the trapezoid rule over the table's 95 wavelengths. Against the same rule
//!   over the CIE's 1 nm table it differs by at most 1.1·10⁻⁶ in X and Y from 600 K to 6500 K
//!   (checked when this was written; Z, which matters only where it is large, by 4·10⁻⁴ at 600 K
//!   and ~10⁻⁶ above 1500 K). Simpson's rule or a linear interpolation of the 5 nm table are
//!   worse: the table is not a polynomial on that scale.
//! - Three representative wavelengths (e.g. `B(610 nm)`, `B(550 nm)`, `B(465 nm)`) were the
//!   cheaper alternative, rejected: a channel responds to a broad band, and point samples give the
//!   wrong hue where fire lives (at 1500 K, green 0.31 of red instead of 0.13: a yellow flame
//!   where it is orange).
//! - Below about 1900 K the blackbody's chromaticity lies outside the Rec. 709 gamut and `M`
//!   gives a slightly negative blue (and below about 950 K green): those components are clamped
//!   to 0, as renderers do. Red is positive at every temperature, so `Y(T_ref) > 0`.
//!
//! `B` is evaluated in W·m⁻²·sr⁻¹·nm⁻¹ and the CMFs are dimensionless, so `rgb` is in
//! W·m⁻²·sr⁻¹ (a radiance): only ratios of it reach the solver. 95 exponentials per voxel are
//! cheap next to the solve (about a microsecond a voxel), and voxels below the cutoff cost nothing.

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
/// First wavelength and step (nm) of [`CIE_1931_2DEG_5NM`], the integration's wavelengths.
pub const LAMBDA_FIRST: f64 = 360.0;
pub const LAMBDA_STEP: f64 = 5.0;

/// The CIE 1931 2° standard observer's colour-matching functions x̄, ȳ, z̄ from 360 to 830 nm
/// every 5 nm (CIE 015; the values as tabulated by the Colour & Vision Research Laboratory, CVRL).
#[rustfmt::skip]
pub const CIE_1931_2DEG_5NM: [[f64; 3]; 95] = [
    [0.000129900000, 0.000003917000, 0.000606100000], // 360 nm
    [0.000232100000, 0.000006965000, 0.001086000000], // 365 nm
    [0.000414900000, 0.000012390000, 0.001946000000], // 370 nm
    [0.000741600000, 0.000022020000, 0.003486000000], // 375 nm
    [0.001368000000, 0.000039000000, 0.006450001000], // 380 nm
    [0.002236000000, 0.000064000000, 0.010549990000], // 385 nm
    [0.004243000000, 0.000120000000, 0.020050010000], // 390 nm
    [0.007650000000, 0.000217000000, 0.036210000000], // 395 nm
    [0.014310000000, 0.000396000000, 0.067850010000], // 400 nm
    [0.023190000000, 0.000640000000, 0.110200000000], // 405 nm
    [0.043510000000, 0.001210000000, 0.207400000000], // 410 nm
    [0.077630000000, 0.002180000000, 0.371300000000], // 415 nm
    [0.134380000000, 0.004000000000, 0.645600000000], // 420 nm
    [0.214770000000, 0.007300000000, 1.039050100000], // 425 nm
    [0.283900000000, 0.011600000000, 1.385600000000], // 430 nm
    [0.328500000000, 0.016840000000, 1.622960000000], // 435 nm
    [0.348280000000, 0.023000000000, 1.747060000000], // 440 nm
    [0.348060000000, 0.029800000000, 1.782600000000], // 445 nm
    [0.336200000000, 0.038000000000, 1.772110000000], // 450 nm
    [0.318700000000, 0.048000000000, 1.744100000000], // 455 nm
    [0.290800000000, 0.060000000000, 1.669200000000], // 460 nm
    [0.251100000000, 0.073900000000, 1.528100000000], // 465 nm
    [0.195360000000, 0.090980000000, 1.287640000000], // 470 nm
    [0.142100000000, 0.112600000000, 1.041900000000], // 475 nm
    [0.095640000000, 0.139020000000, 0.812950100000], // 480 nm
    [0.057950010000, 0.169300000000, 0.616200000000], // 485 nm
    [0.032010000000, 0.208020000000, 0.465180000000], // 490 nm
    [0.014700000000, 0.258600000000, 0.353300000000], // 495 nm
    [0.004900000000, 0.323000000000, 0.272000000000], // 500 nm
    [0.002400000000, 0.407300000000, 0.212300000000], // 505 nm
    [0.009300000000, 0.503000000000, 0.158200000000], // 510 nm
    [0.029100000000, 0.608200000000, 0.111700000000], // 515 nm
    [0.063270000000, 0.710000000000, 0.078249990000], // 520 nm
    [0.109600000000, 0.793200000000, 0.057250010000], // 525 nm
    [0.165500000000, 0.862000000000, 0.042160000000], // 530 nm
    [0.225749900000, 0.914850100000, 0.029840000000], // 535 nm
    [0.290400000000, 0.954000000000, 0.020300000000], // 540 nm
    [0.359700000000, 0.980300000000, 0.013400000000], // 545 nm
    [0.433449900000, 0.994950100000, 0.008749999000], // 550 nm
    [0.512050100000, 1.000000000000, 0.005749999000], // 555 nm
    [0.594500000000, 0.995000000000, 0.003900000000], // 560 nm
    [0.678400000000, 0.978600000000, 0.002749999000], // 565 nm
    [0.762100000000, 0.952000000000, 0.002100000000], // 570 nm
    [0.842500000000, 0.915400000000, 0.001800000000], // 575 nm
    [0.916300000000, 0.870000000000, 0.001650001000], // 580 nm
    [0.978600000000, 0.816300000000, 0.001400000000], // 585 nm
    [1.026300000000, 0.757000000000, 0.001100000000], // 590 nm
    [1.056700000000, 0.694900000000, 0.001000000000], // 595 nm
    [1.062200000000, 0.631000000000, 0.000800000000], // 600 nm
    [1.045600000000, 0.566800000000, 0.000600000000], // 605 nm
    [1.002600000000, 0.503000000000, 0.000340000000], // 610 nm
    [0.938400000000, 0.441200000000, 0.000240000000], // 615 nm
    [0.854449900000, 0.381000000000, 0.000190000000], // 620 nm
    [0.751400000000, 0.321000000000, 0.000100000000], // 625 nm
    [0.642400000000, 0.265000000000, 0.000049999990], // 630 nm
    [0.541900000000, 0.217000000000, 0.000030000000], // 635 nm
    [0.447900000000, 0.175000000000, 0.000020000000], // 640 nm
    [0.360800000000, 0.138200000000, 0.000010000000], // 645 nm
    [0.283500000000, 0.107000000000, 0.000000000000], // 650 nm
    [0.218700000000, 0.081600000000, 0.000000000000], // 655 nm
    [0.164900000000, 0.061000000000, 0.000000000000], // 660 nm
    [0.121200000000, 0.044580000000, 0.000000000000], // 665 nm
    [0.087400000000, 0.032000000000, 0.000000000000], // 670 nm
    [0.063600000000, 0.023200000000, 0.000000000000], // 675 nm
    [0.046770000000, 0.017000000000, 0.000000000000], // 680 nm
    [0.032900000000, 0.011920000000, 0.000000000000], // 685 nm
    [0.022700000000, 0.008210000000, 0.000000000000], // 690 nm
    [0.015840000000, 0.005723000000, 0.000000000000], // 695 nm
    [0.011359160000, 0.004102000000, 0.000000000000], // 700 nm
    [0.008110916000, 0.002929000000, 0.000000000000], // 705 nm
    [0.005790346000, 0.002091000000, 0.000000000000], // 710 nm
    [0.004109457000, 0.001484000000, 0.000000000000], // 715 nm
    [0.002899327000, 0.001047000000, 0.000000000000], // 720 nm
    [0.002049190000, 0.000740000000, 0.000000000000], // 725 nm
    [0.001439971000, 0.000520000000, 0.000000000000], // 730 nm
    [0.000999949300, 0.000361100000, 0.000000000000], // 735 nm
    [0.000690078600, 0.000249200000, 0.000000000000], // 740 nm
    [0.000476021300, 0.000171900000, 0.000000000000], // 745 nm
    [0.000332301100, 0.000120000000, 0.000000000000], // 750 nm
    [0.000234826100, 0.000084800000, 0.000000000000], // 755 nm
    [0.000166150500, 0.000060000000, 0.000000000000], // 760 nm
    [0.000117413000, 0.000042400000, 0.000000000000], // 765 nm
    [0.000083075270, 0.000030000000, 0.000000000000], // 770 nm
    [0.000058706520, 0.000021200000, 0.000000000000], // 775 nm
    [0.000041509940, 0.000014990000, 0.000000000000], // 780 nm
    [0.000029353260, 0.000010600000, 0.000000000000], // 785 nm
    [0.000020673830, 0.000007465700, 0.000000000000], // 790 nm
    [0.000014559770, 0.000005257800, 0.000000000000], // 795 nm
    [0.000010253980, 0.000003702900, 0.000000000000], // 800 nm
    [0.000007221456, 0.000002607800, 0.000000000000], // 805 nm
    [0.000005085868, 0.000001836600, 0.000000000000], // 810 nm
    [0.000003581652, 0.000001293400, 0.000000000000], // 815 nm
    [0.000002522525, 0.000000910930, 0.000000000000], // 820 nm
    [0.000001776509, 0.000000641530, 0.000000000000], // 825 nm
    [0.000001251141, 0.000000451810, 0.000000000000], // 830 nm
];

/// XYZ → linear Rec. 709 (sRGB primaries, D65 white), rows r, g, b (IEC 61966-2-1).
pub const XYZ_TO_REC709: [[f64; 3]; 3] = [
    [3.240_454_2, -1.537_138_5, -0.498_531_4],
    [-0.969_266_0, 1.876_010_8, 0.041_556_0],
    [0.055_643_4, -0.204_025_9, 1.057_225_2],
];
/// Rec. 709 luminance of linear r, g, b (the Y row of the inverse of [`XYZ_TO_REC709`]).
pub const REC709_LUMINANCE: [f64; 3] = [0.212_671, 0.715_160, 0.072_169];

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
        let n = CIE_1931_2DEG_5NM.len() - 1;
        CIE_1931_2DEG_5NM
            .iter()
            .enumerate()
            .map(|(i, xyz)| {
                let lambda = LAMBDA_FIRST + i as f64 * LAMBDA_STEP;
                let l = lambda * 1e-9;
                let end = if i == 0 || i == n { 0.5 } else { 1.0 };
                let scale = end * LAMBDA_STEP * 2.0 * H * C * C / l.powi(5) * 1e-9;
                let w = XYZ_TO_REC709.map(|row| scale * (row[0] * xyz[0] + row[1] * xyz[1] + row[2] * xyz[2]));
                Node { c: H * C / (l * K), w }
            })
            .collect()
    })
}

/// The blackbody's CIE 1931 XYZ at `kelvin` (W·m⁻²·sr⁻¹; the same sum as [`blackbody_rgb`]
/// before the matrix): for chromaticities.
pub fn blackbody_xyz(kelvin: f64) -> [f64; 3] {
    let mut xyz = [0.0; 3];
    if !(kelvin > 0.0) {
        return xyz;
    }
    let n = CIE_1931_2DEG_5NM.len() - 1;
    for (i, bar) in CIE_1931_2DEG_5NM.iter().enumerate() {
        let lambda = LAMBDA_FIRST + i as f64 * LAMBDA_STEP;
        let end = if i == 0 || i == n { 0.5 } else { 1.0 };
        let b = end * LAMBDA_STEP * planck(lambda, kelvin);
        for (o, w) in xyz.iter_mut().zip(bar) {
            *o += w * b;
        }
    }
    xyz
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
