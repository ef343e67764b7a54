//! Comparing `image.exr` of two directories.

use super::metrics::metrics;
use super::{CompareError, ImageComparison};
use std::path::Path;

/// An EXR's size and its r, g, b values (row-major, top row first).
struct Rgb {
    width: usize,
    height: usize,
    values: Vec<f32>,
}

fn read_exr(path: &Path) -> Result<Rgb, CompareError> {
    // Through the input checks: a FIFO in place of image.exr would block in open() forever.
    let file =
        crate::input::open(path).map_err(|e| CompareError::Image { path: path.to_path_buf(), message: e.words() })?;
    use exr::prelude::traits::{ReadChannels, ReadLayers};
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| Rgb {
                width: res.width(),
                height: res.height(),
                values: vec![0.0f32; res.width() * res.height() * 3],
            },
            |img: &mut Rgb, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let i = 3 * (pos.y() * img.width + pos.x());
                if let Some(px) = img.values.get_mut(i..i + 3) {
                    px.copy_from_slice(&[r, g, b]);
                }
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::BufReader::new(file))
        .map_err(|e| CompareError::Image { path: path.to_path_buf(), message: e.to_string() })?;
    Ok(image.layer_data.channel_data.pixels)
}

/// Metrics of `a/image.exr` against `b/image.exr` when both exist with the same size; otherwise
/// `None` and a note (none when neither directory has an image).
pub(super) fn compare_images(
    a: &Path,
    b: &Path,
    notes: &mut Vec<String>,
) -> Result<Option<ImageComparison>, CompareError> {
    let (pa, pb) = (a.join("image.exr"), b.join("image.exr"));
    match (pa.exists(), pb.exists()) {
        (false, false) => return Ok(None),
        (true, true) => {}
        (has_a, _) => {
            let missing = if has_a { &pb } else { &pa };
            notes.push(format!("images not compared: {} does not exist", missing.display()));
            return Ok(None);
        }
    }
    let (ia, ib) = (read_exr(&pa)?, read_exr(&pb)?);
    if (ia.width, ia.height) != (ib.width, ib.height) {
        notes.push(format!(
            "images not compared: {} is {}×{} pixels, {} is {}×{}",
            pa.display(),
            ia.width,
            ia.height,
            pb.display(),
            ib.width,
            ib.height
        ));
        return Ok(None);
    }
    Ok(Some(ImageComparison {
        width: ia.width as u32,
        height: ia.height as u32,
        metrics: metrics(&ia.values, &ib.values),
    }))
}
