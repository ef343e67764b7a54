//! Procedural densities, evaluated per voxel: pure functions of (shape, seed, dims, voxel), so they
//! are deterministic, thread-safe and can be evaluated brick by brick in any order.
//!
//! * [`Shape::Sphere`]: 1 where the voxel centre is within 0.4·min(dims) voxels of the volume
//!   centre, else 0.
//! * [`Shape::Box`]: 1 everywhere.
//! * [`Shape::Cloud`]: a cumulus-like blob: a flat-bottomed body of seeded ellipsoidal puffs,
//!   eroded and grown by 5 octaves of seeded value-noise fBm, clamped to [0, 1]. Everything is
//!   computed in voxel-normalised coordinates (each axis mapped to [0, 1]), so the cloud has the same
//!   shape at any resolution; the density is exactly 0 within 10% of every face of the volume.
//!
//! The noise is a small hash-based value noise (no dependencies): integer lattice values from an
//! integer hash of (x, y, z, octave key), interpolated with a quintic fade.

use super::Shape;

/// Edge of a brick, in voxels.
pub const BRICK_EDGE: u32 = 16;
/// Voxels in a brick (16³).
pub const BRICK_VOXELS: usize = 4096;

/// Density of `voxel` (x, y, z indices) in a `dims` volume of `shape`, in [0, 1]. Voxels outside
/// `dims` have density 0.
pub fn density(shape: Shape, seed: u64, dims: [u32; 3], voxel: [u32; 3]) -> f32 {
    if (0..3).any(|i| voxel[i] >= dims[i]) {
        return 0.0;
    }
    match shape {
        Shape::Sphere => sphere(dims, voxel),
        Shape::Box => 1.0,
        Shape::Cloud => CLOUD_CACHE.with(|cache| {
            let mut cache = cache.borrow_mut();
            match &*cache {
                Some(c) if c.seed == seed => {}
                _ => *cache = Some(Cloud::new(seed)),
            }
            cache.as_ref().map_or(0.0, |c| c.density(dims, voxel))
        }),
    }
}

thread_local! {
    /// The last cloud built on this thread: building one costs about as much as a few hundred
    /// voxels, and callers evaluate millions of voxels of the same seed.
    static CLOUD_CACHE: std::cell::RefCell<Option<Cloud>> = const { std::cell::RefCell::new(None) };
}

/// Fills `out` with the densities of the 16³ brick with brick coordinates `brick` (its first voxel
/// is `brick · 16`), local voxel (x, y, z) at index `x + 16·y + 256·z`. Voxels outside `dims` are 0.
///
/// # Panics
/// If `out.len() != 4096`.
pub fn fill_brick(shape: Shape, seed: u64, dims: [u32; 3], brick: [u32; 3], out: &mut [f32]) {
    assert_eq!(out.len(), BRICK_VOXELS, "fill_brick: a brick holds 16³ = 4096 voxels");
    let cloud = match shape {
        Shape::Cloud => Some(Cloud::new(seed)),
        _ => None,
    };
    let origin = brick.map(|b| u64::from(b) * u64::from(BRICK_EDGE));
    for z in 0..BRICK_EDGE {
        for y in 0..BRICK_EDGE {
            for x in 0..BRICK_EDGE {
                let i = (x + BRICK_EDGE * y + BRICK_EDGE * BRICK_EDGE * z) as usize;
                let g = [origin[0] + u64::from(x), origin[1] + u64::from(y), origin[2] + u64::from(z)];
                if (0..3).any(|a| g[a] >= u64::from(dims[a])) {
                    out[i] = 0.0;
                    continue;
                }
                // In range of dims, so each coordinate fits in u32.
                let v = [g[0] as u32, g[1] as u32, g[2] as u32];
                out[i] = match (&cloud, shape) {
                    (Some(c), _) => c.density(dims, v),
                    (None, Shape::Sphere) => sphere(dims, v),
                    (None, _) => 1.0,
                };
            }
        }
    }
}

fn sphere(dims: [u32; 3], v: [u32; 3]) -> f32 {
    let r = 0.4 * f64::from(dims.iter().copied().min().unwrap_or(0));
    let mut d2 = 0.0;
    for a in 0..3 {
        let d = f64::from(v[a]) + 0.5 - 0.5 * f64::from(dims[a]);
        d2 += d * d;
    }
    if d2 <= r * r {
        1.0
    } else {
        0.0
    }
}

// ---- cloud -------------------------------------------------------------------------------------

const OCTAVES: usize = 5;
const PUFFS: usize = 5;
/// Normalised distance from a face within which the cloud is exactly empty.
const BORDER: f64 = 0.1;
/// Width of the fade-in after the empty border.
const BORDER_FADE: f64 = 0.08;
/// Lattice frequency of the first octave (cells per volume edge).
const BASE_FREQUENCY: f64 = 3.0;
const LACUNARITY: f64 = 2.03;
const GAIN: f64 = 0.55;
/// How far the noise moves the surface, in units of the shape field.
const NOISE_AMPLITUDE: f64 = 0.55;
/// Shape-field units to density: the core saturates at 1 once `s + A·n ≥ 1/SHARPNESS`.
const SHARPNESS: f64 = 2.2;
/// Octaves below this use billow noise (2|v| − 1: rounded bulges, sharp creases), the rest plain
/// value noise (wisps).
const BILLOW_OCTAVES: usize = 3;

/// The seeded parameters of one cloud: per-octave hash keys and lattice offsets, and the puffs.
#[derive(Clone, Debug)]
pub struct Cloud {
    seed: u64,
    keys: [u32; OCTAVES],
    offsets: [[f64; 3]; OCTAVES],
    weights: [f64; OCTAVES],
    /// Weight of the octaves after octave `o` (for early exits).
    remaining: [f64; OCTAVES],
    puffs: [([f64; 3], f64); PUFFS],
    /// Normalised box outside which the shape field is below −NOISE_AMPLITUDE (density 0).
    bounds: [[f64; 2]; 3],
}

impl Cloud {
    pub fn new(seed: u64) -> Cloud {
        let mut rng = SplitMix64(seed ^ 0x6c70_6d5f_636c_6f75);
        let mut keys = [0u32; OCTAVES];
        let mut offsets = [[0.0; 3]; OCTAVES];
        for o in 0..OCTAVES {
            keys[o] = (rng.next() >> 32) as u32;
            offsets[o] = [rng.unit() * 512.0, rng.unit() * 512.0, rng.unit() * 512.0];
        }
        let mut weights = [0.0; OCTAVES];
        let mut amp = 1.0;
        for w in weights.iter_mut() {
            *w = amp;
            amp *= GAIN;
        }
        let total: f64 = weights.iter().sum();
        weights.iter_mut().for_each(|w| *w /= total);
        let mut remaining = [0.0; OCTAVES];
        for o in 0..OCTAVES {
            remaining[o] = weights[o + 1..].iter().sum();
        }
        // Puffs: a ring of bulges around and above the main body, all well inside the border.
        let mut puffs = [([0.0; 3], 0.0); PUFFS];
        let phase = rng.unit() * std::f64::consts::TAU;
        for (i, p) in puffs.iter_mut().enumerate() {
            let angle = phase + std::f64::consts::TAU * (i as f64 + 0.35 * rng.unit()) / PUFFS as f64;
            let dist = 0.06 + 0.13 * rng.unit();
            let centre = [0.5 + dist * angle.cos(), 0.5 + dist * angle.sin(), 0.5 + 0.1 * rng.unit()];
            *p = (centre, 0.13 + 0.07 * rng.unit());
        }
        // Each smooth_max adds at most k/4 above the larger argument; an ellipsoid field 1 − |q| is
        // below −m when |q| > 1 + m. So outside these boxes s + NOISE_AMPLITUDE ≤ 0.
        let margin = 1.0 + NOISE_AMPLITUDE + PUFFS as f64 * SMOOTH_MAX_K / 4.0 + 1e-6;
        let mut bounds = [[f64::INFINITY, f64::NEG_INFINITY]; 3];
        let mut grow = |c: [f64; 3], r: [f64; 3]| {
            for a in 0..3 {
                bounds[a][0] = bounds[a][0].min(c[a] - r[a] * margin);
                bounds[a][1] = bounds[a][1].max(c[a] + r[a] * margin);
            }
        };
        grow(BODY_CENTRE, BODY_RADII);
        for &(c, r) in &puffs {
            grow(c, puff_radii(r));
        }
        bounds[2][0] = bounds[2][0].max(BASE_Z - NOISE_AMPLITUDE / BASE_SLOPE - 1e-6);
        Cloud { seed, keys, offsets, weights, remaining, puffs, bounds }
    }

    /// Density of voxel `v` of a `dims` volume (which must lie inside `dims`), in [0, 1].
    pub fn density(&self, dims: [u32; 3], v: [u32; 3]) -> f32 {
        let p = [0, 1, 2].map(|a| (f64::from(v[a]) + 0.5) / f64::from(dims[a].max(1)));
        self.density_at(p) as f32
    }

    /// Density at normalised position `p` ∈ [0, 1]³ (z up).
    pub fn density_at(&self, p: [f64; 3]) -> f64 {
        let edge = p.iter().map(|&c| c.min(1.0 - c)).fold(f64::INFINITY, f64::min);
        if !(edge > BORDER) {
            return 0.0;
        }
        if (0..3).any(|a| p[a] < self.bounds[a][0] || p[a] > self.bounds[a][1]) {
            return 0.0;
        }
        let border = smoothstep(BORDER, BORDER + BORDER_FADE, edge);
        let s = self.shape(p);
        // Early exits: the normalised fBm lies in [-1, 1], so decide without noise when possible.
        if s + NOISE_AMPLITUDE <= 0.0 {
            return 0.0;
        }
        let mut n = 0.0;
        let mut freq = BASE_FREQUENCY;
        for o in 0..OCTAVES {
            let off = self.offsets[o];
            let v = value_noise(p[0] * freq + off[0], p[1] * freq + off[1], p[2] * freq + off[2], self.keys[o]);
            n += self.weights[o] * if o < BILLOW_OCTAVES { 2.0 * v.abs() - 1.0 } else { v };
            freq *= LACUNARITY;
            let r = self.remaining[o];
            if s + NOISE_AMPLITUDE * (n + r) <= 0.0 {
                return 0.0;
            }
            if SHARPNESS * (s + NOISE_AMPLITUDE * (n - r)) >= 1.0 {
                return border;
            }
        }
        let x = (SHARPNESS * (s + NOISE_AMPLITUDE * n)).clamp(0.0, 1.0);
        // Smoothstep: thin wisps at the edge, a dense core.
        border * x * x * (3.0 - 2.0 * x)
    }

    /// The smooth body: 1 at puff centres, 0 on the surface, negative outside; cut flat below.
    fn shape(&self, p: [f64; 3]) -> f64 {
        // Main body: a flattened ellipsoid.
        let mut s = ellipsoid(p, BODY_CENTRE, BODY_RADII);
        for &(c, r) in &self.puffs {
            s = smooth_max(s, ellipsoid(p, c, puff_radii(r)), SMOOTH_MAX_K);
        }
        // Flat base, slightly above the body's bottom.
        s.min((p[2] - BASE_Z) * BASE_SLOPE)
    }
}

const BODY_CENTRE: [f64; 3] = [0.5, 0.5, 0.44];
const BODY_RADII: [f64; 3] = [0.3, 0.3, 0.2];
const SMOOTH_MAX_K: f64 = 0.08;
const BASE_Z: f64 = 0.3;
const BASE_SLOPE: f64 = 5.0;

fn puff_radii(r: f64) -> [f64; 3] {
    [r, r, r * 0.9]
}

fn ellipsoid(p: [f64; 3], c: [f64; 3], r: [f64; 3]) -> f64 {
    let dx = (p[0] - c[0]) / r[0];
    let dy = (p[1] - c[1]) / r[1];
    let dz = (p[2] - c[2]) / r[2];
    1.0 - (dx * dx + dy * dy + dz * dz).sqrt()
}

/// Polynomial smooth maximum (blends bulges into each other instead of creasing).
fn smooth_max(a: f64, b: f64, k: f64) -> f64 {
    let h = (0.5 + 0.5 * (a - b) / k).clamp(0.0, 1.0);
    b + (a - b) * h + k * h * (1.0 - h)
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in [-1, 1]: hashed lattice values, trilinear with quintic fade.
fn value_noise(x: f64, y: f64, z: f64, key: u32) -> f64 {
    let (fx, fy, fz) = (x.floor(), y.floor(), z.floor());
    let (ix, iy, iz) = (fx as i32, fy as i32, fz as i32);
    let (u, v, w) = (fade(x - fx), fade(y - fy), fade(z - fz));
    let l = |dx: i32, dy: i32, dz: i32| lattice(ix.wrapping_add(dx), iy.wrapping_add(dy), iz.wrapping_add(dz), key);
    let x00 = lerp(l(0, 0, 0), l(1, 0, 0), u);
    let x10 = lerp(l(0, 1, 0), l(1, 1, 0), u);
    let x01 = lerp(l(0, 0, 1), l(1, 0, 1), u);
    let x11 = lerp(l(0, 1, 1), l(1, 1, 1), u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w)
}

fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

/// Lattice value in [-1, 1] from an integer hash of the cell and the octave key.
fn lattice(x: i32, y: i32, z: i32, key: u32) -> f64 {
    let mut h = key
        ^ (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^= h >> 16;
    f64::from(h) * (2.0 / f64::from(u32::MAX)) - 1.0
}

struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_in_range_and_continuous() {
        let mut prev = value_noise(0.0, 0.3, 0.7, 7);
        for i in 1..2000 {
            let x = i as f64 * 0.01;
            let n = value_noise(x, 0.3, 0.7, 7);
            assert!((-1.0..=1.0).contains(&n));
            assert!((n - prev).abs() < 0.1, "jump at {x}");
            prev = n;
        }
    }

    #[test]
    fn out_of_dims_is_zero() {
        assert_eq!(density(Shape::Box, 1, [4, 4, 4], [4, 0, 0]), 0.0);
        assert_eq!(density(Shape::Box, 1, [4, 4, 4], [3, 3, 3]), 1.0);
    }

    #[test]
    fn brick_matches_voxels() {
        let dims = [20, 33, 18];
        let mut out = vec![0.0; BRICK_VOXELS];
        for shape in [Shape::Sphere, Shape::Box, Shape::Cloud] {
            fill_brick(shape, 9, dims, [1, 1, 0], &mut out);
            for z in 0..16 {
                for y in 0..16 {
                    for x in 0..16 {
                        let v = [16 + x, 16 + y, z];
                        assert_eq!(out[(x + 16 * y + 256 * z) as usize], density(shape, 9, dims, v));
                    }
                }
            }
        }
    }

    #[test]
    fn cloud_values_in_unit_interval() {
        let c = Cloud::new(3);
        for i in 0..20_000u32 {
            let v = [i % 41, (i / 41) % 37, i % 29];
            let d = c.density([41, 37, 29], v);
            assert!((0.0..=1.0).contains(&d));
        }
    }
}
