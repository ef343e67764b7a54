//! Rendering the solved volume: a camera ray-march over the in-scattered source, to EXR and PNG.
//!
//! World frame: voxel (i, j, k) occupies `[i·h, (i+1)·h) × [j·h, (j+1)·h) × [k·h, (k+1)·h)` with
//! `h` the voxel size; the volume spans `[0, dims·h]`. Each pixel's ray is walked voxel by voxel
//! (3D DDA, Amanatides–Woo); inside a voxel the medium is constant, so the radiance gathered over the
//! segment uses the exact closed form of the transfer equation ([`march`]). The source is read
//! trilinearly between voxel centres and, for an anisotropic medium, blended between the storage
//! directions around the ray's direction ([`crate::quadrature::StorageBlend`]; [`render_solved`]
//! builds the blend): taking the one storage cell that holds the direction made a seam wherever
//! neighbouring pixels' rays fell in different cells. The suns' single scattering (every sun and an
//! environment map's sun-like peak; point lights alike) is not read from that source but
//! evaluated exactly along the ray, `σs(x)·p_HG(g; ω_sun·ω_camera)·E(x)` from each sun's uncollided irradiance per voxel with
//! the scene's true medium ([`SingleScattering`]; the solve takes the suns' binned first
//! scattering off the source it keeps for the image, [`crate::solver::direct`]): its forward peak,
//! the silver lining of a cloud seen towards the sun, is far narrower than a storage cell and is
//! truncated by δ-M in the solve. Under δ-M the light the truncated peak kept in the sun's beam
//! is scattered towards the camera there too, by chains of peak scatterings, and the sun's light
//! scattered more than once but still near its direction is sharpened from what the storage
//! cells hold of it into its forward lobes ([`peak`]), both corrected for the light's sideways
//! spread by a transport on a cone of directions about each sun ([`cone`]). What the camera sees
//! beyond the volume is the sky's uniform radiance plus the environment map's pixel in the ray's
//! direction.
//!
//! [`render`] produces linear radiance and alpha = 1 − transmittance ([`Image`]); the background
//! is the sky, or nothing ([`Background::Transparent`]: premultiplied colour, for compositing).
//! [`write_exr`] stores it unchanged (RGBA), [`write_png`] exposes and tone-maps it for viewing
//! (RGB; the exposure and view transform of [`crate::scene::Display`], see [`tone`]), and
//! [`write_png_rgba`] does the same with straight alpha for a transparent background.

mod camera;
pub mod cone;
mod image;
pub mod keep;
pub mod march;
pub mod memory;
pub mod peak;
pub mod tone;
mod write;

pub use crate::scene::default_camera;
pub use camera::RayGenerator;
pub use image::{
    render, tone_map, Background, DirectBeam, Image, PointSource, RenderInputs, SingleScattering, VoxelFactors,
};
pub use keep::{render_solved, RenderData, RENDER_DATA};
pub use write::{write_exr, write_images, write_png, write_png_rgba};
