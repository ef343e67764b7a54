//! Henyey–Greenstein phase function (evaluation and inversion sampling) and direction helpers,
//! written from the textbook formulas independently of `crate::quadrature::phase`.

use glam::DVec3;
use std::f64::consts::PI;

/// Below this |g| the medium is sampled as isotropic (the mean-cosine bias is below 1e-6).
const ISOTROPIC_G: f64 = 1e-6;

/// HG phase function value for the cosine `mu` between the propagation directions of the incident
/// and the scattered light; normalised to 1 over the sphere (unit 1/sr).
#[inline]
pub fn hg_eval(g: f64, mu: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * mu;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// Two unit vectors completing `n` (unit) to a right-handed orthonormal basis (Duff et al. 2017).
#[inline]
pub fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let s = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    (t, s)
}

/// The direction with cosine `cos_t` to `axis` (unit) and azimuth `phi` about it.
#[inline]
pub fn around(axis: DVec3, cos_t: f64, phi: f64) -> DVec3 {
    let cos_t = cos_t.clamp(-1.0, 1.0);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (t, s) = basis(axis);
    (t * (sin_t * phi.cos()) + s * (sin_t * phi.sin()) + axis * cos_t).normalize()
}

/// Sample a scattered direction from HG with anisotropy `g`, given the propagation direction
/// `incoming` (unit) and two uniforms in [0, 1). The cosine between `incoming` and the result is
/// distributed with density 2π·p_HG(μ) on [−1, 1] (mean g); the azimuth is uniform.
pub fn sample_hg(g: f64, u1: f64, u2: f64, incoming: DVec3) -> DVec3 {
    let mu = if g.abs() < ISOTROPIC_G {
        1.0 - 2.0 * u1
    } else {
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        (1.0 + g * g - s * s) / (2.0 * g)
    };
    around(incoming, mu, 2.0 * PI * u2)
}

/// Uniform direction on the unit sphere.
#[inline]
pub fn uniform_sphere(u1: f64, u2: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Cosine-weighted direction in the hemisphere around `n` (pdf cosθ/π).
#[inline]
pub fn cosine_hemisphere(n: DVec3, u1: f64, u2: f64) -> DVec3 {
    around(n, u1.sqrt(), 2.0 * PI * u2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal() {
        for n in [DVec3::X, DVec3::NEG_Z, DVec3::Z, DVec3::new(0.3, -0.4, 0.5).normalize()] {
            let (t, s) = basis(n);
            assert!((t.length() - 1.0).abs() < 1e-12 && (s.length() - 1.0).abs() < 1e-12);
            assert!(t.dot(s).abs() < 1e-12 && t.dot(n).abs() < 1e-12 && s.dot(n).abs() < 1e-12);
        }
    }

    #[test]
    fn hg_normalised() {
        for g in [-0.9, 0.0, 0.5, 0.95] {
            // ∫ p dω = 2π ∫_{-1}^{1} p(μ) dμ, midpoint rule.
            let n = 200_000;
            let sum: f64 =
                (0..n).map(|i| hg_eval(g, -1.0 + (i as f64 + 0.5) * 2.0 / n as f64)).sum::<f64>() * 2.0 / n as f64;
            assert!((2.0 * PI * sum - 1.0).abs() < 1e-4, "g {g}: {}", 2.0 * PI * sum);
        }
    }
}
