//! Rendering the solved volume: a camera ray-march over the in-scattered source, to EXR and PNG.
//!
//! World frame: voxel (i, j, k) occupies `[i·h, (i+1)·h) × [j·h, (j+1)·h) × [k·h, (k+1)·h)` with
//! `h` the voxel size; the volume spans `[0, dims·h]`. Each pixel's ray is walked voxel by voxel
//! (3D DDA, Amanatides–Woo); inside a voxel the medium is constant, so the radiance gathered over the
//! segment uses the exact closed form of the transfer equation ([`march`]). What the camera sees
//! beyond the volume is a uniform background radiance.
//!
//! [`render`] produces linear radiance ([`Image`]); [`write_exr`] stores it unchanged, [`write_png`]
//! tone-maps it for viewing.

mod camera;
mod image;
pub mod march;
mod write;

pub use camera::{default_camera, RayGenerator};
pub use image::{render, tone_map, Image, RenderInputs};
pub use write::{write_exr, write_png};
