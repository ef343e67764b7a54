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
//! energy to round-off. The GLSL twin is `glsl/segment.glsl`: keep the two in sync.

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
    fn deposit_balances_extinction() {
        // L_in + J·s = L_out + σt·s·L̄ (energy in a segment, per unit cross-section and solid angle).
        for (l, j, st, s) in [(1.0, 0.0, 0.7, 1.3), (0.2, 0.5, 3.0, 0.4), (2.0, 1.0, 1e-9, 1.0), (1.0, 2.0, 1e4, 1.0)] {
            let (out, avg) = segment(l, j, st, s);
            let balance = l + j * s - out - st * s * avg;
            assert!(balance.abs() < 1e-12 * (l + j * s), "{balance}");
        }
    }
}
