//! The reference's own view of the medium: one density per voxel, per-brick density bounds, the
//! box intersection and an exact 3D DDA. Everything is in grid units (the box is [0, dims], one unit
//! per voxel edge), so extinction coefficients are scaled by the voxel size once, up front.

use glam::DVec3;

/// Brick edge in voxels for the majorant grid.
pub const BRICK: u32 = 16;

/// Densities and per-brick bounds.
#[derive(Clone, Debug)]
pub struct Grid {
    pub dims: [u32; 3],
    /// Bricks per axis: ceil(dims / 16).
    pub bricks: [u32; 3],
    /// Density per voxel, x fastest; every value finite and ≥ 0.
    pub density: Vec<f32>,
    /// Largest and smallest density in each brick (x fastest over bricks).
    pub brick_max: Vec<f32>,
    pub brick_min: Vec<f32>,
    /// Per-voxel emission factor e(v) per channel (x fastest), or empty: the medium emits
    /// uniformly (e = 1).
    pub emission: Vec<[f32; 3]>,
    /// Σ ρ·e over the voxels per channel (Σ ρ when the medium emits uniformly): what the emitted
    /// power is proportional to (without an albedo grid; see [`Grid::absorbing_weight`]).
    pub emission_weight: [f64; 3],
    /// Per-voxel albedo factor a(v) in [0, 1] (x fastest), or empty: the albedo is the medium's
    /// everywhere (a = 1).
    pub albedo: Vec<f32>,
}

impl Grid {
    /// Sample the density function once per voxel. Values that are not finite or are negative are
    /// replaced by 0; their number is returned alongside the grid.
    pub fn new(dims: [u32; 3], density: &(dyn Fn([u32; 3]) -> f32 + Sync)) -> (Grid, u64) {
        let n = dims[0] as usize * dims[1] as usize * dims[2] as usize;
        let mut values = Vec::with_capacity(n);
        let mut bad = 0u64;
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = density([x, y, z]);
                    if v.is_finite() && v >= 0.0 {
                        values.push(v);
                    } else {
                        bad += 1;
                        values.push(0.0);
                    }
                }
            }
        }
        let bricks = [0, 1, 2].map(|a| dims[a].div_ceil(BRICK));
        let nb = bricks[0] as usize * bricks[1] as usize * bricks[2] as usize;
        let mut brick_max = vec![0.0f32; nb];
        let mut brick_min = vec![f32::INFINITY; nb];
        let mut total = 0.0f64;
        let mut i = 0usize;
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let v = values[i];
                    i += 1;
                    total += v as f64;
                    let b = ((z / BRICK) as usize * bricks[1] as usize + (y / BRICK) as usize) * bricks[0] as usize
                        + (x / BRICK) as usize;
                    brick_max[b] = brick_max[b].max(v);
                    brick_min[b] = brick_min[b].min(v);
                }
            }
        }
        for m in brick_min.iter_mut() {
            if !m.is_finite() {
                *m = 0.0;
            }
        }
        let grid = Grid {
            dims,
            bricks,
            density: values,
            brick_max,
            brick_min,
            emission: Vec::new(),
            emission_weight: [total; 3],
            albedo: Vec::new(),
        };
        (grid, bad)
    }

    /// Sets a per-voxel emission factor per channel, sampled once per voxel (a non-finite or
    /// negative value counts as 0; the number of voxels with one is returned).
    pub fn set_emission(&mut self, emission: &(dyn Fn([u32; 3]) -> [f32; 3] + Sync)) -> u64 {
        let mut bad = 0;
        let mut values = Vec::with_capacity(self.density.len());
        for z in 0..self.dims[2] {
            for y in 0..self.dims[1] {
                for x in 0..self.dims[0] {
                    let e = emission([x, y, z]);
                    if !e.iter().all(|v| v.is_finite() && *v >= 0.0) {
                        bad += 1;
                    }
                    values.push(e.map(|v| if v.is_finite() && v >= 0.0 { v } else { 0.0 }));
                }
            }
        }
        self.emission_weight =
            std::array::from_fn(|ch| self.density.iter().zip(&values).map(|(&d, e)| d as f64 * e[ch] as f64).sum());
        self.emission = values;
        bad
    }

    /// Sets a per-voxel albedo factor a(v), sampled once per voxel (a value that is not finite or
    /// lies outside [0, 1] is clamped into it, NaN to 0; the number of voxels with one is returned).
    pub fn set_albedo(&mut self, albedo: &(dyn Fn([u32; 3]) -> f32 + Sync)) -> u64 {
        let mut bad = 0;
        let mut values = Vec::with_capacity(self.density.len());
        for z in 0..self.dims[2] {
            for y in 0..self.dims[1] {
                for x in 0..self.dims[0] {
                    let a = albedo([x, y, z]);
                    if !(0.0..=1.0).contains(&a) {
                        bad += 1;
                    }
                    values.push(if a.is_nan() { 0.0 } else { a.clamp(0.0, 1.0) });
                }
            }
        }
        self.albedo = values;
        bad
    }

    /// The albedo factor of voxel `i` (1 without an albedo grid).
    #[inline]
    pub fn albedo_factor(&self, i: usize) -> f64 {
        self.albedo.get(i).map_or(1.0, |&a| a as f64)
    }

    /// The albedo factor at the point `p` (grid units) of a collision.
    #[inline]
    pub fn albedo_at(&self, p: DVec3) -> f64 {
        if self.albedo.is_empty() {
            return 1.0;
        }
        let v = [0, 1, 2].map(|a| (p[a].floor() as i64).clamp(0, self.dims[a] as i64 - 1));
        self.albedo_factor(self.voxel_index(v))
    }

    /// What the emission of voxel `i` in channel `ch` is proportional to: ρ·e·(1 − α·a(v)) with α
    /// the medium's albedo of the channel (its σa(v) over σt); `None` without an albedo grid, where
    /// the medium's σa is the same in every voxel and [`Grid::emission_weight`] serves.
    pub fn absorbing_weight(&self, i: usize, ch: usize, medium_albedo: f64) -> Option<f64> {
        let a = *self.albedo.get(i)? as f64;
        Some(self.density[i] as f64 * self.emission_factor(i, ch) * (1.0 - medium_albedo * a))
    }

    /// The emission factor of voxel `i` in channel `ch` (1 when the medium emits uniformly).
    pub fn emission_factor(&self, i: usize, ch: usize) -> f64 {
        self.emission.get(i).map_or(1.0, |e| e[ch] as f64)
    }

    pub fn voxel_count(&self) -> usize {
        self.density.len()
    }

    #[inline]
    pub fn extent(&self) -> DVec3 {
        DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64)
    }

    #[inline]
    pub fn voxel_index(&self, v: [i64; 3]) -> usize {
        (v[2] as usize * self.dims[1] as usize + v[1] as usize) * self.dims[0] as usize + v[0] as usize
    }

    #[inline]
    pub fn brick_index(&self, b: [i64; 3]) -> usize {
        (b[2] as usize * self.bricks[1] as usize + b[1] as usize) * self.bricks[0] as usize + b[0] as usize
    }

    /// The voxel containing `p`, clamped into brick `b` (guards against a rounding step across the
    /// brick face, which would otherwise let a density exceed the brick's majorant).
    #[inline]
    pub fn voxel_in_brick(&self, p: DVec3, b: [i64; 3]) -> [i64; 3] {
        let mut v = [0i64; 3];
        for a in 0..3 {
            let lo = b[a] * BRICK as i64;
            let hi = ((b[a] + 1) * BRICK as i64).min(self.dims[a] as i64) - 1;
            v[a] = (p[a].floor() as i64).clamp(lo, hi);
        }
        v
    }
}

/// The parameter interval [t0, t1] (t1 > max(t0, 0)) over which the ray o + t·d is inside the box
/// [0, hi]; `None` when it misses or the box is behind the ray.
pub fn box_interval(o: DVec3, d: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < 0.0 || o[a] > hi[a] {
                return None;
            }
        } else {
            let ta = (0.0 - o[a]) / d[a];
            let tb = (hi[a] - o[a]) / d[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    if t1 > t0 && t1 > 0.0 && t1.is_finite() {
        Some((t0, t1))
    } else {
        None
    }
}

/// Exact 3D DDA over a uniform grid of cubic cells of edge `cell` with `n` cells per axis, for the
/// ray p + t·d, t ∈ [0, t_end]. Yields (cell, t_in, t_out) in order; consecutive intervals share
/// their end points, the first starts at 0 and the last ends at t_end, so the lengths sum to t_end
/// (up to round-off in the differences). `p` should lie in (or on) the grid; the start cell is
/// clamped into it.
pub struct Dda {
    p: DVec3,
    d: DVec3,
    cell_size: f64,
    n: [i64; 3],
    cell: [i64; 3],
    t: f64,
    t_end: f64,
    done: bool,
}

impl Dda {
    pub fn new(p: DVec3, d: DVec3, t_end: f64, cell_size: f64, n: [u32; 3]) -> Dda {
        let n = n.map(|v| v as i64);
        let mut cell = [0i64; 3];
        for a in 0..3 {
            cell[a] = ((p[a] / cell_size).floor() as i64).clamp(0, (n[a] - 1).max(0));
        }
        let done = !(t_end > 0.0) || n.iter().any(|&v| v <= 0);
        Dda { p, d, cell_size, n, cell, t: 0.0, t_end, done }
    }

    #[inline]
    fn boundary(&self, a: usize) -> f64 {
        let d = self.d[a];
        if d > 0.0 {
            ((self.cell[a] + 1) as f64 * self.cell_size - self.p[a]) / d
        } else if d < 0.0 {
            (self.cell[a] as f64 * self.cell_size - self.p[a]) / d
        } else {
            f64::INFINITY
        }
    }
}

impl Iterator for Dda {
    type Item = ([i64; 3], f64, f64);

    #[inline]
    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let tb = [self.boundary(0), self.boundary(1), self.boundary(2)];
        let mut axis = 0;
        if tb[1] < tb[axis] {
            axis = 1;
        }
        if tb[2] < tb[axis] {
            axis = 2;
        }
        let t_in = self.t;
        let t_out = tb[axis].min(self.t_end).max(t_in);
        let cell = self.cell;
        if t_out >= self.t_end {
            self.done = true;
            return Some((cell, t_in, self.t_end));
        }
        self.t = t_out;
        self.cell[axis] += if self.d[axis] > 0.0 { 1 } else { -1 };
        if self.cell[axis] < 0 || self.cell[axis] >= self.n[axis] {
            // Left the grid before t_end (t_end slightly past the box by round-off): the remainder
            // is credited to the last cell so the lengths still sum to t_end.
            self.done = true;
            return Some((cell, t_in, self.t_end));
        }
        Some((cell, t_in, t_out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::rng::Rng;

    #[test]
    fn dda_lengths_sum_to_segment_and_match_brute_force() {
        let dims = [7u32, 5, 9];
        let hi = DVec3::new(7.0, 5.0, 9.0);
        let mut rng = Rng::new(11, 0, 0, 0);
        for case in 0..2000 {
            let p = DVec3::new(rng.uniform() * 7.0, rng.uniform() * 5.0, rng.uniform() * 9.0);
            let mut d = DVec3::new(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5);
            if case % 7 == 0 {
                d.y = 0.0; // axis-parallel components
            }
            if case % 11 == 0 {
                d = DVec3::NEG_Z;
            }
            let d = d.normalize();
            let Some((_, t_exit)) = box_interval(p, d, hi) else { panic!("inside point misses") };
            let t_end = t_exit * rng.uniform().max(0.05);
            let mut sum = 0.0;
            let mut per = vec![0.0f64; 7 * 5 * 9];
            let mut last = 0.0;
            for (c, t0, t1) in Dda::new(p, d, t_end, 1.0, dims) {
                assert!(t1 >= t0 && (t0 - last).abs() < 1e-12);
                last = t1;
                sum += t1 - t0;
                for a in 0..3 {
                    assert!(c[a] >= 0 && c[a] < dims[a] as i64);
                }
                per[((c[2] * 5 + c[1]) * 7 + c[0]) as usize] += t1 - t0;
            }
            assert!((sum - t_end).abs() < 1e-12 * t_end.max(1.0), "sum {sum} vs {t_end}");
            // Brute force: midpoints of fine steps.
            let steps = 4000;
            let mut brute = vec![0.0f64; 7 * 5 * 9];
            for i in 0..steps {
                let q = p + d * ((i as f64 + 0.5) * t_end / steps as f64);
                let v = [q.x.floor().clamp(0.0, 6.0), q.y.floor().clamp(0.0, 4.0), q.z.floor().clamp(0.0, 8.0)];
                brute[((v[2] * 5.0 + v[1]) * 7.0 + v[0]) as usize] += t_end / steps as f64;
            }
            for (a, b) in per.iter().zip(&brute) {
                assert!((a - b).abs() < 2.5 * t_end / steps as f64 + 1e-12, "{a} vs {b}");
            }
        }
    }

    #[test]
    fn box_interval_cases() {
        let hi = DVec3::new(2.0, 3.0, 4.0);
        let (t0, t1) = box_interval(DVec3::new(-1.0, 1.0, 1.0), DVec3::X, hi).expect("hits");
        assert_eq!((t0, t1), (1.0, 3.0));
        assert!(box_interval(DVec3::new(-1.0, 4.0, 1.0), DVec3::X, hi).is_none());
        assert!(box_interval(DVec3::new(3.0, 1.0, 1.0), DVec3::X, hi).is_none());
        let (t0, t1) = box_interval(DVec3::new(1.0, 1.0, 4.0), DVec3::NEG_Z, hi).expect("on the face");
        assert_eq!((t0, t1), (0.0, 4.0));
    }

    #[test]
    fn brick_bounds() {
        let (g, bad) = Grid::new([20, 3, 2], &|[x, _, _]| {
            if x == 18 {
                5.0
            } else if x == 1 {
                f32::NAN
            } else {
                1.0
            }
        });
        assert_eq!(bad, 3 * 2);
        assert_eq!(g.bricks, [2, 1, 1]);
        assert_eq!(g.brick_max, vec![1.0, 5.0]);
        assert_eq!(g.brick_min, vec![0.0, 1.0]);
    }
}
