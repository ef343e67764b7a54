//! Henyey–Greenstein scattering between discrete direction cells.
//!
//! The collect step turns each propagation direction's segment-average radiance L̄_i into the next
//! order's source J^d = σs · Σ_i M\[i\]\[d\] · L̄_i with `M[i][d] = Ω_i·P(i→d)/Ω_d`. P(i→d) is the phase
//! function integrated over both cells (by sub-cell quadrature with exact sub-cell solid angles), each
//! row normalised to sum to 1 so that Σ_d Ω_d J^d = σs Σ_i Ω_i L̄_i: the discrete scattering neither
//! creates nor loses energy, whatever the quadrature error of P itself. For g = 0 the exact value
//! P(i→d) = Ω_d/4π is used.

use super::{cube_face, PropagationSet, StorageSet, FACES};
use glam::DVec3;
use std::f64::consts::PI;

/// Henyey–Greenstein phase function, normalised over the sphere, of the cosine between the incident
/// and the scattered directions of travel.
pub fn henyey_greenstein(g: f64, cos_theta: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
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
pub fn collect_matrix(prop: &PropagationSet, storage: &StorageSet, g: f64) -> Vec<f64> {
    let n = prop.len();
    let s = storage.len();
    let mut p = vec![0.0; n * s];
    if g == 0.0 || storage.is_isotropic() {
        // Isotropic scattering, or a single storage direction: P(i→d) = Ω_d / 4π exactly.
        let total: f64 = storage.solid_angle.iter().sum();
        for i in 0..n {
            for d in 0..s {
                p[i * s + d] = storage.solid_angle[d] / total;
            }
        }
    } else {
        let sub = SubCells::new(prop, refinement(prop));
        for &(wa, oa, ia) in &sub.samples {
            for &(wb, ob, ib) in &sub.samples {
                let d = storage.owner[ib] as usize;
                p[ia * s + d] += oa * ob * henyey_greenstein(g, wa.dot(wb));
            }
        }
        normalise_rows(&mut p, s);
    }
    let mut m = p;
    for i in 0..n {
        for d in 0..s {
            m[i * s + d] *= prop.directions[i].solid_angle / storage.solid_angle[d];
        }
    }
    m
}

/// The collect row of a collimated beam travelling along `travel`: `P(beam→d)/Ω_d`, so that a
/// segment-average irradiance Ē scatters into J^d = σs·Ē·row\[d\].
pub fn beam_row(prop: &PropagationSet, storage: &StorageSet, g: f64, travel: DVec3) -> Vec<f64> {
    BeamRows::new(prop, storage, g).row(travel)
}

/// [`beam_row`] for many beam directions (a point light's, one per voxel): the fine quadrature of
/// the sphere is built once.
pub struct BeamRows {
    /// The fine quadrature, `None` when the row is the isotropic one whatever the direction.
    sub: Option<SubCells>,
    owner: Vec<u32>,
    solid_angle: Vec<f64>,
    g: f64,
}

impl BeamRows {
    pub fn new(prop: &PropagationSet, storage: &StorageSet, g: f64) -> Self {
        let isotropic = g == 0.0 || storage.is_isotropic();
        BeamRows {
            sub: (!isotropic).then(|| SubCells::new(prop, refinement(prop).max(4))),
            owner: storage.owner.clone(),
            solid_angle: storage.solid_angle.clone(),
            g,
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
                for &(wb, ob, ib) in &sub.samples {
                    p[self.owner[ib] as usize] += ob * henyey_greenstein(self.g, travel.dot(wb));
                }
                normalise_rows(&mut p, s);
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
            let m = collect_matrix(&prop, &storage, g);
            for i in 0..prop.len() {
                let w = prop.directions[i].solid_angle;
                assert!((row_power(&m, &storage, i) - w).abs() < 1e-13 * w.max(1.0));
            }
            let beam = beam_row(&prop, &storage, g, DVec3::new(0.1, -0.4, 0.9).normalize());
            let p: f64 = beam.iter().zip(&storage.solid_angle).map(|(r, w)| r * w).sum();
            assert!((p - 1.0).abs() < 1e-13);
        }
    }

    #[test]
    fn effective_mean_cosine_is_zero_for_isotropic_and_below_g_for_a_peak() {
        let prop = PropagationSet::new(4);
        let iso = StorageSet::isotropic(&prop);
        let m = collect_matrix(&prop, &iso, 0.0);
        assert!(effective_mean_cosine(&prop, &iso, &m).abs() < 1e-12);
        let storage = StorageSet::per_face(&prop, 2);
        let m = collect_matrix(&prop, &storage, 0.8);
        let g = effective_mean_cosine(&prop, &storage, &m);
        // 2×2 storage cells per face smear the peak: the discrete scattering is much wider.
        assert!(g > 0.4 && g < 0.78, "{g}");
    }

    #[test]
    fn discrete_mean_cosine_follows_g() {
        let prop = PropagationSet::new(6);
        let storage = StorageSet::per_face(&prop, 6);
        for g in [0.0, 0.3, 0.6] {
            let m = collect_matrix(&prop, &storage, g);
            let mu = discrete_mean_cosine(&prop, &storage, &m);
            assert!((mu - g).abs() < 0.05, "g={g}: mean cosine {mu}");
        }
    }
}
