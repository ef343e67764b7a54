//! The environment map as the reference sees it: one channel's pixel radiances, a lookup by
//! direction and importance sampling of the direction light arrives from.
//!
//! The lat-long convention is written here again from its definition (README, `scene::environment`)
//! rather than called from the scene module, so that a mistake in either mapping shows up as a
//! disagreement between the solver and the reference instead of being shared by both.

use super::rng::Rng;
use crate::scene::{EnvironmentLight, MapUp};
use glam::DVec3;
use std::f64::consts::PI;
use std::sync::Arc;

/// One channel of an environment map.
#[derive(Clone, Debug)]
pub struct EnvChannel {
    map: Arc<crate::scene::EnvironmentMap>,
    channel: usize,
    intensity: f64,
    up: MapUp,
    /// cos and sin of the turn about the zenith.
    turn: (f64, f64),
    /// Cumulative L·Ω over the rows, and within each row over its columns (for sampling).
    row_cdf: Vec<f64>,
    column_cdf: Vec<f64>,
    /// Σ L·Ω over the map: the irradiance-like power per unit area the map sends through a disk
    /// facing each direction, integrated over directions.
    pub power: f64,
}

impl EnvChannel {
    pub fn new(env: &EnvironmentLight, channel: usize) -> EnvChannel {
        let map = Arc::clone(&env.map);
        let (w, h) = (map.width, map.height);
        let intensity = env.intensity[channel];
        let (mut row_cdf, mut column_cdf) = (Vec::with_capacity(h), Vec::with_capacity(w * h));
        let mut total = 0.0;
        for y in 0..h {
            let (t0, t1) = (PI * y as f64 / h as f64, PI * (y + 1) as f64 / h as f64);
            let omega = 2.0 * PI / w as f64 * (t0.cos() - t1.cos());
            let mut row = 0.0;
            for x in 0..w {
                row += intensity * map.rgb[y * w + x][channel] as f64 * omega;
                column_cdf.push(row);
            }
            total += row;
            row_cdf.push(total);
        }
        let turn = env.rotation_degrees.to_radians().sin_cos();
        EnvChannel { map, channel, intensity, up: env.up, turn: (turn.1, turn.0), row_cdf, column_cdf, power: total }
    }

    /// World direction (toward the sky) → map frame (+z the zenith).
    fn to_map(&self, d: DVec3) -> DVec3 {
        let m = if self.up == MapUp::Y { DVec3::new(d.x, -d.z, d.y) } else { d };
        let (c, s) = self.turn;
        DVec3::new(c * m.x - s * m.y, s * m.x + c * m.y, m.z)
    }

    /// Map frame → world direction.
    fn to_world(&self, m: DVec3) -> DVec3 {
        let (c, s) = self.turn;
        let r = DVec3::new(c * m.x + s * m.y, -s * m.x + c * m.y, m.z);
        if self.up == MapUp::Y {
            DVec3::new(r.x, r.z, -r.y)
        } else {
            r
        }
    }

    /// Radiance arriving from the world direction `toward` (unit).
    pub fn radiance(&self, toward: DVec3) -> f64 {
        let m = self.to_map(toward);
        let (w, h) = (self.map.width, self.map.height);
        // φ = atan2(y, x); column = (1/2 − φ/2π)·w; row = θ/π·h.
        let u = (0.5 - m.y.atan2(m.x) / (2.0 * PI)).rem_euclid(1.0);
        let v = m.z.clamp(-1.0, 1.0).acos() / PI;
        let x = ((u * w as f64) as usize).min(w - 1);
        let y = ((v * h as f64) as usize).min(h - 1);
        self.intensity * self.map.rgb[y * w + x][self.channel] as f64
    }

    /// A direction toward the sky with density ∝ L (per unit solid angle): a pixel ∝ L·Ω, then a
    /// point uniform in its solid angle.
    pub fn sample(&self, rng: &mut Rng) -> Option<DVec3> {
        if !(self.power > 0.0) {
            return None;
        }
        let (w, h) = (self.map.width, self.map.height);
        let r = rng.uniform() * self.power;
        let y = self.row_cdf.partition_point(|&c| c <= r).min(h - 1);
        let row = &self.column_cdf[y * w..(y + 1) * w];
        let in_row = rng.uniform() * row[w - 1];
        let x = row.partition_point(|&c| c <= in_row).min(w - 1);
        let (c0, c1) = ((PI * y as f64 / h as f64).cos(), (PI * (y + 1) as f64 / h as f64).cos());
        let cos_t = c0 + (c1 - c0) * rng.uniform();
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = PI - 2.0 * PI * (x as f64 + rng.uniform()) / w as f64;
        Some(self.to_world(DVec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)))
    }
}
