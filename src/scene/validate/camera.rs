//! `[camera]`: the camera keys (any subset of them), checked and completed into a [`Camera`], and
//! the default camera: the one place the default view of a volume is defined (the renderer, the
//! Monte-Carlo reference and `lpm render` all take it from here).
//!
//! Omitted keys take defaults in one of two ways:
//! - **neither `position` nor `look_at` given** (no `[camera]` at all, or only `width`, `height`,
//!   `fov_y`, `projection`, `view_height`, `up`): the default view — a three-quarter view from
//!   above, framing the whole volume — fitted to what is given: its distance is chosen for the
//!   image's aspect and field of view, an omitted `width` is 512 and an omitted `height` follows
//!   the volume's projected aspect (or the other way round when only `height` is given);
//! - **a hand-placed camera** (`position` or `look_at` given): an omitted `look_at` is the volume's
//!   centre, an omitted `position` the default view's eye; `up` defaults to +z, `fov_y` to 40°,
//!   `view_height` to the volume's diagonal and `width`/`height` to 512 each (as they always have).

use super::{Validator, MAX_IMAGE_SIZE, MAX_MAGNITUDE, PROJECTIONS, R};
use crate::scene::{Camera, Display, Exposure, Projection, SceneError, View, VIEW_NAMES};
use glam::DVec3;
use serde::Deserialize;
use std::path::Path;

/// Vertical field of view of the default camera and of a pinhole camera that names none, in degrees.
pub const DEFAULT_FOV_Y_DEGREES: f64 = 40.0;
/// Width and height of a hand-placed camera's image that names none; the default view's width.
pub const DEFAULT_IMAGE_SIZE: u32 = 512;
/// Room left around the volume in the default view (fraction of its projected size).
const DEFAULT_MARGIN: f64 = 1.08;
/// The default view's direction from the volume's centre: azimuth 45° between +x and +z, 30°
/// above the horizon, +y up.
const DEFAULT_ELEVATION_DEGREES: f64 = 30.0;
const DEFAULT_AZIMUTH_DEGREES: f64 = 45.0;

/// The `[camera]` keys as written: every key optional. Also what `lpm render --camera FILE` reads
/// (a `[camera]` table, or the same keys at the top level).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraKeys {
    /// "pinhole" (default) or "orthographic".
    pub projection: Option<String>,
    /// Pinhole only: vertical field of view in degrees.
    pub fov_y: Option<f64>,
    /// Orthographic only: height of the view in world units.
    pub view_height: Option<f64>,
    /// World position of the eye (pinhole) or of the image centre (orthographic).
    #[serde(default, deserialize_with = "crate::scene::raw::exactly3_opt")]
    pub position: Option<[f64; 3]>,
    #[serde(default, deserialize_with = "crate::scene::raw::exactly3_opt")]
    pub look_at: Option<[f64; 3]>,
    #[serde(default, deserialize_with = "crate::scene::raw::exactly3_opt")]
    pub up: Option<[f64; 3]>,
    pub width: Option<i64>,
    pub height: Option<i64>,
    /// The PNG preview's exposure: stops (EV, default 0) or "auto".
    pub exposure: Option<ExposureKey>,
    /// The PNG preview's view transform: "standard", "filmic" or "agx" (default).
    pub view: Option<String>,
}

/// `camera.exposure` as written: a number of stops or a word ("auto").
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum ExposureKey {
    Stops(f64),
    Word(String),
}

/// Where the volume is: what the camera defaults are computed from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeFrame {
    pub dims: [u32; 3],
    pub voxel_size: f64,
    /// World position of the volume's low corner.
    pub origin: DVec3,
}

impl VolumeFrame {
    /// The volume's extent in world units.
    fn extent(&self) -> DVec3 {
        DVec3::new(f64::from(self.dims[0]), f64::from(self.dims[1]), f64::from(self.dims[2])) * self.voxel_size
    }
}

/// The default view of a `dims` volume of voxels of edge `voxel_size`, in the volume's frame (its
/// corner at 0): a pinhole camera looking at the volume's centre from a three-quarter view above
/// it (azimuth 45° between +x and +z, 30° above the horizon, +y up), far enough back that the
/// whole volume is in frame. The image is 512 pixels wide, its aspect that of the volume's
/// projection.
pub fn default_camera(dims: [u32; 3], voxel_size: f64) -> Camera {
    fitted_default_camera(dims, voxel_size, None, None, DEFAULT_FOV_Y_DEGREES)
}

/// The default view for a given image size and field of view: an omitted dimension follows the
/// volume's projected aspect (width 512 when both are omitted), and the distance frames the whole
/// volume at that aspect and field of view.
pub fn fitted_default_camera(
    dims: [u32; 3],
    voxel_size: f64,
    width: Option<u32>,
    height: Option<u32>,
    fov_y_degrees: f64,
) -> Camera {
    let extent = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * voxel_size;
    let centre = extent * 0.5;
    let up = DVec3::Y;
    let (elevation, azimuth) = (DEFAULT_ELEVATION_DEGREES.to_radians(), DEFAULT_AZIMUTH_DEGREES.to_radians());
    let to_eye = DVec3::new(elevation.cos() * azimuth.sin(), elevation.sin(), elevation.cos() * azimuth.cos());
    // The camera frame exactly as the renderer builds it (`render::RayGenerator`).
    let forward = (-to_eye).normalize();
    let right = forward.cross(up).normalize();
    let cam_up = right.cross(forward);

    // Corners relative to the centre, in camera coordinates (right, up, toward the eye).
    let corners: Vec<DVec3> = (0..8)
        .map(|i| {
            let c = DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64) * extent - centre;
            DVec3::new(c.dot(right), c.dot(cam_up), c.dot(to_eye))
        })
        .collect();
    let half_w = corners.iter().map(|c| c.x.abs()).fold(0.0, f64::max);
    let half_h = corners.iter().map(|c| c.y.abs()).fold(0.0, f64::max);
    let aspect = if half_h > 0.0 { half_w / half_h } else { 1.0 };
    let size = |v: f64| (v.round() as u32).clamp(1, MAX_IMAGE_SIZE);
    let (width, height) = match (width, height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (w, size(w as f64 / aspect)),
        (None, Some(h)) => (size(h as f64 * aspect), h),
        (None, None) => (DEFAULT_IMAGE_SIZE, size(DEFAULT_IMAGE_SIZE as f64 / aspect)),
    };
    let aspect = width as f64 / height as f64;

    // Distance at which every corner projects inside the frame (depth grows with the distance).
    let tan_y = (fov_y_degrees.to_radians() * 0.5).tan();
    let distance = corners
        .iter()
        .map(|c| c.z + DEFAULT_MARGIN * (c.x.abs() / (tan_y * aspect)).max(c.y.abs() / tan_y))
        .fold(0.0, f64::max)
        .max(voxel_size);
    Camera {
        projection: Projection::Pinhole { fov_y_degrees },
        position: centre + to_eye * distance,
        look_at: centre,
        up,
        width,
        height,
    }
}

/// The orthographic view height that fits the whole volume whatever the view direction: the
/// length of the volume's diagonal in world units.
pub(super) fn diagonal(dims: [u32; 3], voxel_size: f64) -> f64 {
    let d = DVec3::new(f64::from(dims[0]), f64::from(dims[1]), f64::from(dims[2]));
    d.length() * voxel_size
}

/// Checks and completes camera `keys` for a volume placed as `frame` (see the module docs), as a
/// scene's `[camera]` would be; `source` names where the keys came from in messages (a file, or
/// the command line). The camera is returned in the volume's frame (its corner at 0).
pub fn camera_from_keys(keys: CameraKeys, source: &Path, frame: &VolumeFrame) -> Result<Camera, SceneError> {
    Validator { path: source }.camera(keys, frame)
}

/// Checks `[camera]`'s `exposure` and `view` (defaults for those omitted); `source` names where
/// the keys came from in messages (a file, or the command line).
pub fn display_from_keys(keys: &CameraKeys, source: &Path) -> Result<Display, SceneError> {
    Validator { path: source }.display(keys)
}

impl Validator<'_> {
    /// The preview's exposure and view transform.
    pub(super) fn display(&self, c: &CameraKeys) -> R<Display> {
        let exposure = match &c.exposure {
            None => Exposure::default(),
            Some(ExposureKey::Word(w)) if w == "auto" => Exposure::Auto,
            Some(ExposureKey::Word(w)) => {
                return Err(
                    self.err("camera.exposure", format!("expected a number of stops (EV) or \"auto\", got \"{w}\""))
                )
            }
            Some(ExposureKey::Stops(ev)) => Exposure::ev(*ev).map_err(|m| self.err("camera.exposure", m))?,
        };
        let view = match c.view.as_deref() {
            None => View::default(),
            Some(name) => View::from_name(name).ok_or_else(|| {
                self.err("camera.view", format!("unknown view transform \"{name}\", expected one of {VIEW_NAMES}"))
            })?,
        };
        Ok(Display { view, exposure })
    }

    /// The camera in the volume's frame.
    pub(super) fn camera(&self, c: CameraKeys, frame: &VolumeFrame) -> R<Camera> {
        let orthographic = match c.projection.as_deref().unwrap_or("pinhole") {
            "pinhole" => false,
            "orthographic" => true,
            other => {
                return Err(self.err(
                    "camera.projection",
                    format!("unknown projection \"{other}\", expected one of {PROJECTIONS}"),
                ))
            }
        };
        let fov = match (orthographic, c.fov_y) {
            (true, Some(_)) => return Err(self.err("camera.fov_y", "only applies to a pinhole camera")),
            (_, None) => DEFAULT_FOV_Y_DEGREES,
            (false, Some(f)) => {
                let f = self.finite("camera.fov_y", f)?;
                if f <= 0.0 || f >= 180.0 {
                    return Err(self.err("camera.fov_y", format!("must be in (0, 180) degrees, got {f}")));
                }
                f
            }
        };
        let view_height = match (orthographic, c.view_height) {
            (false, Some(_)) => return Err(self.err("camera.view_height", "only applies to an orthographic camera")),
            (_, None) => diagonal(frame.dims, frame.voxel_size),
            (true, Some(h)) => self.positive("camera.view_height", h, MAX_MAGNITUDE)?,
        };
        let projection = if orthographic {
            Projection::Orthographic { height: view_height }
        } else {
            Projection::Pinhole { fov_y_degrees: fov }
        };
        let width = c.width.map(|w| self.int_range("camera.width", w, 1, MAX_IMAGE_SIZE)).transpose()?;
        let height = c.height.map(|h| self.int_range("camera.height", h, 1, MAX_IMAGE_SIZE)).transpose()?;
        let up = c.up.map(|u| self.coordinates("camera.up", u)).transpose()?;

        if c.position.is_none() && c.look_at.is_none() {
            // The default view, fitted to the size and field of view given.
            let mut camera = fitted_default_camera(frame.dims, frame.voxel_size, width, height, fov);
            camera.projection = projection;
            if let Some(up) = up {
                camera.up = up;
                self.check_basis(camera.look_at - camera.position, up)?;
            }
            return Ok(camera);
        }
        // A hand-placed camera (positions given in the world frame).
        let default_eye = || default_camera(frame.dims, frame.voxel_size).position + frame.origin;
        let position = match c.position {
            Some(p) => self.coordinates("camera.position", p)?,
            None => default_eye(),
        };
        let look_at = match c.look_at {
            Some(l) => self.coordinates("camera.look_at", l)?,
            None => frame.origin + frame.extent() * 0.5,
        };
        let up = up.unwrap_or(DVec3::Z);
        let view = look_at - position;
        if view.length_squared() == 0.0 || !view.length_squared().is_finite() {
            return Err(self.err("camera.look_at", format!("must differ from camera.position, both are {position}")));
        }
        self.check_basis(view, up)?;
        Ok(Camera {
            projection,
            position: position - frame.origin,
            look_at: look_at - frame.origin,
            up,
            width: width.unwrap_or(DEFAULT_IMAGE_SIZE),
            height: height.unwrap_or(DEFAULT_IMAGE_SIZE),
        })
    }

    /// `up` must be a usable basis vector for looking along `view`.
    fn check_basis(&self, view: DVec3, up: DVec3) -> R<()> {
        let (Some(view_dir), Some(up_dir)) = (super::safe_normalize(view), super::safe_normalize(up)) else {
            return Err(self.err("camera.up", "must not be the zero vector"));
        };
        let sin = view_dir.cross(up_dir).length();
        if !(sin > 1e-6) {
            return Err(self.err(
                "camera.up",
                format!("must not be parallel to the view direction (look_at − position = {view}), got {up}"),
            ));
        }
        Ok(())
    }
}
