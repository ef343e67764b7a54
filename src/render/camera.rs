//! The ray through each pixel of a camera (the default view of a volume is defined with the scene's
//! camera keys: [`crate::scene::default_camera`]).

use crate::scene::{Camera, Projection};
use glam::DVec3;

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
    use crate::scene::default_camera;

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
