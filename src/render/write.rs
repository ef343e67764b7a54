//! Image files: linear EXR (the data) and tone-mapped sRGB PNG (for looking at), both atomic.

use super::image::Image;
use super::tone::{exposure_scale, pixel_u8};
use crate::output::{write_atomic, OutputError};
use crate::scene::Display;
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

/// Writes `img` as an 8-bit sRGB PNG: radiance × 2^exposure through `display`'s view transform
/// (see [`super::tone`]). Atomic.
pub fn write_png(path: &Path, img: &Image, display: &Display) -> Result<(), OutputError> {
    check(path, img)?;
    let scale = exposure_scale(display, img);
    let bytes: Vec<u8> =
        img.rgb.chunks_exact(3).flat_map(|p| pixel_u8([p[0], p[1], p[2]], scale, display.view)).collect();
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
/// alpha before it is exposed and mapped as [`write_png`] does; alpha is stored linearly.
/// Pixels of zero alpha are black and fully transparent. An image without alpha is written opaque.
pub fn write_png_rgba(path: &Path, img: &Image, display: &Display) -> Result<(), OutputError> {
    check(path, img)?;
    let scale = exposure_scale(display, img);
    let pixels = img.width as usize * img.height as usize;
    let mut bytes = Vec::with_capacity(pixels * 4);
    for p in 0..pixels {
        let a = img.alpha.as_ref().map_or(1.0, |a| a[p].clamp(0.0, 1.0));
        let straight = [0, 1, 2].map(|ch| if a > 0.0 { img.rgb[3 * p + ch] / a } else { 0.0 });
        bytes.extend(pixel_u8(straight, scale, display.view));
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
/// preview), exposed and mapped as `display` says.
pub fn write_images(
    exr: Option<&Path>,
    png: Option<&Path>,
    img: &Image,
    background: super::Background,
    display: &Display,
) -> Result<(), OutputError> {
    if let Some(path) = exr {
        write_exr(path, img)?;
    }
    match (png, background) {
        (Some(path), super::Background::Sky) => write_png(path, img, display),
        (Some(path), super::Background::Transparent) => write_png_rgba(path, img, display),
        (None, _) => Ok(()),
    }
}
