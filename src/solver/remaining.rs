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
//! not converged. Only voxels holding medium count, and of those only the ones whose fluence is a
//! normal f32 number at least [`DARK`] of the brightest (the others are physically dark: e^{−big}).

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

/// Accumulates e_v over voxels; the brightest fluence seen sets the dark floor at the end.
#[derive(Clone, Debug, Default)]
pub struct RemainingTally {
    /// (Φ, e) of each counted voxel and channel, kept to apply the dark floor afterwards. Only the
    /// pairs above a running floor are kept, so memory stays small for large volumes: see `add`.
    pairs: Vec<(f32, f32)>,
    brightest: f64,
    /// Prune when `pairs` reaches this length: at least [`PRUNE_AT`], and twice what the last
    /// prune kept, so that a volume whose voxels are all bright (nothing to prune) costs one prune
    /// per doubling, not one per voxel.
    prune_at: usize,
}

/// Pairs kept before the first prune.
const PRUNE_AT: usize = 1 << 22;

impl RemainingTally {
    /// Counts one medium voxel with committed fluence `total` and newest-order fluence `newest`,
    /// for tail factor `factor` (= ρ/(1 − ρ), or ∞).
    #[inline]
    pub fn add(&mut self, total: f64, newest: f64, factor: f64) {
        if !(total > 0.0) || !total.is_finite() {
            return;
        }
        if total > self.brightest {
            self.brightest = total;
        }
        // Decided on the value as kept (f32), as `finish` decides: a voxel is dropped here only if
        // it would be dropped there, so tallies merged in any grouping finish alike.
        if ((total as f32) as f64) < DARK * self.brightest {
            return;
        }
        let e = if factor.is_finite() {
            // |φ_k|: a warm start's residual orders have either sign (cold ones are ≥ 0).
            let add = factor * newest.abs();
            add / (total + add)
        } else {
            f64::INFINITY
        };
        self.pairs.push((total as f32, e as f32));
        // Bound the memory: drop pairs that have fallen below the floor since they were kept.
        if self.pairs.len() >= self.prune_at.max(PRUNE_AT) {
            self.prune();
        }
    }

    /// Drops the kept pairs below the current dark floor (they would be dropped by `finish`).
    fn prune(&mut self) {
        let floor = DARK * self.brightest;
        self.pairs.retain(|&(t, _)| t as f64 >= floor);
        self.prune_at = 2 * self.pairs.len();
    }

    /// Appends the voxels `later` counted (voxels that come after this tally's, in the order a
    /// single walk would meet them). The result finishes to bitwise what one walk over both would
    /// give: a voxel either drops below the final dark floor in both or is kept in both, and kept
    /// pairs stay in walk order.
    pub fn merge(&mut self, later: RemainingTally) {
        self.brightest = self.brightest.max(later.brightest);
        let floor = DARK * self.brightest;
        self.pairs.extend(later.pairs.into_iter().filter(|&(t, _)| t as f64 >= floor));
        if self.pairs.len() >= self.prune_at.max(PRUNE_AT) {
            self.prune();
        }
    }

    /// The remaining error over the counted voxels.
    pub fn finish(&self) -> RemainingError {
        let floor = DARK * self.brightest;
        let (mut max, mut sum, mut n) = (0.0f64, 0.0f64, 0usize);
        for &(t, e) in &self.pairs {
            if (t as f64) < floor {
                continue;
            }
            let e = e as f64;
            max = max.max(e);
            sum += e * e;
            n += 1;
        }
        RemainingError { max, l2: if n > 0 { (sum / n as f64).sqrt() } else { 0.0 } }
    }
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

    #[test]
    fn geometric_series_remaining_is_exact() {
        // A voxel whose orders go 1, ρ, ρ², …: after k orders the remaining share is ρ^k.
        let rho: f64 = 0.9;
        let k = 20;
        let total: f64 = (0..k).map(|i| rho.powi(i)).sum();
        let newest = rho.powi(k - 1);
        let mut t = RemainingTally::default();
        t.add(total, newest, tail_factor(rho));
        let r = t.finish();
        assert!((r.max - rho.powi(k)).abs() < 1e-6, "{} vs {}", r.max, rho.powi(k));
    }

    #[test]
    fn dark_voxels_and_unsettled_ratios() {
        let mut t = RemainingTally::default();
        t.add(1e-20, 1e-20, 1.0); // dark next to the bright one: left out
        t.add(1.0, 0.01, 1.0);
        assert!((t.finish().max - 0.01 / 1.01).abs() < 1e-6);
        t.add(0.5, 0.01, tail_factor(1.0));
        assert_eq!(t.finish().max, f64::INFINITY);
    }

    #[test]
    fn merged_tallies_finish_as_one_walk() {
        // Fluences over many decades (so the dark floor drops some voxels, early in one walk and
        // late in a grouped one), in any grouping: the same bits.
        let voxels: Vec<(f64, f64)> = (0..5000u64)
            .map(|i| {
                let x = (i.wrapping_mul(2654435761) % 1000) as f64 / 1000.0;
                (10f64.powf(-16.0 * x) * (1.0 + (i % 7) as f64), 10f64.powf(-3.0 * x) * 0.01)
            })
            .collect();
        let mut one = RemainingTally::default();
        for &(t, k) in &voxels {
            one.add(t, k, 0.9);
        }
        for group in [1, 3, 64, 999] {
            let mut merged = RemainingTally::default();
            for chunk in voxels.chunks(group) {
                let mut part = RemainingTally::default();
                for &(t, k) in chunk {
                    part.add(t, k, 0.9);
                }
                merged.merge(part);
            }
            let (a, b) = (one.finish(), merged.finish());
            assert!(a.max.to_bits() == b.max.to_bits() && a.l2.to_bits() == b.l2.to_bits(), "group {group}");
        }
    }

    #[test]
    fn bright_volumes_prune_once_per_doubling() {
        // Every voxel bright: nothing to prune, so the prune point doubles instead of every add
        // scanning all pairs again (a 256³ RGB order spent 40 s there).
        let mut t = RemainingTally::default();
        for i in 0..(PRUNE_AT + 10) {
            t.add(1.0 + i as f64 * 1e-9, 0.01, 0.5);
        }
        assert_eq!(t.pairs.len(), PRUNE_AT + 10);
        assert_eq!(t.prune_at, 2 * PRUNE_AT, "pruned again after the first prune");
    }
}
