//! Image files: linear EXR (the data) and tone-mapped sRGB PNG (for looking at), both atomic.

use super::image::{tone_map, Image};
use crate::output::{write_atomic, OutputError};
use std::io;
use std::path::Path;

fn check(path: &Path, img: &Image) -> Result<(), OutputError> {
    let n = img.width as usize * img.height as usize * 3;
    let alpha_ok = img.alpha.as_ref().is_none_or(|a| a.len() * 3 == n);
    if img.width == 0 || img.height == 0 || img.rgb.len() != n || !alpha_ok {
        return Err(OutputError::Invalid {
            path: path.to_path_buf(),
            message: format!(
                "image of {}×{} pixels has {} colour values{}, expected {n} (and one alpha per pixel) and a non-zero size",
                img.width,
                img.height,
                img.rgb.len(),
                img.alpha.as_ref().map_or(String::new(), |a| format!(" and {} alpha values", a.len()))
            ),
        });
    }
    Ok(())
}

/// Writes `img` as an OpenEXR file with R, G, B f32 channels (linear radiance) and, when the
/// image has one, an A channel (compositors read EXR colour as premultiplied by it), atomically.
/// The chunks are compressed and written on this thread, in order: the parallel writer emits them
/// in completion order, so the same image gave different bytes from run to run.
pub fn write_exr(path: &Path, img: &Image) -> Result<(), OutputError> {
    use exr::prelude::{Image as ExrImage, SpecificChannels, Vec2, WritableImage};
    check(path, img)?;
    let (w, h) = (img.width as usize, img.height as usize);
    let rgb = |x: usize, y: usize| {
        let i = 3 * (y * w + x);
        (img.rgb[i], img.rgb[i + 1], img.rgb[i + 2])
    };
    match &img.alpha {
        Some(alpha) => {
            let channels = SpecificChannels::rgba(|Vec2(x, y): Vec2<usize>| {
                let (r, g, b) = rgb(x, y);
                (r, g, b, alpha[y * w + x])
            });
            let exr_image = ExrImage::from_channels((w, h), channels);
            write_atomic(path, |out| exr_image.write().non_parallel().to_buffered(out).map_err(io::Error::other))
        }
        None => {
            let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| rgb(x, y));
            let exr_image = ExrImage::from_channels((w, h), channels);
            write_atomic(path, |out| exr_image.write().non_parallel().to_buffered(out).map_err(io::Error::other))
        }
    }
}

/// Writes `img` as an 8-bit sRGB PNG: radiance × `exposure`, tone-mapped ([`tone_map`]), then
/// sRGB-encoded. Atomic.
pub fn write_png(path: &Path, img: &Image, exposure: f64) -> Result<(), OutputError> {
    check(path, img)?;
    let bytes: Vec<u8> = img.rgb.iter().map(|&v| (srgb_encode(tone_map(v, exposure)) * 255.0 + 0.5) as u8).collect();
    write_atomic(path, |out| {
        let mut encoder = png::Encoder::new(out, img.width, img.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header().map_err(io::Error::other)?;
        writer.write_image_data(&bytes).map_err(io::Error::other)?;
        writer.finish().map_err(io::Error::other)
    })
}

/// Writes `img` as an 8-bit sRGB PNG with alpha, for an image rendered over a transparent
/// background: PNG colour is straight (not premultiplied), so each pixel's colour is divided by its
/// alpha before it is scaled by `exposure`, tone-mapped and encoded; alpha is stored linearly.
/// Pixels of zero alpha are black and fully transparent. An image without alpha is written opaque.
pub fn write_png_rgba(path: &Path, img: &Image, exposure: f64) -> Result<(), OutputError> {
    check(path, img)?;
    let pixels = img.width as usize * img.height as usize;
    let mut bytes = Vec::with_capacity(pixels * 4);
    for p in 0..pixels {
        let a = img.alpha.as_ref().map_or(1.0, |a| a[p].clamp(0.0, 1.0));
        for ch in 0..3 {
            let straight = if a > 0.0 { img.rgb[3 * p + ch] / a } else { 0.0 };
            bytes.push((srgb_encode(tone_map(straight, exposure)) * 255.0 + 0.5) as u8);
        }
        bytes.push((a * 255.0 + 0.5) as u8);
    }
    write_atomic(path, |out| {
        let mut encoder = png::Encoder::new(out, img.width, img.height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header().map_err(io::Error::other)?;
        writer.write_image_data(&bytes).map_err(io::Error::other)?;
        writer.finish().map_err(io::Error::other)
    })
}

/// Writes `img` as `exr` and `png` (either may be `None`), as a solve does: the EXR always with
/// alpha, the PNG with alpha only for a transparent background (over the sky it is an opaque
/// preview).
pub fn write_images(
    exr: Option<&Path>,
    png: Option<&Path>,
    img: &Image,
    background: super::Background,
) -> Result<(), OutputError> {
    if let Some(path) = exr {
        write_exr(path, img)?;
    }
    match (png, background) {
        (Some(path), super::Background::Sky) => write_png(path, img, 1.0),
        (Some(path), super::Background::Transparent) => write_png_rgba(path, img, 1.0),
        (None, _) => Ok(()),
    }
}

/// The sRGB transfer function, for `v` in [0, 1].
fn srgb_encode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
