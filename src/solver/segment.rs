//! The exact solution along one voxel segment with constant coefficients.
//!
//! With optical depth x = σt·s over a segment of length s, incoming radiance L and a constant source
//! J (radiance per unit length):
//!
//! ```text
//!   L_out      = L·e^{−x} + J·s·E1(x)
//!   (1/s)∫L ds = L·E1(x)  + J·s·E2(x)          (the segment-average radiance, L̄)
//!   E1(x) = (1 − e^{−x})/x,   E2(x) = (1 − E1(x))/x = (x − 1 + e^{−x})/x²
//! ```
//!
//! Both are evaluated without cancellation as x → 0 (E1 → 1, E2 → ½) and without overflow as x → ∞.
//! σt·s·L̄ is exactly what the ray loses to extinction in the segment, so depositing L̄ conserves
//! energy to round-off. The GLSL twin is `seg_e1`/`seg_e2` in `glsl/common.glsl` (checked by `glsl/segment_test.comp`): keep the two in sync.

/// (1 − e^{−x})/x.
pub fn e1(x: f64) -> f64 {
    if x < 1e-3 {
        // Series: 1 − x/2 + x²/6 − x³/24.
        1.0 - x * (0.5 - x * (1.0 / 6.0 - x / 24.0))
    } else {
        -(-x).exp_m1() / x
    }
}

/// (x − 1 + e^{−x})/x².
pub fn e2(x: f64) -> f64 {
    if x < 1e-2 {
        // Series: Σ (−x)^n / (n+2)!, to the x⁴ term.
        0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0 - x / 720.0)))
    } else {
        (x + (-x).exp_m1()) / (x * x)
    }
}

/// One segment: returns (L_out, L̄) for incoming radiance `l`, source `j`, extinction `sigma_t` and
/// length `s`.
pub fn segment(l: f64, j: f64, sigma_t: f64, s: f64) -> (f64, f64) {
    let x = sigma_t * s;
    let a = e1(x);
    ((-x).exp() * l + j * s * a, l * a + j * s * e2(x))
}

/// (1 − (1 + x)·e^{−x})/x²: ∫₀¹ v·e^{−x·v} dv.
pub fn g1(x: f64) -> f64 {
    if x < 0.1 {
        // Σ (−x)^m (m + 1)/(m + 2)!
        let mut sum = 0.0;
        let mut term = 1.0; // (−x)^m / (m + 2)!, starting at m = 0: 1/2
        let mut fact = 2.0;
        for m in 0..10 {
            if m > 0 {
                term *= -x;
                fact *= (m + 2) as f64;
            }
            sum += term * (m + 1) as f64 / fact;
        }
        sum
    } else {
        (1.0 + (-x).exp() * -(1.0 + x)) / (x * x)
    }
}

/// The linear part of a segment: with a source J(u) = J0 + J1·(u − ½) along the segment (u = s/S),
/// returns (F, H) with L_out = …+ J1·S·F(x) and L̄ = … + J1·S·H(x): F(x) = E1/2 − G1 and
/// H(x) = −F(x)/x, evaluated by series below x = 0.1.
pub fn linear_parts(x: f64) -> (f64, f64) {
    if x < 0.1 {
        // F/x = Σ_k (−x)^k (k + 1) / (2 (k + 3)!)
        let mut sum = 0.0;
        let mut pow = 1.0;
        let mut fact = 6.0;
        for k in 0..10 {
            if k > 0 {
                pow *= -x;
                fact *= (k + 3) as f64;
            }
            sum += pow * (k + 1) as f64 / (2.0 * fact);
        }
        (sum * x, -sum)
    } else {
        let f = 0.5 * e1(x) - g1(x);
        (f, -f / x)
    }
}

/// One segment with a source varying linearly along it, J(u) = j0 + j1·(u − ½): (L_out, L̄).
/// The source integrates to j0·s whatever j1, so the deposit balances as in [`segment`].
pub fn segment_linear(l: f64, j0: f64, j1: f64, sigma_t: f64, s: f64) -> (f64, f64) {
    let x = sigma_t * s;
    let a = e1(x);
    let (f, h) = linear_parts(x);
    ((-x).exp() * l + j0 * s * a + j1 * s * f, l * a + j0 * s * e2(x) + j1 * s * h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_direct_formula_away_from_zero_and_limits() {
        for x in [0.05_f64, 0.3, 1.0, 7.0, 40.0] {
            let direct_e1 = (1.0 - (-x).exp()) / x;
            let direct_e2 = (x - 1.0 + (-x).exp()) / (x * x);
            assert!((e1(x) - direct_e1).abs() < 1e-14);
            assert!((e2(x) - direct_e2).abs() < 1e-13);
        }
        assert_eq!(e1(0.0), 1.0);
        assert_eq!(e2(0.0), 0.5);
        assert!((e1(1e4) - 1e-4).abs() < 1e-18);
        assert!(e2(1e30).is_finite() && e1(1e300).is_finite());
        // Continuity across the series/closed-form switch points.
        for x in [1e-3_f64, 1e-2] {
            assert!((e1(x * (1.0 - 1e-12)) - e1(x)).abs() < 1e-13);
            assert!((e2(x * (1.0 - 1e-12)) - e2(x)).abs() < 1e-13);
        }
    }

    #[test]
    fn linear_source_segment_matches_quadrature_and_balances() {
        for (l, j0, j1, st, s) in [
            (1.0, 0.3, 0.2, 0.7, 1.3),
            (0.2, 0.5, -0.4, 3.0, 0.4),
            (2.0, 1.0, 0.5, 1e-5, 1.0),
            (1.0, 2.0, 1.0, 30.0, 1.0),
            (0.0, 1.0, 1.0, 0.09, 1.0),
            (0.0, 1.0, 1.0, 0.11, 1.0),
        ] {
            // Midpoint quadrature of dL/ds = −σ L + J(s).
            let steps = 200_000;
            let ds = s / steps as f64;
            let (mut lq, mut integral) = (l, 0.0);
            for i in 0..steps {
                let u = (i as f64 + 0.5) / steps as f64;
                let j = j0 + j1 * (u - 0.5);
                // Exact step for constant J over ds.
                let (out, avg) = segment(lq, j, st, ds);
                integral += avg * ds;
                lq = out;
            }
            let (out, avg) = segment_linear(l, j0, j1, st, s);
            assert!((out - lq).abs() < 1e-7 * (1.0 + lq.abs()), "{out} vs {lq}");
            assert!((avg - integral / s).abs() < 1e-7 * (1.0 + avg.abs()), "{avg} vs {}", integral / s);
            let balance = l + j0 * s - out - st * s * avg;
            assert!(balance.abs() < 1e-12 * (l + j0 * s), "{balance}");
        }
    }

    #[test]
    fn deposit_balances_extinction() {
        // L_in + J·s = L_out + σt·s·L̄ (energy in a segment, per unit cross-section and solid angle).
        for (l, j, st, s) in [(1.0, 0.0, 0.7, 1.3), (0.2, 0.5, 3.0, 0.4), (2.0, 1.0, 1e-9, 1.0), (1.0, 2.0, 1e4, 1.0)] {
            let (out, avg) = segment(l, j, st, s);
            let balance = l + j * s - out - st * s * avg;
            assert!(balance.abs() < 1e-12 * (l + j * s), "{balance}");
        }
    }
}
