//! The voxel-to-voxel kernel of uncollided emission: the mean over a source voxel and a target
//! voxel of `T/r²` (voxel units), what one emitting voxel of source `J` gives a target voxel's
//! fluence, `φ = J·h·G` ([module docs](super)).
//!
//! **Near pairs** (offset c with every |c_i| ≤ [`NEAR`]): the double mean over two unit cubes is a
//! single integral against the cubes' autocorrelation, the tent `Λ(u) = Π max(0, 1 − |u_i|)`:
//!
//! `K(c, σ) = ∫ Λ(w − c)·e^{−σ|w|}/|w|² dw = ∫_{S²} dΩ ∫_0^∞ Λ(rω − c)·e^{−σr} dr`,
//!
//! and in polar coordinates about w = 0 the 1/r² singularity is gone: along each direction the
//! integrand is a piecewise cubic times an exponential, integrated exactly enough by Gauss–Legendre
//! between its kinks; the directions are a cube-face grid ([`DIRECTIONS_PER_FACE`]² per face). It
//! is tabulated once per solve for the 10 offset classes (sorted |c_i|) over σ (per voxel edge,
//! nodes uniform in ln(1 + σ) up to [`SIGMA_MAX`]) and interpolated in ln K. In a heterogeneous
//! medium σ is the pair's mean, the optical depth of the centre-to-centre segment over its length
//! (for c = 0 the voxel's own σ): exact in a uniform medium.
//!
//! **Far pairs** in a uniform medium ([`far_factor`], the tests' check of the table and of the
//! conservation; the solver's far pairs sample the source voxel instead, `clusters`): the centre
//! value `T/r²` with the cubes' averaging taken to second order, the
//! exponential's along the segment exactly for a linear path length (`Π_i sinhc(σ ω_i/2)` per end,
//! σ that end's own) and the geometric part by Taylor, `1 + (4/r² + (4σ_s + 4σ_v − 4σ̄)/r)/24`.
//! Against the exact double mean in a uniform medium (6-D Gauss–Legendre): at |c| = 3 and σ·h ≤ 1
//! within 0.3 % (the centre value alone: −1.8 % at σ·h = 0, −14 % at σ·h = 1), at σ·h = 3 within 5 %
//! of a value that is e⁻⁹ of the near field's (`tests`).

use rayon::prelude::*;

/// Offsets with every |c_i| ≤ NEAR are integrated exactly ([`NearTable`]).
pub const NEAR: i64 = 2;
/// Directions per cube face and axis of the near kernel's coarser quadrature (the finer has twice
/// as many; see [`NearTable::new`]).
pub const DIRECTIONS_PER_FACE: usize = 16;
/// σ (per voxel edge) of the last node of the near table; above it the last node's kernel is
/// scaled by e^{−(σ − SIGMA_MAX)·|c|} (beyond e^{−40} of the light one voxel on: nothing).
pub const SIGMA_MAX: f64 = 40.0;
/// Nodes of the near table over σ.
pub const SIGMA_NODES: usize = 40;

/// Gauss–Legendre nodes and weights on [0, 1], 6 points.
const GL6: [(f64, f64); 6] = [
    (0.033_765_242_898_423_99, 0.085_662_246_189_585_17),
    (0.169_395_306_766_867_74, 0.180_380_786_524_069_3),
    (0.380_690_406_958_401_56, 0.233_956_967_286_345_52),
    (0.619_309_593_041_598_4, 0.233_956_967_286_345_52),
    (0.830_604_693_233_132_3, 0.180_380_786_524_069_3),
    (0.966_234_757_101_576, 0.085_662_246_189_585_17),
];

/// `K(c, σ)` by quadrature (module docs): `dirs` the unit directions with their solid angles.
pub fn near_kernel(c: [f64; 3], sigma: f64, dirs: &[([f64; 3], f64)]) -> f64 {
    let mut total = 0.0;
    let mut breaks: Vec<f64> = Vec::with_capacity(12);
    for &(w, omega) in dirs {
        // Where each factor 1 − |r·w_i − c_i| is positive, and its kink.
        let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
        breaks.clear();
        let mut empty = false;
        for i in 0..3 {
            if w[i] == 0.0 {
                if c[i].abs() >= 1.0 {
                    empty = true;
                }
                continue;
            }
            let (a, b) = ((c[i] - 1.0) / w[i], (c[i] + 1.0) / w[i]);
            lo = lo.max(a.min(b));
            hi = hi.min(a.max(b));
            breaks.push(c[i] / w[i]);
        }
        // Past 40 mean free paths from where it starts the integrand is e^{−40} of its start.
        if sigma > 0.0 {
            hi = hi.min(lo + 40.0 / sigma);
        }
        if empty || !(lo < hi) {
            continue;
        }
        breaks.retain(|&k| k > lo && k < hi);
        breaks.push(lo);
        breaks.push(hi);
        breaks.sort_by(f64::total_cmp);
        let tent = |r: f64| (0..3).map(|i| (1.0 - (r * w[i] - c[i]).abs()).max(0.0)).product::<f64>();
        let mut line = 0.0;
        for pair in breaks.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            // Pieces no longer than two mean free paths, so the exponential is resolved.
            let pieces = (0.5 * (b - a) * sigma).ceil().clamp(1.0, 32.0) as usize;
            let step = (b - a) / pieces as f64;
            for p in 0..pieces {
                let a = a + p as f64 * step;
                for &(x, wt) in &GL6 {
                    let r = a + x * step;
                    line += wt * step * tent(r) * (-sigma * r).exp();
                }
            }
        }
        total += omega * line;
    }
    total
}

/// Unit directions at the centres of an n×n grid on each cube face, with their solid angles
/// (exact per cell: the cell's four corners' arctangent formula), summing to 4π.
pub fn cube_directions(n: usize) -> Vec<([f64; 3], f64)> {
    // Solid angle of the face rectangle [0, u] × [0, v] seen from the cube's centre (face at 1).
    let corner = |u: f64, v: f64| (u * v / (1.0 + u * u + v * v).sqrt()).atan();
    let mut out = Vec::with_capacity(6 * n * n);
    for f in 0..6 {
        let axis = f / 2;
        let sign = if f % 2 == 1 { 1.0 } else { -1.0 };
        for j in 0..n {
            for i in 0..n {
                let at = |k: usize| -1.0 + 2.0 * k as f64 / n as f64;
                let (u0, u1, v0, v1) = (at(i), at(i + 1), at(j), at(j + 1));
                let omega = corner(u1, v1) - corner(u0, v1) - corner(u1, v0) + corner(u0, v0);
                let (u, v) = (0.5 * (u0 + u1), 0.5 * (v0 + v1));
                let mut d = [0.0; 3];
                d[axis] = sign;
                d[(axis + 1) % 3] = u;
                d[(axis + 2) % 3] = v;
                let len = (1.0 + u * u + v * v).sqrt();
                out.push((d.map(|x| x / len), omega));
            }
        }
    }
    out
}

/// The near kernel tabulated per offset class and σ node ([module docs](self)).
pub struct NearTable {
    /// `[class][node]`: ln K.
    ln_k: Vec<[f64; SIGMA_NODES]>,
}

impl Default for NearTable {
    fn default() -> Self {
        NearTable::new()
    }
}

/// The class of an offset with every |c_i| ≤ NEAR: its sorted magnitudes, as an index.
fn class_of(c: [i64; 3]) -> usize {
    let mut m = c.map(|x| x.unsigned_abs() as usize);
    m.sort_unstable();
    let n = NEAR as usize + 1;
    (m[0] * n + m[1]) * n + m[2]
}

/// σ at node `j`.
fn node_sigma(j: usize) -> f64 {
    ((SIGMA_MAX + 1.0).ln() * j as f64 / (SIGMA_NODES - 1) as f64).exp() - 1.0
}

impl NearTable {
    /// Tabulates every class (about a second on two cores; computed only when a solve traces).
    pub fn new() -> NearTable {
        let n = NEAR as usize + 1;
        // The midpoint rule over the directions is second order (the integrand has kinks where
        // the tents do): Richardson's extrapolation of n and 2n per face axis takes the K of
        // (2,0,0) at σ = 1 from 0.5 % (n = 24) to 1e-5.
        let coarse = cube_directions(DIRECTIONS_PER_FACE);
        let fine = cube_directions(2 * DIRECTIONS_PER_FACE);
        let extrapolated =
            |c: [f64; 3], sigma: f64| (4.0 * near_kernel(c, sigma, &fine) - near_kernel(c, sigma, &coarse)) / 3.0;
        let classes = n * n * n;
        let ln_k = (0..classes)
            .into_par_iter()
            .map(|k| {
                let c = [(k / (n * n)) as f64, (k / n % n) as f64, (k % n) as f64];
                let sorted = c[0] <= c[1] && c[1] <= c[2];
                std::array::from_fn(|j| if sorted { extrapolated(c, node_sigma(j)).ln() } else { 0.0 })
            })
            .collect();
        NearTable { ln_k }
    }

    /// ln K by offset class (`(m₀·(NEAR+1) + m₁)·(NEAR+1) + m₂` of the sorted magnitudes; the
    /// unsorted classes hold zeros) and σ node, as [`NearTable::kernel`] reads them (the device
    /// kernel's table, `super::gpu`).
    pub fn ln_values(&self) -> &[[f64; SIGMA_NODES]] {
        &self.ln_k
    }

    /// `K(c, σ)` for an offset with every |c_i| ≤ NEAR and σ ≥ 0 per voxel edge.
    pub fn kernel(&self, c: [i64; 3], sigma: f64) -> f64 {
        let row = &self.ln_k[class_of(c)];
        let sigma = sigma.max(0.0);
        if sigma >= SIGMA_MAX {
            let r = ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) as f64).sqrt();
            return (row[SIGMA_NODES - 1] - (sigma - SIGMA_MAX) * r).exp();
        }
        // Quadratic in ln K through the three nodes nearest x.
        let x = (sigma + 1.0).ln() / (SIGMA_MAX + 1.0).ln() * (SIGMA_NODES - 1) as f64;
        let j = (x.round() as usize).clamp(1, SIGMA_NODES - 2);
        let t = x - j as f64;
        (row[j] + 0.5 * t * (row[j + 1] - row[j - 1]) + 0.5 * t * t * (row[j + 1] - 2.0 * row[j] + row[j - 1])).exp()
    }
}

/// `sinh(x)/x`.
pub fn sinhc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 + x * x / 6.0
    } else {
        x.sinh() / x
    }
}

/// The far pair's factor on the centre value `T/r²` ([module docs](self)): offset `c` (voxel
/// units, |c| > 0), σ per voxel edge at the source end, the target end and the segment's mean.
pub fn far_factor(c: [f64; 3], sigma_s: f64, sigma_v: f64, sigma_mean: f64) -> f64 {
    let r = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let mut ends = 1.0;
    for ci in c {
        let w = ci / r;
        ends *= sinhc(0.5 * sigma_s * w) * sinhc(0.5 * sigma_v * w);
    }
    ends * (1.0 + (4.0 / (r * r) + (4.0 * (sigma_s + sigma_v) - 4.0 * sigma_mean) / r) / 24.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact double mean over two unit cubes of e^{−σr}/r² by 6-D Gauss–Legendre (offsets of
    /// two or more along some axis: no singularity).
    fn double_mean(c: [f64; 3], sigma: f64) -> f64 {
        let pts: Vec<(f64, f64)> = GL6.iter().map(|&(x, w)| (x - 0.5, w)).collect();
        let mut cube: Vec<([f64; 3], f64)> = Vec::new();
        for &(x, wx) in &pts {
            for &(y, wy) in &pts {
                for &(z, wz) in &pts {
                    cube.push(([x, y, z], wx * wy * wz));
                }
            }
        }
        let mut sum = 0.0;
        for (a, wa) in &cube {
            for (b, wb) in &cube {
                let d = [0, 1, 2].map(|i| c[i] + a[i] - b[i]);
                let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                sum += wa * wb * (-sigma * r2.sqrt()).exp() / r2;
            }
        }
        sum
    }

    #[test]
    fn the_cube_directions_cover_the_sphere() {
        let dirs = cube_directions(8);
        let total: f64 = dirs.iter().map(|d| d.1).sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-12, "{total}");
    }

    #[test]
    fn near_kernels_match_the_double_mean_and_far_factors_join_them() {
        let table = NearTable::new();
        for (c, sigma) in [([2, 1, 0], 0.0), ([2, 2, 1], 0.2), ([2, 0, 0], 1.0), ([2, 2, 2], 0.5)] {
            let exact = double_mean(c.map(|x| x as f64), sigma);
            let got = table.kernel(c, sigma);
            assert!((got / exact - 1.0).abs() < 5e-4, "{c:?} σ {sigma}: {got} vs {exact}");
        }
        for (c, sigma, tol) in
            [([3.0, 0.0, 0.0], 0.2, 2e-3), ([3.0, 1.0, 0.0], 1.0, 4e-3), ([5.0, 0.0, 0.0], 3.0, 0.05)]
        {
            let exact = double_mean(c, sigma);
            let r = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
            let got = (-sigma * r.sqrt()).exp() / r * far_factor(c, sigma, sigma, sigma);
            assert!((got / exact - 1.0).abs() < tol, "{c:?} σ {sigma}: {got} vs {exact}");
        }
    }

    /// Σ over every offset of K(c, σ) is ∫ e^{−σr}/r² dw = 4π/σ (the tents tile space): in an
    /// infinite uniform absorber the emitting voxel's light is all absorbed, σ·Σφ = emitted.
    #[test]
    fn the_kernels_of_every_offset_conserve_energy() {
        let table = NearTable::new();
        for sigma in [0.5, 1.5] {
            let mut sum = 0.0;
            let n = (40.0 / sigma) as i64;
            for z in -n..=n {
                for y in -n..=n {
                    for x in -n..=n {
                        let c = [x, y, z];
                        sum += if c.iter().all(|v| v.abs() <= NEAR) {
                            table.kernel(c, sigma)
                        } else {
                            let f = c.map(|v| v as f64);
                            let r2 = f[0] * f[0] + f[1] * f[1] + f[2] * f[2];
                            (-sigma * r2.sqrt()).exp() / r2 * far_factor(f, sigma, sigma, sigma)
                        };
                    }
                }
            }
            let want = 4.0 * std::f64::consts::PI / sigma;
            assert!((sum / want - 1.0).abs() < 1e-3, "σ {sigma}: {sum} vs {want}");
        }
    }
}
