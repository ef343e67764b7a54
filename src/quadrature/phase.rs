//! Henyey–Greenstein scattering between discrete direction cells.
//!
//! The collect step turns each propagation direction's segment-average radiance L̄_i into the next
//! order's source J^d = σs · Σ_i M\[i\]\[d\] · L̄_i with `M[i][d] = Ω_i·P(i→d)/Ω_d`. P(i→d) is the phase
//! function integrated over both cells (by sub-cell quadrature with exact sub-cell solid angles), each
//! row normalised to sum to 1 so that Σ_d Ω_d J^d = σs Σ_i Ω_i L̄_i: the discrete scattering neither
//! creates nor loses energy, whatever the quadrature error of P itself. For g = 0 the exact value
//! P(i→d) = Ω_d/4π is used.
//!
//! **The forward peak** ([`Truncation`]). A strongly forward phase function (g ≳ 0.5) has a peak far
//! narrower than a storage cell. δ-M scaling counts a fraction f of the scattering as not scattered
//! at all (σt' = σt·(1 − f·a)) and scatters the rest with a remainder phase function. Classic δ-M
//! takes f = g² and an HG(g') remainder with g' = (g − f)/(1 − f); that keeps the transport
//! cross-section σt·(1 − a·g) but not the phase function's shape: HG(g') scatters far more light
//! backwards than HG(g) does outside its peak (a τ = 2, g = 0.85 slab reflects 21 % too much under
//! it, exactly transported: benches/RESULTS.md). lpm's remainder is HG(g) itself outside a forward
//! cone of a few storage cells' solid angle; what HG(g) scatters into the cone, C, is split between
//! the unscattered beam (f) and an even spread over the cone (C − f). f is chosen so that the
//! *discrete* scattering (after the storage cells' own widening, [`effective_mean_cosine`]) has
//! the true transport cross-section, (1 − f)·(1 − ḡ) = 1 − g (the cone is the narrowest of 1, 2,
//! 4, … cells in which that takes no more than C). Outside the cone every angle
//! scatters exactly as HG(g) does. (Transported exactly, a slab's reflectance under this
//! truncation is within the Monte Carlo's noise of HG(g)'s for cones of 10° to 50°.)

use super::{cube_face, PropagationSet, StorageSet, FACES};
use glam::DVec3;
use std::f64::consts::PI;

/// Henyey–Greenstein phase function, normalised over the sphere, of the cosine between the incident
/// and the scattered directions of travel.
pub fn henyey_greenstein(g: f64, cos_theta: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// The phase function the collect step discretises.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Phase {
    /// Henyey–Greenstein with mean cosine `g`.
    HenyeyGreenstein { g: f64 },
    /// What HG(g) leaves once δ-M moved its forward fraction into the unscattered beam.
    Truncated(Truncation),
}

impl Phase {
    /// Whether it scatters alike into every direction.
    pub fn is_isotropic(&self) -> bool {
        matches!(self, Phase::HenyeyGreenstein { g } if *g == 0.0)
    }

    /// The weighted sum of `rows(part)` over the phase function's parts (each part's rows
    /// normalised on their own, so the sum's rows are normalised too).
    fn mix(&self, rows: impl Fn(Part) -> Vec<f64>) -> Vec<f64> {
        let mut sum: Vec<f64> = Vec::new();
        for (weight, part) in self.parts() {
            let r = rows(part);
            sum.resize(r.len(), 0.0);
            sum.iter_mut().zip(r).for_each(|(acc, v)| *acc += weight * v);
        }
        sum
    }

    /// The phase function's parts, each normalised over the sphere, with their weights (summing
    /// to 1).
    fn parts(&self) -> Vec<(f64, Part)> {
        match *self {
            Phase::HenyeyGreenstein { g } => vec![(1.0, Part::HenyeyGreenstein(g))],
            Phase::Truncated(t) => {
                let keep = 1.0 - t.fraction;
                let mut parts = vec![((1.0 - t.peak) / keep, Part::Outside { g: t.g, cone: t.cone })];
                if t.peak > t.fraction {
                    parts.push(((t.peak - t.fraction) / keep, Part::Cone(t.cone)));
                }
                parts
            }
        }
    }
}

/// One normalised part of a [`Phase`].
#[derive(Clone, Copy, Debug)]
enum Part {
    HenyeyGreenstein(f64),
    /// HG(g) outside the cone of cosine `cone`, zero inside.
    Outside {
        g: f64,
        cone: f64,
    },
    /// Uniform over the directions within the cone of cosine `cone` around the forward one.
    Cone(f64),
}

impl Part {
    /// The part's value for scattering cosine `cos`, up to a constant factor.
    fn value(&self, cos: f64) -> f64 {
        match *self {
            Part::HenyeyGreenstein(g) => henyey_greenstein(g, cos),
            Part::Outside { g, cone } => (cos <= cone) as u8 as f64 * henyey_greenstein(g, cos),
            Part::Cone(cone) => (cos > cone) as u8 as f64,
        }
    }
}

/// The cosine of the widest forward cone a truncation takes (60°: transported exactly, a slab's
/// reflectance is the same with cones of 10° to 50°, benches/RESULTS.md).
pub const WIDEST_CONE: f64 = 0.5;

/// The forward peak of HG(g) cut at a cone (module docs): HG(g) outside; of what it scatters
/// into the cone, `peak`, the share `fraction` (f) is treated as not scattered and the rest is
/// spread evenly over the cone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truncation {
    pub g: f64,
    /// The cosine of the cone's half-angle.
    pub cone: f64,
    /// C: the share of HG(g)'s scattering into the cone.
    pub peak: f64,
    /// f ∈ [0, C]: the share counted as not scattered.
    pub fraction: f64,
}

impl Truncation {
    /// The truncation of HG(g) (g > 0) for the storage cells of `storage`: the narrowest cone of
    /// 1, 2, 4, … storage cells' mean solid angle (at most [`WIDEST_CONE`]) in which f, chosen so
    /// that the discrete scattering keeps the transport cross-section, is at most what HG(g)
    /// scatters into the cone (module docs).
    pub fn for_sets(g: f64, prop: &PropagationSet, storage: &StorageSet) -> Truncation {
        let cells = storage.len() as f64;
        // ḡ of a part as the discrete scattering sees it.
        let mean_cosine = |part: Part| {
            let m = to_collect(prop, storage, part_rows(prop, storage, part));
            effective_mean_cosine(prop, storage, &m)
        };
        let mut cells_in_cone = 1.0;
        loop {
            let cone = (1.0 - 2.0 * cells_in_cone / cells).max(WIDEST_CONE);
            let (peak, _) = hg_cone_moments(g, cone);
            // ḡ of the part outside the cone and of the even spread over it.
            let (g_outside, g_cone) = (mean_cosine(Part::Outside { g, cone }), mean_cosine(Part::Cone(cone)));
            // (1 − f)(1 − ḡ_f) = 1 − g with (1 − f)·ḡ_f = (1 − C)·ḡ_outside + (C − f)·ḡ_cone.
            let fraction = (g - (1.0 - peak) * g_outside - peak * g_cone) / (1.0 - g_cone);
            // The storage cells widen the scattering outside a narrow cone so much that even all
            // of the cone in the beam leaves the transport cross-section too large: a wider cone.
            if fraction <= peak || cone <= WIDEST_CONE {
                return Truncation { g, cone, peak, fraction: fraction.clamp(0.0, peak) };
            }
            cells_in_cone *= 2.0;
        }
    }

    /// The remainder's mean cosine over the continuous sphere (the g solved, for the report).
    pub fn remainder_g(&self) -> f64 {
        let (_, moment) = hg_cone_moments(self.g, self.cone);
        let cone_mean = 0.5 * (1.0 + self.cone);
        (self.g - moment + (self.peak - self.fraction) * cone_mean) / (1.0 - self.fraction)
    }
}

/// The share of HG(g) scattered within the cone of cosine `cone` around the forward direction,
/// and its first moment ∫ μ·p dΩ there (g ≥ 0). With s = √(1 + g² − 2g·cone) the integrals are
/// (1 − g²)/(2g)·(1/(1 − g) − 1/s) and a similar difference over g²; written here with the
/// differences cancelled by hand, so that they hold to rounding down to g → 0 (the uniform
/// function's (1 − cone)/2 and (1 − cone²)/4).
fn hg_cone_moments(g: f64, cone: f64) -> (f64, f64) {
    let s = (1.0 + g * g - 2.0 * g * cone).sqrt();
    let width = 1.0 - cone;
    let mass = (1.0 + g) * width / (s * (s + 1.0 - g));
    let moment = (1.0 + g) * width * (1.0 + g * g + cone * (1.0 - g) * (1.0 - g))
        / ((1.0 + g * g + (1.0 - g) * s) * s * (s + 1.0 - g));
    (mass, moment)
}

/// A fine quadrature of the sphere that refines every propagation cell into m×m sub-cells.
struct SubCells {
    /// (direction, solid angle, propagation cell index)
    samples: Vec<(DVec3, f64, usize)>,
}

impl SubCells {
    fn new(prop: &PropagationSet, m: u32) -> Self {
        let k = prop.k;
        let mut samples = Vec::with_capacity(prop.len() * (m * m) as usize);
        for (i, d) in prop.directions.iter().enumerate() {
            let face = FACES[d.face];
            let (u0, u1) = cube_face::cell_bounds(d.cell[0], k);
            let (v0, v1) = cube_face::cell_bounds(d.cell[1], k);
            for sb in 0..m {
                for sc in 0..m {
                    let su0 = u0 + (u1 - u0) * sb as f64 / m as f64;
                    let su1 = u0 + (u1 - u0) * (sb + 1) as f64 / m as f64;
                    let sv0 = v0 + (v1 - v0) * sc as f64 / m as f64;
                    let sv1 = v0 + (v1 - v0) * (sc + 1) as f64 / m as f64;
                    let w = cube_face::cell_solid_angle(su0, su1, sv0, sv1);
                    let omega = face.direction(0.5 * (su0 + su1), 0.5 * (sv0 + sv1));
                    samples.push((omega, w, i));
                }
            }
        }
        SubCells { samples }
    }
}

/// Sub-cells per propagation-cell edge: as fine as keeps the pair count around 10⁷.
fn refinement(prop: &PropagationSet) -> u32 {
    let target = 3000.0 / prop.len() as f64;
    (target.sqrt().floor() as u32).clamp(1, 8)
}

/// The collect matrix, row-major `[propagation direction][storage direction]`.
pub fn collect_matrix(prop: &PropagationSet, storage: &StorageSet, phase: &Phase) -> Vec<f64> {
    let n = prop.len();
    let s = storage.len();
    let mut p = vec![0.0; n * s];
    if phase.is_isotropic() || storage.is_isotropic() {
        // Isotropic scattering, or a single storage direction: P(i→d) = Ω_d / 4π exactly.
        let total: f64 = storage.solid_angle.iter().sum();
        for i in 0..n {
            for d in 0..s {
                p[i * s + d] = storage.solid_angle[d] / total;
            }
        }
    } else {
        p = phase.mix(|part| part_rows(prop, storage, part));
    }
    to_collect(prop, storage, p)
}

/// P(i→d) of one part, each row normalised to 1.
fn part_rows(prop: &PropagationSet, storage: &StorageSet, part: Part) -> Vec<f64> {
    let s = storage.len();
    let mut p = vec![0.0; prop.len() * s];
    let sub = SubCells::new(prop, refinement(prop));
    for &(wa, oa, ia) in &sub.samples {
        for &(wb, ob, ib) in &sub.samples {
            let d = storage.owner[ib] as usize;
            p[ia * s + d] += oa * ob * part.value(wa.dot(wb));
        }
    }
    normalise_rows(&mut p, s);
    p
}

/// M\[i\]\[d\] = Ω_i·P(i→d)/Ω_d.
fn to_collect(prop: &PropagationSet, storage: &StorageSet, mut m: Vec<f64>) -> Vec<f64> {
    let s = storage.len();
    for i in 0..prop.len() {
        for d in 0..s {
            m[i * s + d] *= prop.directions[i].solid_angle / storage.solid_angle[d];
        }
    }
    m
}

/// The collect row of a collimated beam travelling along `travel`: `P(beam→d)/Ω_d`, so that a
/// segment-average irradiance Ē scatters into J^d = σs·Ē·row\[d\].
pub fn beam_row(prop: &PropagationSet, storage: &StorageSet, phase: &Phase, travel: DVec3) -> Vec<f64> {
    BeamRows::new(prop, storage, phase).row(travel)
}

/// [`beam_row`] for many beam directions (a point light's, one per voxel): the fine quadrature of
/// the sphere is built once.
pub struct BeamRows {
    /// The fine quadrature, `None` when the row is the isotropic one whatever the direction.
    sub: Option<SubCells>,
    owner: Vec<u32>,
    solid_angle: Vec<f64>,
    phase: Phase,
}

impl BeamRows {
    pub fn new(prop: &PropagationSet, storage: &StorageSet, phase: &Phase) -> Self {
        let isotropic = phase.is_isotropic() || storage.is_isotropic();
        BeamRows {
            sub: (!isotropic).then(|| SubCells::new(prop, refinement(prop).max(4))),
            owner: storage.owner.clone(),
            solid_angle: storage.solid_angle.clone(),
            phase: *phase,
        }
    }

    /// The row of a beam travelling along `travel` (unit length; ignored when isotropic).
    pub fn row(&self, travel: DVec3) -> Vec<f64> {
        let s = self.solid_angle.len();
        let mut p = vec![0.0; s];
        match &self.sub {
            None => {
                let total: f64 = self.solid_angle.iter().sum();
                for d in 0..s {
                    p[d] = self.solid_angle[d] / total;
                }
            }
            Some(sub) => {
                p = self.phase.mix(|part| {
                    let mut q = vec![0.0; s];
                    for &(wb, ob, ib) in &sub.samples {
                        q[self.owner[ib] as usize] += ob * part.value(travel.dot(wb));
                    }
                    normalise_rows(&mut q, s);
                    q
                });
            }
        }
        p.iter().zip(&self.solid_angle).map(|(p, w)| p / w).collect()
    }

    /// Whether every beam has the same row (g = 0 or a single storage direction).
    pub fn is_isotropic(&self) -> bool {
        self.sub.is_none()
    }

    /// Storage directions (the length of a row).
    pub fn storage_len(&self) -> usize {
        self.solid_angle.len()
    }

    /// The row of light arriving from every direction alike (no preferred direction of travel):
    /// `1/4π` in every storage direction.
    pub fn isotropic_row(&self) -> Vec<f64> {
        let total: f64 = self.solid_angle.iter().sum();
        vec![1.0 / total; self.solid_angle.len()]
    }
}

fn normalise_rows(p: &mut [f64], s: usize) {
    for row in p.chunks_mut(s) {
        let sum: f64 = row.iter().sum();
        if sum > 0.0 {
            row.iter_mut().for_each(|v| *v /= sum);
        }
    }
}

/// The mean cosine of the discrete scattering (Σ_d P(i→d)·ω_i·ω_d, solid-angle weighted over i);
/// close to g when the storage set resolves the phase function.
pub fn discrete_mean_cosine(prop: &PropagationSet, storage: &StorageSet, m: &[f64]) -> f64 {
    let s = storage.len();
    let mut num = 0.0;
    let mut den = 0.0;
    for (i, d) in prop.directions.iter().enumerate() {
        for j in 0..s {
            let prob = m[i * s + j] * storage.solid_angle[j] / d.solid_angle;
            num += d.solid_angle * prob * d.omega.dot(storage.omega[j]);
        }
        den += d.solid_angle;
    }
    num / den
}

/// The mean cosine of scattering as the rays see it: from propagation direction i into the
/// storage cell d and, since every propagation direction j owned by d gains d's source, on into
/// each such j in proportion to its solid angle. This includes the smearing of the peak over the
/// storage cell, so it is the g the discrete solve behaves like (`discrete_mean_cosine` uses the
/// storage cells' mean directions, which hides that smearing).
pub fn effective_mean_cosine(prop: &PropagationSet, storage: &StorageSet, m: &[f64]) -> f64 {
    let s = storage.len();
    let mut num = 0.0;
    let mut den = 0.0;
    for (i, di) in prop.directions.iter().enumerate() {
        // P_eff(i → j) = M[i][owner(j)]·Ω_j/Ω_i.
        let mut sum = 0.0;
        for (j, dj) in prop.directions.iter().enumerate() {
            let d = storage.owner[j] as usize;
            sum += m[i * s + d] * dj.solid_angle * di.omega.dot(dj.omega);
        }
        num += sum;
        den += di.solid_angle;
    }
    num / den
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row_power(m: &[f64], storage: &StorageSet, i: usize) -> f64 {
        let s = storage.len();
        (0..s).map(|d| m[i * s + d] * storage.solid_angle[d]).sum()
    }

    #[test]
    fn hg_integrates_to_one() {
        let prop = PropagationSet::new(8);
        let sub = SubCells::new(&prop, 4);
        for g in [-0.9, 0.0, 0.5, 0.8] {
            let axis = DVec3::new(0.2, 0.3, 0.9).normalize();
            let sum: f64 = sub.samples.iter().map(|(w, o, _)| o * henyey_greenstein(g, axis.dot(*w))).sum();
            assert!((sum - 1.0).abs() < 2e-3, "g={g}: {sum}");
        }
    }

    #[test]
    fn scattering_conserves_energy_per_direction() {
        let prop = PropagationSet::new(4);
        for (storage, g) in [
            (StorageSet::isotropic(&prop), 0.0),
            (StorageSet::per_face(&prop, 2), 0.7),
            (StorageSet::per_face(&prop, 4), -0.5),
            (StorageSet::per_face(&prop, 1), 0.99),
        ] {
            let m = collect_matrix(&prop, &storage, &Phase::HenyeyGreenstein { g });
            for i in 0..prop.len() {
                let w = prop.directions[i].solid_angle;
                assert!((row_power(&m, &storage, i) - w).abs() < 1e-13 * w.max(1.0));
            }
            let beam =
                beam_row(&prop, &storage, &Phase::HenyeyGreenstein { g }, DVec3::new(0.1, -0.4, 0.9).normalize());
            let p: f64 = beam.iter().zip(&storage.solid_angle).map(|(r, w)| r * w).sum();
            assert!((p - 1.0).abs() < 1e-13);
        }
    }

    #[test]
    fn effective_mean_cosine_is_zero_for_isotropic_and_below_g_for_a_peak() {
        let prop = PropagationSet::new(4);
        let iso = StorageSet::isotropic(&prop);
        let m = collect_matrix(&prop, &iso, &Phase::HenyeyGreenstein { g: 0.0 });
        assert!(effective_mean_cosine(&prop, &iso, &m).abs() < 1e-12);
        let storage = StorageSet::per_face(&prop, 2);
        let m = collect_matrix(&prop, &storage, &Phase::HenyeyGreenstein { g: 0.8 });
        let g = effective_mean_cosine(&prop, &storage, &m);
        // 2×2 storage cells per face smear the peak: the discrete scattering is much wider.
        assert!(g > 0.4 && g < 0.78, "{g}");
    }

    #[test]
    fn discrete_mean_cosine_follows_g() {
        let prop = PropagationSet::new(6);
        let storage = StorageSet::per_face(&prop, 6);
        for g in [0.0, 0.3, 0.6] {
            let m = collect_matrix(&prop, &storage, &Phase::HenyeyGreenstein { g });
            let mu = discrete_mean_cosine(&prop, &storage, &m);
            assert!((mu - g).abs() < 0.05, "g={g}: mean cosine {mu}");
        }
    }

    #[test]
    fn hg_cone_moments_match_quadrature() {
        for (g, cone) in [(0.85, 0.9167), (0.5, 0.6), (0.95, 0.99), (1e-9, 0.3)] {
            let steps = 200_000;
            let (mut mass, mut moment) = (0.0, 0.0);
            for i in 0..steps {
                let mu = cone + (1.0 - cone) * (i as f64 + 0.5) / steps as f64;
                let w = 2.0 * PI * henyey_greenstein(g, mu) * (1.0 - cone) / steps as f64;
                mass += w;
                moment += w * mu;
            }
            let (m, f) = hg_cone_moments(g, cone);
            assert!((m - mass).abs() < 1e-6 && (f - moment).abs() < 1e-6, "g {g}: {m} {mass}, {f} {moment}");
        }
    }

    #[test]
    fn the_truncated_remainder_keeps_the_transport_cross_section_and_the_shape_outside_the_cone() {
        let prop = PropagationSet::new(5);
        for (ks, g) in [(2, 0.85), (2, 0.95), (3, 0.6), (1, 0.8)] {
            let storage = StorageSet::per_face(&prop, ks);
            let t = Truncation::for_sets(g, &prop, &storage);
            assert!(t.fraction > 0.0 && t.fraction <= t.peak && t.peak < 1.0, "{t:?}");
            let m = collect_matrix(&prop, &storage, &Phase::Truncated(t));
            for i in 0..prop.len() {
                let w = prop.directions[i].solid_angle;
                assert!((row_power(&m, &storage, i) - w).abs() < 1e-12 * w.max(1.0));
            }
            // The discrete scattering's transport cross-section is the true one.
            let g_eff = effective_mean_cosine(&prop, &storage, &m);
            assert!(((1.0 - t.fraction) * (1.0 - g_eff) - (1.0 - g)).abs() < 1e-9, "{t:?}: ḡ {g_eff}");
            // Outside the cone σs'·p' = σs·p: (1 − f)·p_remainder = HG(g) there (the part's
            // weight over its mass 1 − C is the remainder's density per unit of HG(g)).
            let parts = Phase::Truncated(t).parts();
            let (outside_weight, _) = parts[0];
            assert!(((1.0 - t.fraction) * outside_weight / (1.0 - t.peak) - 1.0).abs() < 1e-12);
            // Its continuous mean cosine lies between g' of classic δ-M and g.
            let g_rem = t.remainder_g();
            assert!(g_rem > 0.0 && g_rem < g, "{g_rem}");
        }
    }

    #[test]
    fn without_the_storage_cells_widening_the_fraction_is_the_continuous_one() {
        // For a cone of cosine c the continuous condition gives f = C·(2μ_C − 1 − c)/(1 − c), μ_C
        // the mean cosine of HG(g) in the cone: 0.316 for g = 0.85 and a 23.6° cone (one of 24
        // cells), where C = 0.685.
        let (g, cone) = (0.85, 1.0 - 2.0 / 24.0);
        let (peak, moment) = hg_cone_moments(g, cone);
        let f = peak * (2.0 * moment / peak - 1.0 - cone) / (1.0 - cone);
        assert!((peak - 0.685).abs() < 2e-3 && (f - 0.316).abs() < 2e-3, "C {peak} f {f}");
        let t = Truncation { g, cone, peak, fraction: f };
        assert!(((1.0 - f) * (1.0 - t.remainder_g()) - (1.0 - g)).abs() < 1e-12);
    }
}
