//! Environment maps: a lat-long (equirectangular) OpenEXR image of the radiance arriving from every
//! direction, read and checked once when the scene is loaded.
//!
//! # Orientation (the convention of Blender's Environment Texture)
//!
//! The map is looked up with a direction `d` pointing *from the volume out to the sky* (the
//! direction the light comes from). `d` is first turned into the map's own frame, in which +z is
//! the zenith:
//!
//! - `up = "z"` (the default, Blender's world): the map frame is the world frame;
//! - `up = "y"` (Houdini's and most Y-up tools' world): +y is the zenith, and the map frame is
//!   the one Blender uses for the same scene after the usual Y-up → Z-up conversion
//!   `(x, y, z) → (x, −z, y)`;
//!
//! then turned by `rotation` degrees about the zenith (as Blender's Mapping node rotates the
//! lookup vector about Z). In the map frame, with φ = atan2(y, x) and θ = acos(z):
//!
//! ```text
//! u = 0.5 − φ/2π   (0 = left edge, column u·width)    v = θ/π   (0 = top row, row v·height)
//! ```
//!
//! so the top row is the zenith, the bottom row the nadir, the centre column looks along +x, the
//! column a quarter from the left along +y and the left/right edges along −x. This is exactly
//! Blender's `direction_to_equirectangular` (its v runs bottom-up; EXR rows run top-down).
//!
//! Each pixel is a constant radiance over its cell of solid angle
//! `Δφ·(cos θ_top − cos θ_bottom)`: the solver averages the map over its direction cells from
//! these pixel cells (see `solver::environment`), the renderer and the Monte-Carlo reference look
//! up the pixel a direction falls in.

use glam::DVec3;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Largest map width accepted, in pixels (16384 × 8192: about 1.6 GB of f32 RGB in memory).
pub const MAX_MAP_WIDTH: usize = 16384;

/// The axis of the world that the map's zenith (top row) points along (`lights[i].up`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MapUp {
    /// +z up (Blender).
    #[default]
    Z,
    /// +y up (Houdini, Maya, glTF): the world's (x, y, z) is the map frame's (x, −z, y).
    Y,
}

impl MapUp {
    /// The scene file's spelling: "z" or "y".
    pub fn name(self) -> &'static str {
        match self {
            MapUp::Z => "z",
            MapUp::Y => "y",
        }
    }
}

/// A lat-long map's pixels as read: linear RGB, f32, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentMap {
    /// The file it was read from (absolute).
    pub path: PathBuf,
    /// width = 2 · height.
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<[f32; 3]>,
}

/// `[[lights]] kind = "environment"`: a map, its scale and its orientation.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentLight {
    pub map: Arc<EnvironmentMap>,
    /// Scale of the map's values per channel (≥ 0): radiance = intensity · pixel.
    pub intensity: [f64; 3],
    pub up: MapUp,
    /// Turn about the zenith, in degrees (see the module docs).
    pub rotation_degrees: f64,
}

impl EnvironmentMap {
    /// The pixel's value at (x, y), x wrapping around, y clamped.
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        self.rgb[y.min(self.height - 1) * self.width + x % self.width]
    }

    /// Solid angle of one pixel of row `y` (sr): Δφ·(cos θ_top − cos θ_bottom). They sum to 4π.
    pub fn pixel_solid_angle(&self, y: usize) -> f64 {
        let h = self.height as f64;
        let (t0, t1) = (PI * y as f64 / h, PI * (y + 1) as f64 / h);
        2.0 * PI / self.width as f64 * (t0.cos() - t1.cos())
    }

    /// True when every pixel has r = g = b.
    pub fn is_grey(&self) -> bool {
        self.rgb.iter().all(|p| p[0] == p[1] && p[1] == p[2])
    }
}

impl EnvironmentLight {
    /// The direction `d` (world, toward the sky) in the map's frame (+z the zenith, turned by
    /// `rotation`).
    pub fn to_map(&self, d: DVec3) -> DVec3 {
        let m = match self.up {
            MapUp::Z => d,
            MapUp::Y => DVec3::new(d.x, -d.z, d.y),
        };
        let (s, c) = self.rotation_degrees.to_radians().sin_cos();
        DVec3::new(c * m.x - s * m.y, s * m.x + c * m.y, m.z)
    }

    /// The world direction (toward the sky) of a map-frame direction: the inverse of [`Self::to_map`].
    pub fn from_map(&self, m: DVec3) -> DVec3 {
        let (s, c) = self.rotation_degrees.to_radians().sin_cos();
        let r = DVec3::new(c * m.x + s * m.y, -s * m.x + c * m.y, m.z);
        match self.up {
            MapUp::Z => r,
            MapUp::Y => DVec3::new(r.x, r.z, -r.y),
        }
    }

    /// Continuous image coordinates (column, row; pixel (x, y) spans [x, x+1) × [y, y+1)) of the
    /// world direction `d` (toward the sky; need not be normalised).
    pub fn image_position(&self, d: DVec3) -> (f64, f64) {
        let m = self.to_map(d).normalize_or_zero();
        let u = (0.5 - m.y.atan2(m.x) / (2.0 * PI)).rem_euclid(1.0);
        let v = m.z.clamp(-1.0, 1.0).acos() / PI;
        (u * self.map.width as f64, v * self.map.height as f64)
    }

    /// The world direction (toward the sky) of image position (column, row), continuous.
    pub fn direction_at(&self, column: f64, row: f64) -> DVec3 {
        let phi = PI - 2.0 * PI * column / self.map.width as f64;
        let theta = PI * row / self.map.height as f64;
        let m = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        self.from_map(m)
    }

    /// The pixel the world direction `d` (toward the sky) falls in.
    pub fn pixel_of(&self, d: DVec3) -> (usize, usize) {
        let (x, y) = self.image_position(d);
        let (w, h) = (self.map.width, self.map.height);
        ((x.floor().max(0.0) as usize).min(w - 1), (y.floor().max(0.0) as usize).min(h - 1))
    }

    /// The radiance arriving from the world direction `d` (toward the sky): intensity × the
    /// pixel `d` falls in (the map is constant over each pixel).
    pub fn radiance(&self, d: DVec3) -> [f64; 3] {
        let (x, y) = self.pixel_of(d);
        let p = self.map.pixel(x, y);
        [0, 1, 2].map(|c| self.intensity[c] * p[c] as f64)
    }

    /// The same radiance in every channel (a grey map at a grey intensity).
    pub fn is_grey(&self) -> bool {
        let i = self.intensity;
        i[0] == i[1] && i[1] == i[2] && self.map.is_grey()
    }
}

/// Why a map file was refused, in words (the caller names the scene, key and file).
pub fn read_map(path: &Path) -> Result<EnvironmentMap, String> {
    use std::io::Seek;
    // One open file for the header and the pixels: what was checked is what is read.
    let file = crate::input::open(path).map_err(|e| match e {
        crate::input::InputError::Io { source, .. } => io_words(&source),
        crate::input::InputError::NotRegular { kind, .. } => format!("is {kind}, not a regular file"),
        e => e.to_string(),
    })?;
    let mut reader = std::io::BufReader::new(file);
    // The header first: its size decides the allocation below, and a lat-long map must be 2:1.
    let header = exr::meta::MetaData::read_from_buffered(&mut reader, false)
        .map_err(|e| format!("not a readable OpenEXR file ({})", exr_words(&e)))?;
    reader.rewind().map_err(|e| io_words(&e))?;
    let layer = header.headers.first().ok_or("an OpenEXR file without a layer")?;
    let (w, h) = (layer.layer_size.width(), layer.layer_size.height());
    if w != 2 * h || h == 0 {
        return Err(format!(
            "is {w} × {h} pixels: a lat-long (equirectangular) map is exactly twice as wide as it is high"
        ));
    }
    if w > MAX_MAP_WIDTH {
        return Err(format!("is {w} pixels wide, more than the limit of {MAX_MAP_WIDTH}"));
    }
    let names: Vec<String> = layer.channels.list.iter().map(|c| c.name.to_string()).collect();
    if !["R", "G", "B"].iter().all(|c| names.iter().any(|n| n == c)) {
        return Err(format!("has channels {names:?}: an R, G, B (and optionally A) image is expected"));
    }
    struct Pixels {
        width: usize,
        rgb: Vec<[f32; 3]>,
    }
    use exr::prelude::traits::{ReadChannels, ReadLayers};
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| Pixels { width: res.width(), rgb: vec![[0.0; 3]; res.width() * res.height()] },
            |px: &mut Pixels, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                if let Some(p) = px.rgb.get_mut(pos.y() * px.width + pos.x()) {
                    *p = [r, g, b];
                }
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(reader)
        .map_err(|e| format!("cannot read its pixels ({})", exr_words(&e)))?;
    let pixels = image.layer_data.channel_data.pixels;
    if pixels.width != w || pixels.rgb.len() != w * h {
        return Err(format!("its first layer's pixels are not the {w} × {h} its header declares"));
    }
    for (i, p) in pixels.rgb.iter().enumerate() {
        for (c, &v) in p.iter().enumerate() {
            if !v.is_finite() || v < 0.0 {
                let channel = ["R", "G", "B"][c];
                return Err(format!(
                    "pixel (x {}, y {}) channel {channel} is {v}: radiance must be finite and ≥ 0",
                    i % w,
                    i / w
                ));
            }
        }
    }
    Ok(EnvironmentMap { path: path.to_path_buf(), width: w, height: h, rgb: pixels.rgb })
}

fn io_words(e: &std::io::Error) -> String {
    let s = e.to_string();
    match s.rfind(" (os error ") {
        Some(i) if s.ends_with(')') => format!("cannot read it: {}", &s[..i]),
        _ => format!("cannot read it: {s}"),
    }
}

fn exr_words(e: &exr::error::Error) -> String {
    e.to_string().lines().next().unwrap_or("unknown error").to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(up: MapUp, rotation: f64) -> EnvironmentLight {
        let map = EnvironmentMap { path: "m.exr".into(), width: 64, height: 32, rgb: vec![[1.0; 3]; 64 * 32] };
        EnvironmentLight { map: Arc::new(map), intensity: [1.0; 3], up, rotation_degrees: rotation }
    }

    #[test]
    fn blender_orientation() {
        let l = light(MapUp::Z, 0.0);
        let at = |d: DVec3| {
            let (x, y) = l.image_position(d);
            (x / 64.0, y / 32.0)
        };
        let close = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12;
        // Centre column faces +x, a quarter from the left +y, three quarters −y; top row zenith.
        assert!(close(at(DVec3::X), (0.5, 0.5)));
        assert!(close(at(DVec3::Y), (0.25, 0.5)));
        assert!(close(at(-DVec3::Y), (0.75, 0.5)));
        assert!(at(DVec3::Z).1.abs() < 1e-12 && (at(-DVec3::Z).1 - 1.0).abs() < 1e-12);
        // Y up: +y is the zenith, −z the quarter column (Blender's +y after (x, y, z) → (x, −z, y)).
        let y = light(MapUp::Y, 0.0);
        assert!(y.image_position(DVec3::Y).1.abs() < 1e-12);
        assert!((y.image_position(-DVec3::Z).0 / 64.0 - 0.25).abs() < 1e-12);
        assert!((y.image_position(DVec3::X).0 / 64.0 - 0.5).abs() < 1e-12);
        // rotation = 90: the lookup vector turns by +90° about z, so −y now sees the centre column
        // and +x the quarter column.
        let r = light(MapUp::Z, 90.0);
        assert!((r.image_position(-DVec3::Y).0 / 64.0 - 0.5).abs() < 1e-9);
        assert!((r.image_position(DVec3::X).0 / 64.0 - 0.25).abs() < 1e-9);
    }

    #[test]
    fn directions_round_trip_and_solid_angles_sum_to_four_pi() {
        for (up, rot) in [(MapUp::Z, 0.0), (MapUp::Y, 37.0)] {
            let l = light(up, rot);
            for (cx, cy) in [(3.5, 7.25), (40.0, 0.5), (63.9, 31.5)] {
                let d = l.direction_at(cx, cy);
                let (x, y) = l.image_position(d);
                assert!((x - cx).abs() < 1e-9 && (y - cy).abs() < 1e-9, "{up:?}: ({cx}, {cy}) → ({x}, {y})");
            }
        }
        let m = light(MapUp::Z, 0.0).map;
        let sum: f64 = (0..m.height).map(|y| m.pixel_solid_angle(y) * m.width as f64).sum();
        assert!((sum - 4.0 * PI).abs() < 1e-12);
    }
}
