//! A grid's transform (index space → world space). lpm's voxels are axis-aligned cubes, so only
//! maps made of a uniform positive scale and a translation are accepted: `UniformScaleMap`,
//! `UniformScaleTranslateMap`, `ScaleMap`/`ScaleTranslateMap` with equal scales, `TranslationMap`,
//! and an `AffineMap` whose matrix is such a scale and translation. Rotation, shear, non-uniform
//! scale and frustum maps are refused with a message saying so (resampling is not done here).

use super::error::{VdbError, R};
use super::stream::Stream;
use std::io::{Read, Seek};

/// Index coordinate `ijk` (a voxel centre) is at world `translation + voxel_size · ijk`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub voxel_size: f64,
    pub translation: [f64; 3],
}

pub(crate) fn read_transform<S: Read + Seek>(s: &mut Stream<S>, grid: &str) -> R<Placement> {
    let what = "the grid transform";
    let map = s.string(what)?;
    let refuse = |message: String| VdbError::Transform { name: grid.to_string(), message };
    let (scale, translation) = match map.as_str() {
        "UniformScaleMap" | "ScaleMap" => {
            let scale = s.vec3d(what)?;
            s.skip(4 * 24, what)?;
            (scale, [0.0; 3])
        }
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let t = s.vec3d(what)?;
            let scale = s.vec3d(what)?;
            s.skip(4 * 24, what)?;
            (scale, t)
        }
        "TranslationMap" => ([1.0; 3], s.vec3d(what)?),
        "AffineMap" => {
            let mut m = [0.0f64; 16];
            for v in &mut m {
                *v = s.f64(what)?;
            }
            // Row-major, row vectors: the translation is the last row.
            let off_diagonal = [1, 2, 3, 4, 6, 7, 8, 9, 11];
            if off_diagonal.iter().any(|&i| m[i] != 0.0) || m[15] != 1.0 {
                return Err(refuse(format!(
                    "its AffineMap has rotation, shear or projection (matrix {m:?}); lpm needs axis-aligned cubic voxels: resample the grid to an axis-aligned transform"
                )));
            }
            ([m[0], m[5], m[10]], [m[12], m[13], m[14]])
        }
        other => {
            return Err(refuse(format!(
                "its transform is a {other}, which rotates, shears or projects the voxels; lpm needs axis-aligned cubic voxels (a uniform scale and a translation): resample the grid"
            )))
        }
    };
    if !scale.iter().chain(&translation).all(|v| v.is_finite()) || scale.iter().any(|&v| v <= 0.0) {
        return Err(refuse(format!("its transform has a scale of {scale:?} and a translation of {translation:?}; the scale must be positive and all values finite")));
    }
    let (lo, hi) = (scale.iter().cloned().fold(f64::MAX, f64::min), scale.iter().cloned().fold(0.0, f64::max));
    if hi - lo > 1e-9 * hi {
        return Err(refuse(format!(
            "its voxels are not cubes (voxel size {} × {} × {}); lpm needs a uniform scale: resample the grid",
            scale[0], scale[1], scale[2]
        )));
    }
    Ok(Placement { voxel_size: scale[0], translation })
}
