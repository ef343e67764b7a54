//! Error metrics of a candidate against a reference, accumulated value by value in f64.

use serde::Serialize;

/// How far the candidate is from the reference over the values compared. A metric whose reference
/// denominator is zero (or that has no values) is `None`; a non-finite candidate value makes every
/// metric NaN (written as `null` in JSON, shown as "NaN" in text).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metrics {
    /// Values compared (voxels or pixels × components).
    pub values: u64,
    /// ‖a − b‖₂ / ‖b‖₂.
    pub relative_l2: Option<f64>,
    /// √(mean (a − b)²).
    pub rmse: Option<f64>,
    /// max |a − b| / |b| over the values with b ≠ 0.
    pub max_relative_error: Option<f64>,
    /// mean(a − b) / mean(b).
    pub mean_bias: Option<f64>,
}

/// Running sums behind [`Metrics`].
#[derive(Clone, Debug, Default)]
pub(crate) struct Accumulator {
    n: u64,
    diff_sq: f64,
    ref_sq: f64,
    diff: f64,
    reference: f64,
    max_rel: Option<f64>,
}

impl Accumulator {
    pub(crate) fn add(&mut self, a: f32, b: f32) {
        let (a, b) = (a as f64, b as f64);
        let d = a - b;
        self.n += 1;
        self.diff_sq += d * d;
        self.ref_sq += b * b;
        self.diff += d;
        self.reference += b;
        if b != 0.0 {
            let r = d.abs() / b.abs();
            // Written so that a NaN replaces the maximum rather than being skipped by `f64::max`.
            self.max_rel = Some(match self.max_rel {
                None => r,
                Some(m) if m.is_nan() || r.is_nan() => f64::NAN,
                Some(m) => m.max(r),
            });
        }
    }

    pub(crate) fn finish(&self) -> Metrics {
        let ratio = |num: f64, den: f64| (den != 0.0).then(|| num / den);
        let n = self.n as f64;
        Metrics {
            values: self.n,
            relative_l2: ratio(self.diff_sq, self.ref_sq).map(f64::sqrt),
            rmse: (self.n > 0).then(|| (self.diff_sq / n).sqrt()),
            max_relative_error: self.max_rel,
            mean_bias: ratio(self.diff, self.reference),
        }
    }
}

/// Metrics of `a` against `b` over every value.
pub(crate) fn metrics(a: &[f32], b: &[f32]) -> Metrics {
    let mut acc = Accumulator::default();
    a.iter().zip(b).for_each(|(&x, &y)| acc.add(x, y));
    acc.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_and_nan_candidates() {
        let b = [1.0f32, 2.0, 4.0];
        let a: Vec<f32> = b.iter().map(|v| v * 1.5).collect();
        let m = metrics(&a, &b);
        assert!((m.relative_l2.unwrap() - 0.5).abs() < 1e-12);
        assert!((m.mean_bias.unwrap() - 0.5).abs() < 1e-12);
        assert!((m.max_relative_error.unwrap() - 0.5).abs() < 1e-12);
        let m = metrics(&[1.0, f32::NAN, 1.0], &b);
        assert!(m.max_relative_error.unwrap().is_nan() && m.relative_l2.unwrap().is_nan());
        let m = metrics(&[1.0], &[0.0]);
        assert_eq!((m.relative_l2, m.max_relative_error, m.mean_bias), (None, None, None));
        assert_eq!(m.rmse, Some(1.0));
    }
}
