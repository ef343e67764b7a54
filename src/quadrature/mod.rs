//! Directions: the propagation set, the storage set, and the phase tables between them.
//!
//! Propagation directions come from a cube-face parametrisation: each of the six faces of the cube
//! [−1, 1]³ is split into k×k equal cells in its (u, v) coordinates, and a cell's direction is its
//! centre, normalised. The solid angle of a cell is exact (`cell_solid_angle`), so the weights of all
//! 6k² directions sum to 4π to round-off and a uniform radiance integrates exactly.
//!
//! Storage directions (where the in-scattered source J is kept per voxel) are coarser. Each storage
//! direction owns a *union of propagation cells* (on a face, the k_s×k_s grid cell that holds the
//! propagation cell's centre), and its solid angle is the sum of theirs. Defining storage cells this
//! way (instead of as their own geometric cells) is what makes the discrete scattering conserve
//! energy exactly: a ray of direction i gains the source of the storage direction that owns i, and the
//! power emitted over the cells of d is J^d·Ω_d by construction. An isotropic medium needs a single
//! storage direction (the whole sphere).
//!
//! A camera ray needs the source for its own direction, between the storage directions: [`blend`]
//! weighs the few storage directions around it (barycentric weights on a mesh of the storage
//! directions), so the rendered source is continuous in direction instead of jumping at a storage
//! cell's boundary.
//!
//! [`phase`] builds the collect matrix `M[i][d] = Ω_i·P(i→d)/Ω_d`, where P(i→d) is the probability
//! that light travelling along cell i scatters into cell d (Henyey–Greenstein, integrated over both
//! cells, rows normalised to sum to 1 so scattering conserves energy exactly in the discrete set),
//! or, under δ-M scaling, what HG is left with once its forward peak joins the unscattered light
//! ([`phase::Truncation`]).

pub mod blend;
mod cube_face;
pub mod phase;

pub use blend::{Blend, StorageBlend};
pub use cube_face::{cell_solid_angle, Face, FACES};

/// The face (0..6) a direction of travel belongs to (its dominant axis and sign).
pub fn cube_face_of(omega: DVec3) -> usize {
    cube_face::project(omega).0
}

use glam::DVec3;

/// One propagation direction (a cell of a cube face).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Direction {
    /// Index of the face (0..6, see [`FACES`]).
    pub face: usize,
    /// Cell indices along the face's lateral axes (b, c).
    pub cell: [u32; 2],
    /// Unit direction of travel (the normalised cell centre).
    pub omega: DVec3,
    /// Exact solid angle of the cell (sr).
    pub solid_angle: f64,
}

/// The 6k² propagation directions, face-major (all of face 0, then face 1, …), within a face cell c
/// fastest then b.
#[derive(Clone, Debug)]
pub struct PropagationSet {
    pub k: u32,
    pub directions: Vec<Direction>,
}

impl PropagationSet {
    pub fn new(k: u32) -> Self {
        assert!(k >= 1, "directions per face must be at least 1");
        let mut directions = Vec::with_capacity(6 * (k * k) as usize);
        for (face_index, face) in FACES.iter().enumerate() {
            for cb in 0..k {
                for cc in 0..k {
                    let (u0, u1) = cube_face::cell_bounds(cb, k);
                    let (v0, v1) = cube_face::cell_bounds(cc, k);
                    directions.push(Direction {
                        face: face_index,
                        cell: [cb, cc],
                        omega: face.direction(0.5 * (u0 + u1), 0.5 * (v0 + v1)),
                        solid_angle: cell_solid_angle(u0, u1, v0, v1),
                    });
                }
            }
        }
        PropagationSet { k, directions }
    }

    pub fn len(&self) -> usize {
        self.directions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// Directions per face (k²).
    pub fn per_face(&self) -> usize {
        (self.k * self.k) as usize
    }

    /// The directions of one face.
    pub fn face(&self, face: usize) -> &[Direction] {
        let n = self.per_face();
        &self.directions[face * n..(face + 1) * n]
    }

    /// Index of the propagation cell that contains the direction `omega` (need not be normalised).
    pub fn containing(&self, omega: DVec3) -> usize {
        let (face, u, v) = cube_face::project(omega);
        let k = self.k;
        let cb = cube_face::cell_of(u, k);
        let cc = cube_face::cell_of(v, k);
        face * self.per_face() + (cb * k + cc) as usize
    }
}

/// The storage directions for the in-scattered source, each a union of propagation cells.
#[derive(Clone, Debug)]
pub struct StorageSet {
    /// Storage cells per face edge; 0 means a single storage direction for the whole sphere
    /// (isotropic media).
    pub per_face: u32,
    /// Storage index owning each propagation direction.
    pub owner: Vec<u32>,
    /// Solid angle of each storage direction (the sum over the propagation cells it owns).
    pub solid_angle: Vec<f64>,
    /// Representative direction of each storage cell (its solid-angle-weighted mean, normalised);
    /// zero for the isotropic set.
    pub omega: Vec<DVec3>,
}

impl StorageSet {
    /// One storage direction: the source is the same in every direction.
    pub fn isotropic(prop: &PropagationSet) -> Self {
        StorageSet {
            per_face: 0,
            owner: vec![0; prop.len()],
            solid_angle: vec![prop.directions.iter().map(|d| d.solid_angle).sum()],
            omega: vec![DVec3::ZERO],
        }
    }

    /// `ks`×`ks` storage cells per face (1 ≤ ks ≤ k).
    pub fn per_face(prop: &PropagationSet, ks: u32) -> Self {
        assert!(ks >= 1 && ks <= prop.k, "storage directions per face must be in 1..=k");
        let k = prop.k;
        let count = 6 * (ks * ks) as usize;
        let mut owner = Vec::with_capacity(prop.len());
        let mut solid_angle = vec![0.0; count];
        let mut mean = vec![DVec3::ZERO; count];
        for d in &prop.directions {
            // The storage cell holding the propagation cell's centre, in exact integer arithmetic:
            // centre u = −1 + (2c+1)/k, storage cell = floor((u+1)/2·ks) = floor((2c+1)·ks / 2k).
            let sb = (2 * d.cell[0] + 1) * ks / (2 * k);
            let sc = (2 * d.cell[1] + 1) * ks / (2 * k);
            let s = d.face * (ks * ks) as usize + (sb * ks + sc) as usize;
            owner.push(s as u32);
            solid_angle[s] += d.solid_angle;
            mean[s] += d.omega * d.solid_angle;
        }
        let omega = mean.into_iter().map(|m| m.normalize()).collect();
        StorageSet { per_face: ks, owner, solid_angle, omega }
    }

    pub fn len(&self) -> usize {
        self.solid_angle.len()
    }

    pub fn is_empty(&self) -> bool {
        self.solid_angle.is_empty()
    }

    pub fn is_isotropic(&self) -> bool {
        self.per_face == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn solid_angles_sum_to_four_pi() {
        for k in [1, 2, 3, 5, 8, 17] {
            let set = PropagationSet::new(k);
            let sum: f64 = set.directions.iter().map(|d| d.solid_angle).sum();
            assert!((sum - 4.0 * PI).abs() < 1e-12, "k={k}: {sum}");
            assert_eq!(set.len(), 6 * (k * k) as usize);
        }
    }

    #[test]
    fn every_direction_lies_in_its_own_cell_and_on_its_face() {
        let set = PropagationSet::new(5);
        for (i, d) in set.directions.iter().enumerate() {
            assert_eq!(set.containing(d.omega), i);
            let f = FACES[d.face];
            assert!(d.omega[f.axis] * f.sign > 0.0);
            assert!((d.omega.length() - 1.0).abs() < 1e-14);
        }
    }

    #[test]
    fn storage_cells_partition_the_propagation_cells() {
        let prop = PropagationSet::new(5);
        for ks in 1..=5 {
            let st = StorageSet::per_face(&prop, ks);
            assert_eq!(st.len(), 6 * (ks * ks) as usize);
            let sum: f64 = st.solid_angle.iter().sum();
            assert!((sum - 4.0 * PI).abs() < 1e-12);
            assert!(st.solid_angle.iter().all(|&w| w > 0.0), "every storage cell owns a direction");
        }
        let iso = StorageSet::isotropic(&prop);
        assert_eq!(iso.len(), 1);
        assert!((iso.solid_angle[0] - 4.0 * PI).abs() < 1e-12);
    }
}
