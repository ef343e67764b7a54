//! Cameras: the default view of a volume, and the ray through each pixel.

use crate::scene::{Camera, Projection};
use glam::DVec3;

/// Width in pixels of the default camera's image.
const DEFAULT_WIDTH: u32 = 512;
/// Vertical field of view of the default camera, in degrees.
const DEFAULT_FOV_Y: f64 = 40.0;
/// Room left around the volume in the default view (fraction of its projected size).
const DEFAULT_MARGIN: f64 = 1.08;

/// A pinhole camera looking at the volume's centre from a three-quarter view above it (azimuth 45°
/// between +x and +z, 30° above the horizon, +y up), far enough back that the whole volume is in
/// frame. The image is 512 pixels wide, its aspect that of the volume's projection.
pub fn default_camera(dims: [u32; 3], voxel_size: f64) -> Camera {
    let extent = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * voxel_size;
    let centre = extent * 0.5;
    let up = DVec3::Y;
    let (elevation, azimuth) = (30f64.to_radians(), 45f64.to_radians());
    let to_eye = DVec3::new(elevation.cos() * azimuth.sin(), elevation.sin(), elevation.cos() * azimuth.cos());
    let frame = Frame::new(-to_eye, up);

    // Corners relative to the centre, in camera coordinates (right, up, toward the eye).
    let corners: Vec<DVec3> = (0..8)
        .map(|i| {
            let c = DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64) * extent - centre;
            DVec3::new(c.dot(frame.right), c.dot(frame.up), c.dot(to_eye))
        })
        .collect();
    let half_w = corners.iter().map(|c| c.x.abs()).fold(0.0, f64::max);
    let half_h = corners.iter().map(|c| c.y.abs()).fold(0.0, f64::max);
    let aspect = if half_h > 0.0 { half_w / half_h } else { 1.0 };
    let height = ((DEFAULT_WIDTH as f64 / aspect).round() as u32).clamp(1, 16384);
    let aspect = DEFAULT_WIDTH as f64 / height as f64;

    // Distance at which every corner projects inside the frame (depth grows with the distance).
    let tan_y = (DEFAULT_FOV_Y.to_radians() * 0.5).tan();
    let distance = corners
        .iter()
        .map(|c| c.z + DEFAULT_MARGIN * (c.x.abs() / (tan_y * aspect)).max(c.y.abs() / tan_y))
        .fold(0.0, f64::max)
        .max(voxel_size);
    Camera {
        projection: Projection::Pinhole { fov_y_degrees: DEFAULT_FOV_Y },
        position: centre + to_eye * distance,
        look_at: centre,
        up,
        width: DEFAULT_WIDTH,
        height,
    }
}

/// An orthonormal camera frame.
#[derive(Clone, Copy, Debug)]
struct Frame {
    forward: DVec3,
    right: DVec3,
    up: DVec3,
}

impl Frame {
    /// Frame looking along `forward`, with `up` made perpendicular. Degenerate inputs (zero forward,
    /// up parallel to forward) fall back to some valid frame instead of producing NaN rays.
    fn new(forward: DVec3, up: DVec3) -> Frame {
        let forward = forward.try_normalize().unwrap_or(DVec3::NEG_Z);
        let right = forward.cross(up).try_normalize().unwrap_or_else(|| forward.any_orthonormal_vector());
        Frame { forward, right, up: right.cross(forward) }
    }
}

/// Turns pixel coordinates into world rays for one camera.
#[derive(Clone, Copy, Debug)]
pub struct RayGenerator {
    frame: Frame,
    position: DVec3,
    projection: Projection,
    width: u32,
    height: u32,
}

impl RayGenerator {
    pub fn new(camera: &Camera) -> RayGenerator {
        RayGenerator {
            frame: Frame::new(camera.look_at - camera.position, camera.up),
            position: camera.position,
            projection: camera.projection,
            width: camera.width.max(1),
            height: camera.height.max(1),
        }
    }

    /// (origin, unit direction) of the ray through the centre of pixel (`px`, `py`), `py` = 0 being
    /// the top row. Orthographic rays start on the image plane through the camera position; nothing
    /// behind a camera is seen.
    pub fn ray(&self, px: u32, py: u32) -> (DVec3, DVec3) {
        let u = (px as f64 + 0.5) / self.width as f64 * 2.0 - 1.0;
        let v = 1.0 - (py as f64 + 0.5) / self.height as f64 * 2.0;
        let aspect = self.width as f64 / self.height as f64;
        let f = self.frame;
        match self.projection {
            Projection::Pinhole { fov_y_degrees } => {
                let t = (fov_y_degrees.to_radians() * 0.5).tan();
                let dir = f.forward + f.right * (u * t * aspect) + f.up * (v * t);
                (self.position, dir.normalize())
            }
            Projection::Orthographic { height } => {
                let half = height * 0.5;
                (self.position + f.right * (u * half * aspect) + f.up * (v * half), f.forward)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_goes_through_look_at() {
        let mut camera = default_camera([30, 40, 50], 0.5);
        camera.width = 5;
        camera.height = 3;
        let (o, d) = RayGenerator::new(&camera).ray(2, 1);
        let to_target = camera.look_at - o;
        assert!((to_target.normalize() - d).length() < 1e-12);
        assert!((camera.height as f64) > 0.0);
        // Top row looks higher than the bottom row.
        let g = RayGenerator::new(&camera);
        assert!(g.ray(2, 0).1.y > g.ray(2, 2).1.y);
        // A degenerate up vector still gives finite rays.
        camera.up = camera.look_at - camera.position;
        let (_, d) = RayGenerator::new(&camera).ray(0, 0);
        assert!(d.is_finite());
    }
}
