//! The sun's light that δ-M scaling kept in the beam, scattered towards the camera with the true
//! phase function: the chains of forward-peak scatterings a binned source cannot show.
//!
//! **Why.** Under δ-M ([`crate::quadrature::phase::Truncation`]) a fraction f of every scattering
//! counts as not scattered at all: the beam the solve sweeps, with the scaled extinction σt* =
//! σt − f·σs, carries E*(x) = E(x)·e^{τ(x)}, where E is the truly uncollided irradiance and τ(x) =
//! ln(E*/E) the optical depth of those peak scatterings along the sun's path to x. The solve
//! scatters E* out of the beam with the remainder phase function only, binned; the image takes
//! that first scattering off ([`crate::solver::direct`]) and puts back the exact single
//! scattering of E. Without more, the light E* − E, which has been deflected by the forward peak
//! once or more and is still travelling close to the sun's direction, reaches the camera from
//! nowhere: looking towards the sun through a forward-scattering cloud, the image misses a large
//! part of its brightness (g = 0.8: a quarter of the cloud's, benches/RESULTS.md).
//!
//! **What.** Along the sun's path the peak scatterings are independent events at rate f·σs, so the
//! number n that the light reaching x has undergone is Poisson-distributed with mean τ(x):
//! a share `P(n; τ) = e^{−τ}·τⁿ/n!` of E*. Each deflects the light by the core of HG(g) (the
//! peak δ-M truncates is HG(g)'s own: its value at the forward direction is within a few per cent
//! of the truncated part's), and the last scattering, towards the camera, is a whole HG(g). The
//! convolution of Henyey–Greenstein phase functions over the sphere is again one: their Legendre
//! coefficients are gˡ and multiply, so HG(g₁) ⊛ HG(g₂) = HG(g₁·g₂) exactly. The light scattered
//! towards the camera at x is then
//!
//! `σs(x)·E*(x)·Σₙ P(n; τ(x))·HG(g^{n+1}; ω_sun·ω_camera)`
//!
//! whose n = 0 term is the exact single scattering `σs·HG(g)·E`. Where the sun's light has met no
//! medium (τ = 0) it is that term alone; deep in a cloud (τ large) the sum tends to the isotropic
//! 1/4π. It travels to the camera with the true extinction, as the single scattering does: a
//! further peak scattering on the way is counted where it happens, by the same sum.
//!
//! **Not exact.** The chains are followed along straight lines (a small-angle view), and wide
//! scatterings that return light into the peak are the solve's. Against the Monte-Carlo
//! reference this brings a backlit g = 0.8 cloud from 31 % to 17 % (4 × 4-pixel blocks over the
//! cloud, relative L2) and g = 0.95 from 80 % to 29–39 %, still too dark: forward light scattered
//! outside δ-M's peak but within a storage cell of the sun is the binned source's, smeared. Side-
//! and front-lit views are within 1.2–5.3 % (benches/RESULTS.md, "Render: the suns' single
//! scattering exact", `tools/forward_image_table.sh`).

use crate::quadrature::phase::henyey_greenstein;
use std::f64::consts::PI;

/// The chain sum stops once HG(gⁿ) is this close to isotropic (relative): what is left is 1/4π.
const ISOTROPIC: f64 = 1e-5;

/// Most terms of the table (g → 1 would need ever more: 0.99 needs ~1,200).
const MOST_TERMS: usize = 4096;

/// `HG(g^{n+1}; μ)` for n = 0, 1, … until it is isotropic to 10⁻⁵ (relative), for one sun and one
/// camera ray (μ = ω_sun·ω_camera is the same all along the ray).
pub struct PeakChains {
    phases: Vec<f64>,
}

impl PeakChains {
    pub fn new(g: f64, mu: f64) -> PeakChains {
        let iso = 1.0 / (4.0 * PI);
        let mut phases = Vec::new();
        let mut gn = g;
        loop {
            let p = henyey_greenstein(gn, mu);
            phases.push(p);
            if (p / iso - 1.0).abs() < ISOTROPIC || phases.len() == MOST_TERMS {
                break;
            }
            gn *= g;
        }
        PeakChains { phases }
    }

    /// The single-scattering term alone (no table): for a render without δ-M, which asks only
    /// for [`single_phase`](Self::single_phase).
    pub fn single(g: f64, mu: f64) -> PeakChains {
        PeakChains { phases: vec![henyey_greenstein(g, mu)] }
    }

    /// The single-scattering phase HG(g; μ): the sum at τ = 0.
    pub fn single_phase(&self) -> f64 {
        self.phases[0]
    }

    /// `Σₙ P(n; τ)·HG(g^{n+1}; μ)` for τ ≥ 0 (τ = ∞ gives 1/4π). τ = 0 returns
    /// [`single_phase`](Self::single_phase) bit for bit.
    pub fn phase(&self, tau: f64) -> f64 {
        poisson_mix(tau, self.phases.len(), |n| self.phases[n])
    }
}

/// [`PeakChains::phase`] for one (g, μ) without a table: for a light whose direction changes
/// along the camera ray (a point light), where a table per sample would cost more than the sum.
pub fn chain_phase(g: f64, mu: f64, tau: f64) -> f64 {
    let iso = 1.0 / (4.0 * PI);
    if tau <= 0.0 {
        return henyey_greenstein(g, mu);
    }
    if !tau.is_finite() {
        return iso;
    }
    // Only the terms the Poisson weights reach, until they are isotropic.
    let last = ((tau + 12.0 * tau.sqrt() + 12.0).ceil() as usize).min(MOST_TERMS - 1);
    let mut terms = Vec::with_capacity(last + 1);
    let mut gn = g;
    for _ in 0..=last {
        let p = henyey_greenstein(gn, mu);
        terms.push(p);
        if (p / iso - 1.0).abs() < ISOTROPIC {
            break;
        }
        gn *= g;
    }
    poisson_mix(tau, terms.len(), |n| terms[n])
}

/// `Σₙ P(n; τ)·phase(n)` over n < `terms`, the Poisson mass past them counted as isotropic
/// (1/4π): τ ≤ 0 gives `phase(0)` exactly, τ = ∞ 1/4π.
fn poisson_mix(tau: f64, terms: usize, phase: impl Fn(usize) -> f64) -> f64 {
    let iso = 1.0 / (4.0 * PI);
    if tau <= 0.0 {
        return phase(0);
    }
    if !tau.is_finite() || terms == 0 {
        return iso;
    }
    // Past τ + 12√τ + 12 the remaining Poisson mass is below 1e-25; past the last term every
    // term is isotropic.
    let last = ((tau + 12.0 * tau.sqrt() + 12.0).ceil() as usize).min(terms - 1);
    let (mut sum, mut mass) = (0.0, 0.0);
    if tau < 600.0 {
        // The weights by their recurrence, w₀ = e^{−τ} and w_{n+1} = w_n·τ/(n+1): one
        // exponential per sample (e^{−600} is still a normal f64).
        let mut w = (-tau).exp();
        for n in 0..=last {
            sum += w * phase(n);
            mass += w;
            w *= tau / (n + 1) as f64;
        }
    } else {
        // In logarithms, where e^{−τ} would underflow.
        let (ln_tau, mut ln_w) = (tau.ln(), -tau);
        for n in 0..=last {
            if n > 0 {
                ln_w += ln_tau - (n as f64).ln();
            }
            if ln_w > -60.0 {
                let w = ln_w.exp();
                sum += w * phase(n);
                mass += w;
            }
        }
    }
    sum + (1.0 - mass).max(0.0) * iso
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The spherical convolution of HG(g₁) and HG(g₂) at scattering cosine μ: light deflected
    /// by HG(g₁) from the z axis, then by HG(g₂), arriving at angle acos μ.
    fn convolved(g1: f64, g2: f64, mu: f64) -> f64 {
        let (n_theta, n_phi) = (4000, 256);
        let out = glam::DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
        let mut sum = 0.0;
        for i in 0..n_theta {
            // Finer near the forward direction: θ = (u²)·π.
            let u0 = i as f64 / n_theta as f64;
            let u1 = (i + 1) as f64 / n_theta as f64;
            let (t0, t1) = (u0 * u0 * PI, u1 * u1 * PI);
            let t = 0.5 * (t0 + t1);
            let band = 2.0 * PI * (t0.cos() - t1.cos()) / n_phi as f64;
            for j in 0..n_phi {
                let phi = (j as f64 + 0.5) * 2.0 * PI / n_phi as f64;
                let mid = glam::DVec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos());
                sum += band * henyey_greenstein(g1, t.cos()) * henyey_greenstein(g2, mid.dot(out));
            }
        }
        sum
    }

    #[test]
    fn henyey_greenstein_convolves_into_henyey_greenstein_of_the_product() {
        for (g1, g2) in [(0.8, 0.8), (0.6, 0.9)] {
            for mu in [1.0, 0.95, 0.5, -0.5] {
                let (got, want) = (convolved(g1, g2, mu), henyey_greenstein(g1 * g2, mu));
                assert!((got / want - 1.0).abs() < 2e-3, "g {g1}·{g2}, μ {mu}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn the_sum_is_the_single_scattering_without_peak_and_isotropic_deep_in() {
        let chains = PeakChains::new(0.8, 0.97);
        assert_eq!(chains.phase(0.0).to_bits(), henyey_greenstein(0.8, 0.97).to_bits());
        assert_eq!(chains.single_phase(), henyey_greenstein(0.8, 0.97));
        let iso = 1.0 / (4.0 * PI);
        assert!((chains.phase(f64::INFINITY) - iso).abs() < 1e-15);
        assert!((chains.phase(2000.0) / iso - 1.0).abs() < 1e-5);
        // One peak scattering on average: the Poisson mixture written out.
        let tau: f64 = 1.0;
        let want: f64 = (0..60)
            .map(|n| {
                let w = (-tau).exp() * tau.powi(n) / (1..=n).map(f64::from).product::<f64>();
                w * henyey_greenstein(0.8f64.powi(n + 1), 0.97)
            })
            .sum();
        assert!((chains.phase(tau) / want - 1.0).abs() < 1e-12, "{} vs {want}", chains.phase(tau));
        // Towards the sun the sum falls as the peak spreads; away from it, it rises.
        let back = PeakChains::new(0.8, -0.5);
        assert!(chains.phase(0.5) < chains.phase(0.0) && chains.phase(5.0) < chains.phase(0.5));
        assert!(back.phase(5.0) > back.phase(0.0));
        // Without a table, the same sums.
        for tau in [0.0, 0.3, 4.0, 90.0, 900.0, f64::INFINITY] {
            for (g, mu) in [(0.8, 0.97), (0.95, 0.2)] {
                let (a, b) = (chain_phase(g, mu, tau), PeakChains::new(g, mu).phase(tau));
                assert!((a - b).abs() <= 1e-12 * b, "g {g}, μ {mu}, τ {tau}: {a} vs {b}");
            }
        }
    }
}
