//! The PNG preview's display transform: linear radiance × exposure → a view transform (tone
//! curve) → sRGB-encoded values in [0, 1]. The EXR never passes through here.
//!
//! - `standard`: Reinhard's `x / (1 + x)` per channel, then the sRGB transfer function (lpm's
//!   mapping before the choice existed; at exposure 0 it gives the same bytes).
//! - `filmic`: per channel, log2 of the value over a range of 16.5 stops, 10 below mid grey (0.18)
//!   and 6.5 above it ([`AGX_MIN_EV`], [`AGX_MAX_EV`]), through AgX's S-shaped contrast curve (a
//!   polynomial fit, [`agx_contrast`]). Highlights roll off towards white up to radiance ≈ 16
//!   instead of clipping at 1; shadows keep detail 10 stops down.
//! - `agx`: the same curve between AgX's inset and outset matrices (Troy Sobotka's AgX, as in
//!   Blender 4 and three.js): bright, saturated light goes to white through desaturation rather
//!   than skewing in hue channel by channel.
//!
//! The curve's output is a display value for a 2.2 power display, which is converted to the
//! sRGB encoding the PNG declares. Auto exposure ([`auto_exposure_ev`]) meters the medium.

use super::image::{tone_map, Image};
use crate::scene::{Display, Exposure, View};

/// log2 of the value where the log encoding starts (black): 10 stops below mid grey.
pub const AGX_MIN_EV: f64 = -12.473_931_188_332_41;
/// log2 of the value where it ends (white): 6.5 stops above mid grey, radiance ≈ 16.3.
pub const AGX_MAX_EV: f64 = 4.026_068_811_667_588;
/// Mid grey: the linear value the log encoding is centred on, and auto exposure's target.
pub const MID_GREY: f64 = 0.18;

/// AgX's inset: linear sRGB → the space the curve is applied in (rows; each sums to 1, so grey stays grey).
const INSET: [[f64; 3]; 3] = [
    [0.842_479_062_253_094, 0.078_433_599_999_999_2, 0.079_223_745_147_764_3],
    [0.042_328_242_261_012_3, 0.878_468_636_469_772, 0.079_166_127_460_543_4],
    [0.042_375_654_905_705_1, 0.078_433_6, 0.879_142_973_793_104],
];
/// AgX's outset, the inset's inverse (rows).
const OUTSET: [[f64; 3]; 3] = [
    [1.196_879_005_120_17, -0.098_020_881_140_136_8, -0.099_029_744_079_720_5],
    [-0.052_896_851_757_456_2, 1.151_903_129_904_17, -0.098_961_176_844_843_3],
    [-0.052_971_635_514_443_8, -0.098_043_450_117_124_1, 1.151_073_672_641_16],
];

fn mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

/// AgX's default contrast curve on the log-encoded value `x` in [0, 1] (the 6th-order polynomial
/// fit of Blender's AgX "base contrast"): increasing on [0, 1], about 0 at 0 and 1 at 1.
pub fn agx_contrast(x: f64) -> f64 {
    let x2 = x * x;
    let x4 = x2 * x2;
    15.5 * x4 * x2 - 40.14 * x4 * x + 31.96 * x4 - 6.868 * x2 * x + 0.4298 * x2 + 0.1191 * x - 0.00232
}

/// The log encoding of a linear value, in [0, 1]; non-positive and NaN values are black.
fn log_encode(v: f64) -> f64 {
    let ev = if v > 0.0 { v.log2() } else { AGX_MIN_EV };
    let ev = if ev.is_nan() { AGX_MIN_EV } else { ev.clamp(AGX_MIN_EV, AGX_MAX_EV) };
    (ev - AGX_MIN_EV) / (AGX_MAX_EV - AGX_MIN_EV)
}

/// A 2.2-power display value → the sRGB encoding.
fn gamma22_to_srgb(v: f64) -> f64 {
    srgb_encode(v.clamp(0.0, 1.0).powf(2.2))
}

/// The sRGB transfer function, for `v` in [0, 1].
pub(super) fn srgb_encode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The sRGB-encoded display value in [0, 1] of linear radiance `rgb` (already multiplied by the
/// exposure scale) through `view`. Negative and NaN components count as 0; +∞ is white.
pub fn display_rgb(rgb: [f64; 3], view: View) -> [f64; 3] {
    let rgb = rgb.map(|v| if v.is_nan() { 0.0 } else { v.max(0.0) });
    match view {
        View::Standard => rgb.map(|v| srgb_encode(reinhard(v))),
        View::Filmic => rgb.map(|v| gamma22_to_srgb(agx_contrast(log_encode(v)))),
        View::Agx => {
            let inset = mul(&INSET, rgb).map(|v| agx_contrast(log_encode(v)));
            mul(&OUTSET, inset).map(gamma22_to_srgb)
        }
    }
}

fn reinhard(x: f64) -> f64 {
    if x.is_infinite() {
        1.0
    } else {
        x / (1.0 + x)
    }
}

/// The 8-bit value of a display value in [0, 1].
pub(super) fn to_u8(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// The 8-bit sRGB values of one pixel's linear radiance `rgb` under `view`, scaled by `scale`
/// (2^EV). For [`View::Standard`] exactly what lpm wrote before the view could be chosen.
pub fn pixel_u8(rgb: [f32; 3], scale: f64, view: View) -> [u8; 3] {
    match view {
        // Through the same arithmetic as ever (f32 → f64, × scale, Reinhard, sRGB): the bytes stay the same.
        View::Standard => rgb.map(|v| to_u8(srgb_encode(tone_map(v, scale)))),
        _ => display_rgb(rgb.map(|v| f64::from(v) * scale), view).map(to_u8),
    }
}

/// Rec. 709 luminance.
fn luminance(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// The exposure (EV) that puts the image's key, the log-average luminance of the medium, at mid
/// grey. Each pixel is weighted by its alpha (how much of the medium it sees; its colour taken
/// straight, not premultiplied), so a cloud in a wide sky is exposed for the cloud; an image
/// without alpha, or one where the medium covers less than a pixel in all, weighs every pixel
/// alike. A black image gets 0. The result is clamped to ±[`crate::scene::MAX_EXPOSURE_EV`].
pub fn auto_exposure_ev(img: &Image) -> f64 {
    const FLOOR: f64 = 1e-9;
    let pixels = img.width as usize * img.height as usize;
    let straight = |p: usize, a: f64| {
        let rgb = [0, 1, 2].map(|c| f64::from(img.rgb[3 * p + c]));
        let y = luminance(rgb);
        if a > 0.0 && a < 1.0 && img.alpha.is_some() {
            y / a
        } else {
            y
        }
    };
    let weigh = |use_alpha: bool| {
        let (mut sum, mut weight, mut lit) = (0.0, 0.0, false);
        for p in 0..pixels {
            let a = img.alpha.as_ref().map_or(1.0, |a| f64::from(a[p]).clamp(0.0, 1.0));
            let w = if use_alpha { a } else { 1.0 };
            let y = straight(p, a);
            if w > 0.0 && y.is_finite() {
                sum += w * y.max(FLOOR).ln();
                weight += w;
                lit |= y > FLOOR;
            }
        }
        (sum, weight, lit)
    };
    let (mut sum, mut weight, mut lit) = weigh(img.alpha.is_some());
    if weight < 1.0 {
        (sum, weight, lit) = weigh(false);
    }
    if weight <= 0.0 || !lit {
        return 0.0;
    }
    let key = (sum / weight).exp();
    let max = crate::scene::MAX_EXPOSURE_EV;
    (MID_GREY / key).log2().clamp(-max, max)
}

/// The factor radiance is multiplied by before the view transform: 2^EV, with auto exposure
/// metered on `img`.
pub fn exposure_scale(display: &Display, img: &Image) -> f64 {
    match display.exposure {
        Exposure::Ev(ev) => ev.exp2(),
        Exposure::Auto => auto_exposure_ev(img).exp2(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const VIEWS: [View; 3] = [View::Standard, View::Filmic, View::Agx];

    /// Grey radiance `x` under `view` at scale 1.
    fn grey(x: f64, view: View) -> f64 {
        display_rgb([x; 3], view)[1]
    }

    /// Every view is monotone in radiance (per channel and for grey), starts at black and stays
    /// within [0, 1]; grey stays grey.
    #[test]
    fn the_curves_are_monotone_from_black() {
        for view in VIEWS {
            assert!(grey(0.0, view) < 0.01, "{view:?} black");
            let mut last = -1.0;
            for i in 0..4000 {
                let x = 1e-6 * 1.005f64.powi(i);
                let d = display_rgb([x; 3], view);
                assert!((d[0] - d[1]).abs() < 2e-3 && (d[1] - d[2]).abs() < 2e-3, "{view:?} grey at {x}: {d:?}");
                assert!(d[1] >= last - 1e-12, "{view:?} not monotone at {x}: {} after {last}", d[1]);
                assert!((0.0..=1.0).contains(&d[1]));
                last = d[1];
                for ch in 0..3 {
                    let mut rgb = [0.3; 3];
                    let low = display_rgb(rgb, view)[ch];
                    rgb[ch] = 0.3 + x;
                    assert!(display_rgb(rgb, view)[ch] >= low - 1e-12, "{view:?} channel {ch} at {x}");
                }
            }
        }
        // The polynomial itself on its domain.
        let mut last = agx_contrast(0.0);
        for i in 1..=1000 {
            let y = agx_contrast(f64::from(i) / 1000.0);
            assert!(y > last, "contrast curve falls at {i}/1000");
            last = y;
        }
    }

    /// Highlights are not clipped: radiance from 1 to 8 (2.5 to 5.5 stops over mid grey at EV 0:
    /// a sunlit cloud's lit side) keeps distinct 8-bit values below white under filmic and agx,
    /// where a plain clip would make them all 255; mid grey sits in the middle of the range.
    #[test]
    fn highlights_roll_off_instead_of_clipping() {
        for view in [View::Filmic, View::Agx] {
            let bytes: Vec<u8> = [1.0f32, 2.0, 4.0, 8.0].iter().map(|&x| pixel_u8([x; 3], 1.0, view)[1]).collect();
            assert!(bytes.windows(2).all(|w| w[0] < w[1]), "{view:?}: {bytes:?}");
            assert!(bytes[3] < 255, "{view:?}: {bytes:?}");
            let mid = pixel_u8([MID_GREY as f32; 3], 1.0, view)[1];
            assert!((90..=160).contains(&mid), "{view:?} mid grey → {mid}");
            // Far above the range: white, not wrapped or NaN.
            assert_eq!(pixel_u8([1e30; 3], 1.0, view), [255; 3]);
            assert_eq!(pixel_u8([f32::INFINITY; 3], 1.0, view), [255; 3]);
            assert_eq!(pixel_u8([f32::NAN, -1.0, 0.0], 1.0, view)[0], pixel_u8([0.0; 3], 1.0, view)[0]);
        }
        // AgX desaturates a bright saturated colour towards white more than filmic does.
        let red = [8.0, 0.2, 0.2];
        let spread = |d: [f64; 3]| d[0] - d[1].min(d[2]);
        assert!(spread(display_rgb(red, View::Agx)) < spread(display_rgb(red, View::Filmic)));
    }

    /// `standard` at EV 0 is the mapping lpm used before (Reinhard on f32 radiance × 1, sRGB),
    /// byte for byte; EV +1 is the same as radiance × 2.
    #[test]
    fn standard_at_ev_0_is_the_old_mapping() {
        let old = |v: f32| -> u8 {
            let x = v as f64 * 1.0;
            let t = if x.is_nan() || x <= 0.0 {
                0.0
            } else if x.is_infinite() {
                1.0
            } else {
                x / (1.0 + x)
            };
            (srgb_encode(t) * 255.0 + 0.5) as u8
        };
        for i in 0..2000 {
            let v = 1e-5 * 1.01f32.powi(i);
            assert_eq!(pixel_u8([v, -v, v * 3.0], 1.0, View::Standard), [old(v), old(-v), old(v * 3.0)], "{v}");
        }
        for view in VIEWS {
            assert_eq!(pixel_u8([0.3; 3], Exposure::Ev(1.0).scale_for_test(), view), pixel_u8([0.6; 3], 1.0, view));
        }
    }

    impl Exposure {
        fn scale_for_test(self) -> f64 {
            let img = Image { width: 1, height: 1, rgb: vec![0.0; 3], alpha: None };
            exposure_scale(&Display { view: View::Agx, exposure: self }, &img)
        }
    }

    /// Auto exposure puts the medium's log-average luminance at mid grey whatever the sky: two
    /// pixels of medium (alpha 1) at luminance 0.5 and 2 (key 1) and a sky pixel of alpha 0.
    #[test]
    fn auto_exposure_meters_the_medium() {
        let img = Image {
            width: 3,
            height: 1,
            rgb: vec![0.5, 0.5, 0.5, 2.0, 2.0, 2.0, 100.0, 100.0, 100.0],
            alpha: Some(vec![1.0, 1.0, 0.0]),
        };
        assert!((auto_exposure_ev(&img) - MID_GREY.log2()).abs() < 1e-9);
        // No medium in view: every pixel counts.
        let sky = Image { width: 2, height: 1, rgb: vec![0.72; 6], alpha: Some(vec![0.0, 0.0]) };
        assert!((auto_exposure_ev(&sky) - (MID_GREY / 0.72).log2()).abs() < 1e-6);
        // Black: EV 0, not infinity.
        let black = Image { width: 1, height: 1, rgb: vec![0.0; 3], alpha: None };
        assert_eq!(auto_exposure_ev(&black), 0.0);
    }
}
