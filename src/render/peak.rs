//! The sun's light that δ-M scaling kept in the beam, scattered towards the camera with the true
//! phase function: the chains of forward-peak scatterings, and the sharp forward lobes of the
//! light scattered more than once, that a binned source cannot show.
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
//! reference the chains brought a backlit g = 0.8 cloud from 31 % to 17 % (4 × 4-pixel blocks over
//! the cloud, relative L2) and g = 0.95 from 80 % to 29–39 %, still too dark: forward light
//! scattered outside δ-M's peak but within a storage cell of the sun is the binned source's,
//! smeared over a cell ~45° wide. Side- and front-lit views are within 0.6–4.7 %
//! (benches/RESULTS.md, "Render: the suns' single scattering exact", `tools/forward_image_table.sh`).
//!
//! **The forward lobes** ([`ForwardLobes`]). That smeared light is mostly the sun's, scattered
//! twice or more yet still travelling near the sun's direction. In the same small-angle view, the
//! light reaching x after n scatterings along the sun's path is `E·τₛⁿ/n!` (E the truly
//! uncollided irradiance, τₛ = τ/f the scattering depth, f δ-M's peak share, so that all its
//! scatterings being peak ones is the chains' `E·τⁿ/n!`), and its last scattering towards the
//! camera spreads it as HG(g^{n+1}). The chains count the all-peak part; the rest,
//! `wₙ = E·(τₛⁿ − τⁿ)/n!`, met at least one of δ-M's remainder scatterings and is the solve's.
//! The render adds, per lobe, how far the sharp lobe exceeds what the solve's storage cells hold of
//! it towards the camera, `σs·Σₙ wₙ·max(HG(g^{n+1}; μ) − heldₙ, 0)`, to the single scattering.
//! Three choices make it agree with the Monte-Carlo reference:
//!
//! - **What the cells hold is the solve's shape, not the lobe's.** The solve sees only the
//!   remainder scatterings (the peak ones pass straight on), each with the remainder phase of mean
//!   cosine g̃ (`render.json`'s medium g), and scatters towards the camera with it once more. Of
//!   lobe n's light, the share that met m = 1..=n remainder scatterings is binomial in 1 − f
//!   (given at least one), and the solve holds that share with the shape its own m + 1
//!   scatterings give it: `heldₙ = Σₘ βₙₘ·rowₘ`, rowₘ the beam's binned first scattering passed
//!   m times more through the solve's collect matrix (`SolvedScattering`; each pass from cell to
//!   cell widens it more than the continuous HG(g̃^{m+1}) binned once, and towards the sun it is
//!   lower: with that as the threshold the lobes came out some 15 % short). (The lobe's own cell
//!   mean, binned HG(g^{n+1}), is sharper still than what the solve holds: taken as the
//!   threshold, a slab towards the sun came out 5–14 % dark.)
//! - **The lobes travel to the camera with the true extinction**, as the single scattering does,
//!   not with the solved source's scaled one. Under δ-M a peak scattering on the way leaves light
//!   where it was, which is right for the smooth binned source but not for a sharp lobe: each peak
//!   scattering widens it, and its value towards the camera falls. The wider lobe is counted
//!   where it happens, by the larger n further along the ray (the camera looks along the sun's
//!   path). With the scaled extinction a backlit g = 0.95 cloud came out 2.6× too bright through
//!   its thick core, which a bound on the lobes (no more than the solved source towards the sun)
//!   held back only by making the thin parts 13 % too dark.
//! - **Only where the sharp lobe is above what the cells hold** (towards the sun): the bins are
//!   left as they are elsewhere. Taking each lobe's bin off where the sharp lobe is below it (a
//!   zero-sum reshaping) made a side-lit g = 0.8 cloud 1.6 % darker against the reference.
//!
//! **Sideways.** Both count their light along the sun's straight line; [`super::cone`] adds how
//! far the light of a cone of directions about the sun, transported with the real geometry,
//! differs from the same held on that line (a thin rim loses it sideways, a core gains it).
//!
//! Lobes broader than HG(0.05) are left to the bins, which hold their shape. Against the
//! Monte-Carlo reference (`tools/forward_image_table.sh` at 4096 paths per pixel,
//! benches/RESULTS.md; with the suns' irradiance at the voxels' centres,
//! [`crate::solver::beam_trace`]) the backlit clouds' blocks come within 3.2–4.7 % (g = 0.8) and
//! 4.6–5.4 % (g = 0.95), and seen exactly towards the sun 3.7–4.6 %, from 17 % and 29–39 % with
//! the chains alone (the thin rim of a g = 0.95 cloud, not in those blocks, is some 6 % too
//! bright: where the camera ray grazes the cloud's edge, so does the straight line
//! from the sun the chains and lobes count their depth along, while light deflected on the way
//! soon leaves the thin fringe; its orders 2, 3, … come out ≈ 1.2ⁿ times the reference's there.
//! Monte Carlo on the δ-M scaled medium puts 11–13 % too much light into that fringe as well:
//! it is δ-M's straight peak itself, which the lobes and chains inherit);
//! side- and front-lit views are unchanged to the digit (away from the sun only the broadest lobes
//! exceed what the cells hold, by under 1 % of their value). Only under
//! δ-M (the default for a forward-scattering medium): without it the render has no peak depth to
//! take τₛ from, and `forward_peak = "keep"` renders as before.

use crate::quadrature::phase::{collect_matrix, henyey_greenstein, BeamRows, Phase, Truncation};
use crate::quadrature::{Blend, PropagationSet, StorageSet};
use glam::DVec3;
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

/// A lobe HG(g') is left to the bins once g' is below this: a storage cell then holds its shape
/// (at g' = 0.05 the lobe varies by ±15 % over the sphere, by a few per cent across one cell).
const BROAD_LOBE: f64 = 0.05;

/// One sun's forward lobes (module docs, "The forward lobes"): for n = 1, 2, … the sharp shape
/// HG(g^{n+1}) about the sun's direction of travel, until the lobe is broad enough that the cells
/// keep its shape, and what the solve's storage cells hold of the same light: the mixture, over
/// how many of the n scatterings were δ-M's remainder ones, of the remainder's own binned shapes.
pub struct ForwardLobes {
    travel: DVec3,
    /// HG parameter per lobe: g², g³, …
    gs: Vec<f64>,
    /// The solve's shape after m = 1, 2, … remainder scatterings and the remainder scattering
    /// towards the camera, as the solve's own cell-to-cell scattering makes it
    /// ([`SolvedScattering`]), per storage cell (1/sr); past the last row, isotropic.
    solved_rows: Vec<Vec<f64>>,
    /// Per lobe n, the share of its light that met m = 1..=n remainder scatterings (binomial in
    /// the remainder's share 1 − f, given at least one).
    remainder_mix: Vec<Vec<f64>>,
    /// δ-M's peak share f: the scattering depth is the peak's depth over f.
    peak_share: f64,
}

impl ForwardLobes {
    /// `g`: the scene's true Henyey–Greenstein parameter; `solved_g` (g̃) and `peak_share` (f):
    /// the remainder's mean cosine and δ-M's peak share the solve ran with. No lobes for an
    /// isotropic storage set, g ≤ 0 or no peak truncated (the bins then hold every lobe's shape,
    /// or the render has no peak depth to take the lobes' amounts from).
    pub fn new(
        prop: &PropagationSet,
        storage: &StorageSet,
        g: f64,
        solved_g: f64,
        peak_share: f64,
        travel: DVec3,
    ) -> Self {
        Self::for_suns(prop, storage, g, solved_g, peak_share, &[travel]).remove(0)
    }

    /// [`new`](Self::new) for every sun's direction of travel, with the solve's scattering
    /// between its cells rebuilt once for all.
    pub fn for_suns(
        prop: &PropagationSet,
        storage: &StorageSet,
        g: f64,
        solved_g: f64,
        peak_share: f64,
        travels: &[DVec3],
    ) -> Vec<Self> {
        let lobed = !storage.is_isotropic() && g > 0.0 && peak_share > 0.0 && peak_share < 1.0;
        let mut gs = Vec::new();
        let mut remainder_mix = Vec::new();
        if lobed {
            let mut gn = g * g;
            while gn >= BROAD_LOBE && gs.len() < MOST_TERMS {
                gs.push(gn);
                gn *= g;
            }
            let f = peak_share;
            for n in 1..=gs.len() {
                let mut binomial = 1.0;
                let at_least_one = 1.0 - f.powi(n as i32);
                let mix = (1..=n)
                    .map(|m| {
                        binomial *= (n - m + 1) as f64 / m as f64;
                        binomial * (1.0 - f).powi(m as i32) * f.powi((n - m) as i32) / at_least_one
                    })
                    .collect();
                remainder_mix.push(mix);
            }
        }
        // A shape per remainder count m while g̃^{m+1} is at least BROAD_LOBE (past that the solve
        // holds the light nearly isotropic), and no more than the lobes have.
        let mut rows = 0;
        let mut gm = solved_g * solved_g;
        while lobed && gm >= BROAD_LOBE && rows < gs.len() {
            rows += 1;
            gm *= solved_g;
        }
        let solve = (rows > 0).then(|| SolvedScattering::new(prop, storage, g, solved_g));
        travels
            .iter()
            .map(|&travel| ForwardLobes {
                travel,
                gs: gs.clone(),
                solved_rows: solve.as_ref().map_or_else(Vec::new, |s| s.rows(travel, rows)),
                remainder_mix: remainder_mix.clone(),
                peak_share,
            })
            .collect()
    }

    /// δ-M's peak share f the lobes were built for (the peak's depth τₚ is f times the
    /// scattering depth τₛ).
    pub fn peak_share(&self) -> f64 {
        self.peak_share
    }

    /// Whether there is any lobe to sharpen.
    pub fn is_empty(&self) -> bool {
        self.gs.is_empty()
    }

    /// For the camera ray whose light reaches the camera travelling along `towards` (blended over
    /// the storage directions by `blend`): per lobe, how far the sharp lobe exceeds what the
    /// solve's cells hold of it there, `max(HG(g^{n+1}; μ) − Σₘ βₙₘ·binned HG(g̃^{m+1}), 0)` (μ
    /// the cosine to the sun's travel). Empty where no lobe exceeds its bins (a ray looking away
    /// from the sun: nothing to add).
    pub fn excess(&self, towards: DVec3, blend: &Blend) -> Vec<f64> {
        let mu = self.travel.dot(towards);
        let iso = 1.0 / (4.0 * PI);
        let solved: Vec<f64> = self.solved_rows.iter().map(|row| blended(row, blend)).collect();
        let excess: Vec<f64> = self
            .gs
            .iter()
            .zip(&self.remainder_mix)
            .map(|(&g, mix)| {
                let held: f64 = mix.iter().enumerate().map(|(m, b)| b * solved.get(m).copied().unwrap_or(iso)).sum();
                (henyey_greenstein(g, mu) - held).max(0.0)
            })
            .collect();
        if excess.iter().any(|&x| x > 0.0) {
            excess
        } else {
            Vec::new()
        }
    }

    /// The lobes' light at a point towards the camera, per unit σs: `Σₙ wₙ·excess[n]` with
    /// `wₙ = e·(τₛⁿ − τₚⁿ)/n!`, the light scattered n times along the sun's path (Poisson in the
    /// scattering depth τₛ) less the chains' share (τₚ, all n in the peak).
    pub fn light(&self, excess: &[f64], e: f64, tau_s: f64, tau_p: f64) -> f64 {
        let (mut ws, mut wp, mut added) = (e, e, 0.0);
        for (n, x) in excess.iter().enumerate() {
            ws *= tau_s / (n + 1) as f64;
            wp *= tau_p / (n + 1) as f64;
            added += (ws - wp).max(0.0) * x;
        }
        added
    }
}

/// The solve's scattering between its direction cells, rebuilt from the render data: δ-M's
/// truncation of the scene's g for the same direction sets ([`Truncation::for_sets`], which the
/// solve's plan ran) and its collect matrix. A solve scatters light that has left the sun's beam
/// from cell to cell: each propagation direction takes the source of the storage cell that owns
/// it, and the collect matrix bins its scattering into the storage cells again. Each pass widens
/// the light more than the continuous convolution would (HG(g̃) ⊛ HG(g̃) = HG(g̃²) binned once),
/// so towards the sun the solve holds less of the forward-scattered light than binned HG(g̃^{m+1})
/// says; taking that as the threshold left the lobes some 15 % short (backlit clouds 0.5–1.2 points
/// further from Monte Carlo, benches/RESULTS.md).
struct SolvedScattering {
    /// The phase function found (only the tests ask which).
    #[cfg(test)]
    phase: Phase,
    /// `[propagation direction][storage direction]`, as [`collect_matrix`] builds it.
    collect: Vec<f64>,
    /// The beam's first scattering into the storage cells, its fine quadrature built once for
    /// every sun.
    beam: BeamRows,
    /// The storage cell owning each propagation direction.
    owner: Vec<u32>,
}

impl SolvedScattering {
    /// The truncation the solve ran with when its remainder's g is `solved_g` (to 10⁻⁹; it is
    /// rebuilt from the same inputs), else HG(g̃) itself (render data of a solve that truncated
    /// otherwise: the same remainder cosine, the nearest shape the data says).
    fn new(prop: &PropagationSet, storage: &StorageSet, g: f64, solved_g: f64) -> SolvedScattering {
        let t = Truncation::for_sets(g, prop, storage);
        let phase = if (t.remainder_g() - solved_g).abs() <= 1e-9 {
            Phase::Truncated(t)
        } else {
            Phase::HenyeyGreenstein { g: solved_g }
        };
        SolvedScattering {
            #[cfg(test)]
            phase,
            collect: collect_matrix(prop, storage, &phase),
            beam: BeamRows::new(prop, storage, &phase),
            owner: storage.owner.clone(),
        }
    }

    /// For a beam along `travel`: the storage rows after m = 1..=`count` scatterings out of the
    /// beam's first one, each propagation direction taking its owner's source and the collect
    /// matrix scattering it again (per steradian; each row's light sums to 1 over the sphere).
    fn rows(&self, travel: DVec3, count: usize) -> Vec<Vec<f64>> {
        let s = self.beam.storage_len();
        let first = self.beam.row(travel);
        let mut rows: Vec<Vec<f64>> = Vec::with_capacity(count);
        for _ in 0..count {
            let row = rows.last().unwrap_or(&first);
            let mut next = vec![0.0; s];
            for (owner, collect) in self.owner.iter().zip(self.collect.chunks(s)) {
                let radiance = row[*owner as usize];
                next.iter_mut().zip(collect).for_each(|(n, m)| *n += radiance * m);
            }
            rows.push(next);
        }
        rows
    }
}

/// δ-M's peak share f from the scene's true extinction and albedo and the extinction the solve
/// ran with, σt* = σt·(1 − a·f); 0 where nothing scatters.
pub fn peak_share(true_sigma_t: f64, albedo: f64, solved_sigma_t: f64) -> f64 {
    if true_sigma_t > 0.0 && albedo > 0.0 {
        ((1.0 - solved_sigma_t / true_sigma_t) / albedo).max(0.0)
    } else {
        0.0
    }
}

/// A row over the storage directions blended by `blend`.
fn blended(row: &[f64], blend: &Blend) -> f64 {
    blend.entries().map(|(d, w)| w * row.get(d as usize).copied().unwrap_or(0.0)).sum()
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
    use crate::quadrature::StorageBlend;

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
    fn forward_lobes_exceed_what_the_solve_holds_only_towards_the_sun() {
        let prop = PropagationSet::new(4);
        let storage = StorageSet::per_face(&prop, 2);
        let blend = StorageBlend::new(&storage);
        let travel = DVec3::new(-0.55, -0.35, 0.75).normalize();
        // g 0.8 as the default solve truncates it: g̃ 0.570, f 0.582.
        let t = Truncation::for_sets(0.8, &prop, &storage);
        assert!((t.remainder_g() - 0.570).abs() < 1e-3 && (t.fraction - 0.582).abs() < 1e-3, "{t:?}");
        let lobes = ForwardLobes::new(&prop, &storage, 0.8, t.remainder_g(), t.fraction, travel);
        // HG(0.8²) … HG(0.8¹³): 0.8¹⁴ = 0.044 is broad enough for the bins.
        assert_eq!(lobes.gs.len(), 12);
        assert!((lobes.gs[0] - 0.64).abs() < 1e-12 && lobes.gs.iter().all(|&g| g >= BROAD_LOBE));
        // The solve's shapes HG(0.570²) … HG(0.570⁵) (0.570⁶ = 0.034 is isotropic enough).
        assert_eq!(lobes.solved_rows.len(), 4);
        for row in &lobes.solved_rows {
            // Each binned shape holds all of its light (per steradian × solid angle).
            let total: f64 = row.iter().zip(&storage.solid_angle).map(|(r, w)| r * w).sum();
            assert!((total - 1.0).abs() < 1e-9, "{total}");
        }
        // The remainder counts of each lobe's light: a distribution over m = 1..=n.
        for (n, mix) in lobes.remainder_mix.iter().enumerate() {
            assert_eq!(mix.len(), n + 1);
            assert!((mix.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{mix:?}");
        }
        // One scattering along the path: it was the remainder one.
        assert_eq!(lobes.remainder_mix[0], vec![1.0]);
        // Towards the sun every lobe is sharper than what the cells hold; behind, none is; at
        // right angles only the broadest, by less than 1 % of their value (the solve holds their
        // light nearly isotropic there).
        let at_sun = lobes.excess(travel, &blend.weights(travel));
        assert_eq!(at_sun.len(), 12);
        assert!(at_sun.iter().all(|&x| x > 0.0), "{at_sun:?}");
        let side = travel.cross(DVec3::Z).normalize();
        let sideways = lobes.excess(side, &blend.weights(side));
        for (x, &g) in sideways.iter().zip(&lobes.gs) {
            assert!(*x < 0.01 * henyey_greenstein(g, 0.0), "{sideways:?}");
        }
        assert!(lobes.excess(-travel, &blend.weights(-travel)).is_empty());
        // No lobes where the bins already hold every shape, or with no peak truncated.
        let iso = StorageSet::isotropic(&prop);
        assert!(ForwardLobes::new(&prop, &iso, 0.8, 0.570, 0.582, travel).is_empty());
        assert!(ForwardLobes::new(&prop, &storage, 0.0, 0.0, 0.582, travel).is_empty());
        assert!(ForwardLobes::new(&prop, &storage, 0.8, 0.8, 0.0, travel).is_empty());
    }

    /// The solve's shapes are its own cell-to-cell scatterings: the truncation it ran with, found
    /// again from g and the direction sets; the first row is the beam's binned scattering
    /// collected once more. With fine cells that is the binned convolution HG(g̃²); with the
    /// default cells it is wider, lower towards the sun than binned HG(g̃²) (what the threshold
    /// took before, which left the lobes short).
    #[test]
    fn the_solve_holds_its_own_cell_to_cell_scatterings() {
        let travel = DVec3::new(0.2, -0.1, 1.0).normalize();
        let sun_value = |k: u32, ks: u32, g: f64| {
            let prop = PropagationSet::new(k);
            let storage = StorageSet::per_face(&prop, ks);
            let solve = SolvedScattering::new(&prop, &storage, g, g);
            let rows = solve.rows(travel, 2);
            for row in &rows {
                let total: f64 = row.iter().zip(&storage.solid_angle).map(|(r, w)| r * w).sum();
                assert!((total - 1.0).abs() < 1e-9, "{total}");
            }
            let weights = StorageBlend::new(&storage).weights(travel);
            let binned = BeamRows::new(&prop, &storage, &Phase::HenyeyGreenstein { g: g * g }).row(travel);
            (blended(&rows[0], &weights), blended(&binned, &weights))
        };
        // A g that no truncation leaves as its remainder: HG(g̃) itself, for the fine cells too.
        let (fine, binned_fine) = sun_value(8, 8, 0.5);
        assert!((fine / binned_fine - 1.0).abs() < 0.05, "fine cells: {fine} vs {binned_fine}");
        let (coarse, binned_coarse) = sun_value(4, 2, 0.5);
        eprintln!("towards the sun: fine cells {fine} vs {binned_fine}, default {coarse} vs {binned_coarse}");
        assert!(coarse < 0.97 * binned_coarse, "default cells: {coarse} vs {binned_coarse}");
        // The truncation a δ-M solve of g 0.8 ran with is found again from its remainder's g.
        let prop = PropagationSet::new(4);
        let storage = StorageSet::per_face(&prop, 2);
        let t = Truncation::for_sets(0.8, &prop, &storage);
        let solve = SolvedScattering::new(&prop, &storage, 0.8, t.remainder_g());
        assert_eq!(solve.phase, Phase::Truncated(t));
        assert_eq!(solve.collect, collect_matrix(&prop, &storage, &Phase::Truncated(t)));
        let first = solve.rows(travel, 1).remove(0);
        let beam = BeamRows::new(&prop, &storage, &Phase::Truncated(t)).row(travel);
        let s = storage.len();
        for d in 0..s {
            let want: f64 = (0..prop.len()).map(|j| beam[storage.owner[j] as usize] * solve.collect[j * s + d]).sum();
            assert!((first[d] - want).abs() <= 1e-12 * want.max(1e-12), "cell {d}: {} vs {want}", first[d]);
        }
    }

    #[test]
    fn the_lobes_light_is_the_small_angle_sum_less_the_chains() {
        let prop = PropagationSet::new(4);
        let storage = StorageSet::per_face(&prop, 2);
        let blend = StorageBlend::new(&storage);
        let travel = DVec3::Z;
        let lobes = ForwardLobes::new(&prop, &storage, 0.9, 0.6, 0.7, travel);
        let towards = DVec3::new(0.1, 0.0, 1.0).normalize();
        let excess = lobes.excess(towards, &blend.weights(towards));
        let (e, tau_s, tau_p) = (0.3, 2.5, 1.5);
        let added = lobes.light(&excess, e, tau_s, tau_p);
        let factorial = |n: i32| (1..=n).map(f64::from).product::<f64>();
        let w = |n: usize| e * (tau_s.powi(n as i32) - tau_p.powi(n as i32)) / factorial(n as i32);
        let want: f64 = excess.iter().enumerate().map(|(i, x)| w(i + 1) * x).sum();
        assert!((added / want - 1.0).abs() < 1e-12, "{added} vs {want}");
        // Nothing but peak scatterings (the chains' light): nothing for the lobes.
        assert_eq!(lobes.light(&excess, e, 1.5, 1.5), 0.0);
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
