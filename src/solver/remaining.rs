//! How far the fluence still is from its converged value, voxel by voxel: the stop rule.
//!
//! The orders of scattering form a series whose terms shrink, eventually, by a common ratio ρ (the
//! spectral radius of one scattering-and-transport step). Once they do, what the orders not yet
//! propagated will add to voxel v is the newest order's fluence there times ρ/(1 − ρ). Dividing by
//! what the voxel will hold then gives the voxel's relative error if the solve stopped now:
//!
//! ```text
//!   e_v = f·φ_k(v) / (Φ(v) + f·φ_k(v)),   f = ρ/(1 − ρ)
//! ```
//!
//! with φ_k the newest order's fluence and Φ the sum so far. The solve stops when the largest e_v
//! over the medium is below the tolerance. This looks where the light arrives last (a dark,
//! dense core keeps growing long after the total power has settled, because its share of each
//! order grows), and it counts the whole tail, not only the next order: at albedo 0.99 the orders
//! still to come add ~100 times the newest one.
//!
//! ρ is measured from the scattered power of the last orders, per channel; while it is still
//! creeping up (see [`super::orders::TailEstimate`]) the far end of its drift is used, so the
//! estimate errs on the side of more orders. A ratio at or above 1 (light still building up) means
//! not converged. Only voxels holding medium count, and of those only the ones whose fluence's
//! magnitude |Φ| is a normal f32 number at least [`DARK`] of the brightest (the others are
//! physically dark: e^{−big}). A cold solve's Φ is never negative; a warm start's can be while its
//! guess is still far from the answer, and such a voxel is measured by |Φ|, never left out (left
//! out, a guess of −1e6 everywhere measured no voxel at all and stopped "converged" after two
//! orders, issue 57).

use serde::Serialize;

/// Voxels whose fluence is below this fraction of the brightest medium voxel are left out.
pub const DARK: f64 = 1e-12;

/// The estimated remaining relative error over the medium's voxels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct RemainingError {
    /// The largest e_v (∞ when the ratio has not fallen below 1 yet).
    pub max: f64,
    /// The root mean square of e_v.
    pub l2: f64,
}

/// Whether a committed fluence's magnitude `total` (|Φ|: see the module docs) counts at all, and
/// toward the brightest, which sets the dark floor.
#[inline]
pub fn counts(total: f64) -> bool {
    total > 0.0 && total.is_finite()
}

/// The dark floor under the brightest counted fluence: voxels below it are left out.
pub fn dark_floor(brightest: f64) -> f64 {
    DARK * brightest
}

/// One unit's share of the remaining error (a brick of the store, a voxel of the twin), taken
/// once the dark floor is known: a pass finds the brightest fluence first, then each unit walks
/// its voxels. The units are merged in unit order ([`UnitTally::merge`]), so the result does not
/// depend on how they were spread over threads, and the GPU's resident mode, whose kernel tallies a
/// brick per invocation in the same walk, gives the same bits (`glsl/remaining.comp`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UnitTally {
    /// Σ e_v² over the counted voxels, in walk order (e_v rounded to f32 first).
    pub sum_sq: f64,
    /// The largest e_v.
    pub max: f64,
    pub count: u64,
}

impl UnitTally {
    /// Counts one medium voxel with committed fluence `total` (an f32 value) and newest-order
    /// fluence `newest`, for tail factor `factor` (= ρ/(1 − ρ), or ∞), above the dark `floor`;
    /// `total` is taken by its magnitude (see the module docs).
    #[inline]
    pub fn add(&mut self, total: f64, newest: f64, factor: f64, floor: f64) {
        let total = total.abs();
        if !counts(total) || total < floor {
            return;
        }
        let e = if factor.is_finite() {
            // |φ_k|: a warm start's residual orders have either sign (cold ones are ≥ 0).
            let add = factor * newest.abs();
            add / (total + add)
        } else {
            f64::INFINITY
        };
        let e = e as f32 as f64;
        self.max = self.max.max(e);
        self.sum_sq += e * e;
        self.count += 1;
    }

    /// Adds the tally of the unit after the ones this one holds (units merge in unit order).
    pub fn merge(&mut self, later: UnitTally) {
        self.max = self.max.max(later.max);
        self.sum_sq += later.sum_sq;
        self.count += later.count;
    }

    /// The remaining error over the units merged into this tally.
    pub fn finish(&self) -> RemainingError {
        let l2 = if self.count > 0 { (self.sum_sq / self.count as f64).sqrt() } else { 0.0 };
        RemainingError { max: self.max, l2 }
    }
}

/// The remaining error over the units' tallies, merged in the order given.
pub fn finish(units: impl IntoIterator<Item = UnitTally>) -> RemainingError {
    let mut all = UnitTally::default();
    for unit in units {
        all.merge(unit);
    }
    all.finish()
}

/// The tail factor ρ/(1 − ρ) for ratio `rho` (∞ unless 0 ≤ ρ < 1).
pub fn tail_factor(rho: f64) -> f64 {
    if (0.0..1.0).contains(&rho) {
        rho / (1.0 - rho)
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk(voxels: &[(f64, f64)], factor: f64) -> UnitTally {
        let brightest = voxels.iter().map(|v| v.0.abs()).filter(|&t| counts(t)).fold(0.0, f64::max);
        let mut t = UnitTally::default();
        for &(total, newest) in voxels {
            t.add(total, newest, factor, dark_floor(brightest));
        }
        t
    }

    #[test]
    fn geometric_series_remaining_is_exact() {
        // A voxel whose orders go 1, ρ, ρ², …: after k orders the remaining share is ρ^k.
        let rho: f64 = 0.9;
        let k = 20;
        let total: f64 = (0..k).map(|i| rho.powi(i)).sum();
        let newest = rho.powi(k - 1);
        let r = finish([walk(&[(total, newest)], tail_factor(rho))]);
        assert!((r.max - rho.powi(k)).abs() < 1e-6, "{} vs {}", r.max, rho.powi(k));
    }

    #[test]
    fn dark_voxels_and_unsettled_ratios() {
        // Dark next to the bright one: left out.
        let voxels = [(1e-20, 1e-20), (1.0, 0.01)];
        assert!((finish([walk(&voxels, 1.0)]).max - 0.01 / 1.01).abs() < 1e-6);
        assert_eq!(finish([walk(&[(0.5, 0.01)], tail_factor(1.0))]).max, f64::INFINITY);
        // Neither zero, NaN nor infinite fluence counts.
        assert_eq!(finish([walk(&[(0.0, 1.0), (f64::NAN, 1.0), (f64::INFINITY, 1.0)], 1.0)]).max, 0.0);
        // A negative total (a warm start's guess still far below the answer) counts by its
        // magnitude: with nothing else counted it is the brightest, and far from converged.
        assert!((finish([walk(&[(-1.0, 1.0)], 1.0)]).max - 0.5).abs() < 1e-6);
    }

    #[test]
    fn units_add_up_in_order() {
        let a = UnitTally { sum_sq: 0.5, max: 0.25, count: 2 };
        let b = UnitTally { sum_sq: 1.5, max: 0.75, count: 6 };
        let r = finish([a, b]);
        assert_eq!((r.max, r.l2), (0.75, 0.5));
        assert_eq!(finish([]), RemainingError { max: 0.0, l2: 0.0 });
    }
}
