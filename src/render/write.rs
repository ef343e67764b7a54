//! Image files: linear EXR (the data) and tone-mapped sRGB PNG (for looking at), both atomic.

use super::image::{tone_map, Image};
use crate::output::{write_atomic, OutputError};
use std::io;
use std::path::Path;

fn check(path: &Path, img: &Image) -> Result<(), OutputError> {
    let n = img.width as usize * img.height as usize * 3;
    if img.width == 0 || img.height == 0 || img.rgb.len() != n {
        return Err(OutputError::Invalid {
            path: path.to_path_buf(),
            message: format!(
                "image of {}×{} pixels has {} values, expected {n} and a non-zero size",
                img.width,
                img.height,
                img.rgb.len()
            ),
        });
    }
    Ok(())
}

/// Writes `img` as an OpenEXR file with R, G, B f32 channels (linear radiance), atomically. The
/// chunks are compressed and written on this thread, in order: the parallel writer emits them in
/// completion order, so the same image gave different bytes from run to run.
pub fn write_exr(path: &Path, img: &Image) -> Result<(), OutputError> {
    use exr::prelude::{Image as ExrImage, SpecificChannels, Vec2, WritableImage};
    check(path, img)?;
    let w = img.width as usize;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let i = 3 * (y * w + x);
        (img.rgb[i], img.rgb[i + 1], img.rgb[i + 2])
    });
    let exr_image = ExrImage::from_channels((w, img.height as usize), channels);
    write_atomic(path, |out| exr_image.write().non_parallel().to_buffered(out).map_err(io::Error::other))
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

/// The sRGB transfer function, for `v` in [0, 1].
fn srgb_encode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
