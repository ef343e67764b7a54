//! The in-scattered source between storage directions: weights that blend the stored source of a
//! few storage directions into the source for any direction, continuously.
//!
//! Why: the source is stored for a few directions (k_s×k_s per cube face), and a camera ray needs it
//! for its own direction. Taking the storage direction whose cell holds the ray's direction makes
//! the image jump wherever neighbouring pixels' rays fall into different cells: a pinhole camera
//! sees a cell boundary (a great circle) as a straight seam across the image, and on a face lit
//! from one side as bands. Blending makes the source a continuous function of direction.
//!
//! How: the storage directions (each cell's solid-angle-weighted mean direction) are the vertices of
//! a closed triangle mesh around the origin, laid out by the cube's structure, so it needs no
//! general hull algorithm and has no ties to break:
//!
//! - on each face, the (k_s−1)² quads between neighbouring cells, two triangles each;
//! - across each of the 12 cube edges, the k_s−1 quads between the two faces' border rows;
//! - at each of the 8 cube corners, the triangle of the three faces' corner cells.
//!
//! That is 12·k_s² − 4 triangles, as a closed mesh of 6·k_s² vertices has (Euler). Each triangle
//! spans a cone from the origin; the cones tile the sphere (tested: their solid angles sum to 4π).
//! A direction's weights are its barycentric coordinates in the cone that holds it (ω = αa + βb + γc
//! with α, β, γ ≥ 0, normalised to sum to 1: the barycentric coordinates of the point where the ray
//! meets the triangle's plane). So the weights are non-negative, sum to 1, are exactly 1 at a
//! storage direction (the stored value is reproduced there) and are continuous everywhere: on an
//! edge shared by two triangles both give the same two weights, the third being zero.
//!
//! An isotropic set (one storage direction) blends nothing: weight 1 on direction 0, so an
//! isotropic image is bitwise what it was without blending.

use super::{cube_face::FACES, StorageSet};
use glam::{DMat3, DVec3};

/// Up to three storage directions and their weights (non-negative, summing to 1); entries past
/// `len` are unused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blend {
    pub index: [u32; 3],
    pub weight: [f64; 3],
    pub len: usize,
}

impl Blend {
    /// All of the weight on storage direction `d`.
    pub fn single(d: u32) -> Self {
        Blend { index: [d, 0, 0], weight: [1.0, 0.0, 0.0], len: 1 }
    }

    /// The (storage direction, weight) pairs in use.
    pub fn entries(&self) -> impl Iterator<Item = (u32, f64)> + '_ {
        self.index.iter().copied().zip(self.weight.iter().copied()).take(self.len)
    }
}

/// One cone of the mesh: its three storage directions and the inverse of the matrix whose columns
/// are their unit vectors (so `inverse · ω` gives ω's coordinates in that basis).
#[derive(Clone, Debug)]
struct Cone {
    vertex: [u32; 3],
    inverse: DMat3,
}

/// Blending weights over a [`StorageSet`]'s directions.
#[derive(Clone, Debug)]
pub struct StorageBlend {
    cones: Vec<Cone>,
}

impl StorageBlend {
    pub fn new(storage: &StorageSet) -> Self {
        if storage.is_isotropic() {
            return StorageBlend { cones: Vec::new() };
        }
        let ks = storage.per_face;
        let last = ks - 1;
        // Storage index of the cell of `face` at position `at[axis]` along each of its lateral axes
        // (the face's own axis entry is ignored).
        let node = |face: usize, at: [u32; 3]| -> u32 {
            let [b, c] = FACES[face].lateral;
            face as u32 * ks * ks + at[b] * ks + at[c]
        };
        // The index at the `sign` end of an axis (the cells next to that cube edge).
        let end = |sign: f64| if sign > 0.0 { last } else { 0 };
        let mut triangles: Vec<[u32; 3]> = Vec::with_capacity((12 * ks * ks - 4) as usize);
        let mut quad = |q: [u32; 4]| {
            triangles.push([q[0], q[1], q[2]]);
            triangles.push([q[0], q[2], q[3]]);
        };
        // Within each face: the quads between neighbouring cell centres.
        for face in 0..6 {
            let [b, c] = FACES[face].lateral;
            for i in 0..last {
                for j in 0..last {
                    let at = |di: u32, dj: u32| {
                        let mut a = [0; 3];
                        a[b] = i + di;
                        a[c] = j + dj;
                        node(face, a)
                    };
                    quad([at(0, 0), at(1, 0), at(1, 1), at(0, 1)]);
                }
            }
        }
        // Across each cube edge: faces A (axis a) and B (axis b) meet where the direction is at
        // A's sign along a and B's along b; both faces run along the third axis c the same way.
        for (fa, a_face) in FACES.iter().enumerate() {
            for (fb, b_face) in FACES.iter().enumerate().skip(fa + 1) {
                let (a, b) = (a_face.axis, b_face.axis);
                if a == b {
                    continue;
                }
                let c = 3 - a - b;
                let row = |face: usize, j: u32| {
                    let mut at = [0; 3];
                    at[a] = end(a_face.sign);
                    at[b] = end(b_face.sign);
                    at[c] = j;
                    node(face, at)
                };
                for j in 0..last {
                    quad([row(fa, j), row(fa, j + 1), row(fb, j + 1), row(fb, j)]);
                }
            }
        }
        // At each cube corner: the three faces' cells nearest to it.
        for corner in 0..8u32 {
            let sign = [0, 1, 2].map(|axis| if corner >> axis & 1 == 1 { 1.0 } else { -1.0 });
            let at = sign.map(end);
            let face = |axis: usize| 2 * axis + usize::from(sign[axis] < 0.0);
            triangles.push([node(face(0), at), node(face(1), at), node(face(2), at)]);
        }
        let cones = triangles
            .into_iter()
            .map(|mut v| {
                let col = |i: u32| storage.omega[i as usize];
                // Outward orientation, so every cone's solid angle counts positive.
                if col(v[0]).dot(col(v[1]).cross(col(v[2]))) < 0.0 {
                    v.swap(1, 2);
                }
                Cone { vertex: v, inverse: DMat3::from_cols(col(v[0]), col(v[1]), col(v[2])).inverse() }
            })
            .collect();
        StorageBlend { cones }
    }

    /// The weights of the storage directions for a direction of travel `omega` (need not be
    /// normalised; zero or non-finite gets storage direction 0).
    pub fn weights(&self, omega: DVec3) -> Blend {
        if self.cones.is_empty() || !omega.is_finite() || omega == DVec3::ZERO {
            return Blend::single(0);
        }
        // The cone holding ω has all three coordinates ≥ 0; round-off may leave a direction on a
        // shared edge slightly negative in every cone, so take the cone whose smallest coordinate
        // is largest (a cone on the far side of the sphere has all three negative).
        let mut best = (f64::NEG_INFINITY, 0usize, DVec3::ZERO);
        for (i, cone) in self.cones.iter().enumerate() {
            let x = cone.inverse * omega;
            let low = x.min_element();
            if low > best.0 {
                best = (low, i, x);
            }
        }
        let (_, i, x) = best;
        let x = x.max(DVec3::ZERO);
        let sum = x.x + x.y + x.z;
        if !(sum > 0.0) {
            return Blend::single(self.cones[i].vertex[0]);
        }
        Blend { index: self.cones[i].vertex, weight: (x / sum).to_array(), len: 3 }
    }

    /// Number of cones in the mesh (0 for an isotropic set).
    pub fn cone_count(&self) -> usize {
        self.cones.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::PropagationSet;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    /// Solid angle of the spherical triangle (a, b, c) (Van Oosterom–Strackee), signed by orientation.
    fn solid_angle(a: DVec3, b: DVec3, c: DVec3) -> f64 {
        let num = a.dot(b.cross(c));
        let den = 1.0 + a.dot(b) + b.dot(c) + c.dot(a);
        2.0 * num.atan2(den)
    }

    fn sets() -> Vec<StorageSet> {
        let mut out = Vec::new();
        for k in [1, 2, 3, 4, 5, 8] {
            let prop = PropagationSet::new(k);
            for ks in 1..=k.min(5) {
                out.push(StorageSet::per_face(&prop, ks));
            }
        }
        out
    }

    #[test]
    fn the_cones_tile_the_sphere() {
        for storage in sets() {
            let blend = StorageBlend::new(&storage);
            let ks = storage.per_face;
            assert_eq!(blend.cone_count() as u32, 12 * ks * ks - 4, "ks {ks}");
            let mut total = 0.0;
            for cone in &blend.cones {
                let [a, b, c] = cone.vertex.map(|i| storage.omega[i as usize]);
                let w = solid_angle(a, b, c);
                assert!(w > 0.0, "ks {ks}: cone {:?} is not outward", cone.vertex);
                total += w;
            }
            assert!((total - 4.0 * PI).abs() < 1e-9, "ks {ks}: {total}");
        }
    }

    #[test]
    fn a_storage_direction_gets_all_the_weight() {
        for storage in sets() {
            let blend = StorageBlend::new(&storage);
            for (d, &omega) in storage.omega.iter().enumerate() {
                let w = blend.weights(omega);
                let own: f64 = w.entries().filter(|&(i, _)| i as usize == d).map(|(_, w)| w).sum();
                assert!((own - 1.0).abs() < 1e-12, "ks {}: {d} {w:?}", storage.per_face);
            }
        }
    }

    #[test]
    fn isotropic_is_a_single_weight_of_one() {
        let iso = StorageSet::isotropic(&PropagationSet::new(4));
        let blend = StorageBlend::new(&iso);
        for omega in [DVec3::X, DVec3::new(-0.3, 0.2, 0.9), DVec3::ZERO, DVec3::NAN] {
            assert_eq!(blend.weights(omega), Blend::single(0));
        }
    }

    /// Directions on cube edges and at corners, where three or four cells meet.
    #[test]
    fn cube_edges_and_corners_blend_their_neighbours() {
        for storage in sets() {
            let blend = StorageBlend::new(&storage);
            for omega in [
                DVec3::ONE,
                DVec3::new(-1.0, 1.0, -1.0),
                DVec3::new(1.0, 1.0, 0.0),
                DVec3::new(0.0, -1.0, 1.0),
                DVec3::new(1.0, 0.3, -1.0),
                DVec3::X,
                DVec3::NEG_Z,
            ] {
                let w = blend.weights(omega);
                let sum: f64 = w.entries().map(|e| e.1).sum();
                assert!((sum - 1.0).abs() < 1e-14 && w.entries().all(|e| e.1 >= 0.0), "{omega}: {w:?}");
                // The blend points where ω points: its weighted mean direction is near ω.
                let mean: DVec3 = w.entries().map(|(i, x)| storage.omega[i as usize] * x).sum();
                assert!(mean.normalize().dot(omega.normalize()) > 0.8, "{omega}: {w:?}");
            }
        }
    }

    fn direction() -> impl Strategy<Value = DVec3> {
        // Uniform on the sphere, plus directions snapped onto cube edges and corners.
        (-1.0f64..1.0, 0.0f64..(2.0 * PI), 0u8..4).prop_map(|(z, phi, snap)| {
            let r = (1.0 - z * z).sqrt();
            let mut w = DVec3::new(r * phi.cos(), r * phi.sin(), z);
            let m = w.abs().max_element();
            if snap >= 1 {
                // The largest component's partner takes the same magnitude: a cube edge.
                let a = w.abs().to_array();
                let top = (0..3).max_by(|&i, &j| a[i].total_cmp(&a[j])).unwrap_or(0);
                let next = (0..3).filter(|&i| i != top).max_by(|&i, &j| a[i].total_cmp(&a[j])).unwrap_or(0);
                w[next] = m.copysign(w[next]);
                if snap >= 2 {
                    w = w.signum() * m; // a corner
                }
            }
            w
        })
    }

    proptest! {
        #[test]
        fn weights_are_non_negative_sum_to_one_and_change_little_for_a_small_turn(
            omega in direction(),
            turn in proptest::array::uniform3(-1.0f64..1.0),
            set in 0usize..24,
        ) {
            let sets = sets();
            let storage = &sets[set % sets.len()];
            let blend = StorageBlend::new(storage);
            let w = blend.weights(omega);
            let sum: f64 = w.entries().map(|e| e.1).sum();
            prop_assert!((sum - 1.0).abs() < 1e-14, "{:?}", w);
            prop_assert!(w.entries().all(|(i, x)| x >= 0.0 && (i as usize) < storage.len()), "{:?}", w);
            // Continuity: a turn by ε changes each weight by O(ε) (the bound is a generous
            // Lipschitz constant for the finest mesh tested; nearest-cell jumps by 1).
            let eps = 1e-6;
            let moved = omega.normalize() + DVec3::from_array(turn) * eps;
            let dense = |b: Blend| {
                let mut v = vec![0.0; storage.len()];
                for (i, x) in b.entries() {
                    v[i as usize] += x;
                }
                v
            };
            let (a, b) = (dense(w), dense(blend.weights(moved)));
            let change = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            prop_assert!(change < 100.0 * eps, "{omega} change {change}");
        }
    }
}
