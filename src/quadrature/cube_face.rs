//! The cube-face parametrisation of the sphere of directions.

use glam::DVec3;

/// A face of the direction cube: the directions whose largest component is along `axis` with `sign`.
/// Its lateral axes (b, c) are the other two axes in increasing order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Face {
    pub axis: usize,
    pub sign: f64,
    pub lateral: [usize; 2],
}

/// +X, −X, +Y, −Y, +Z, −Z.
pub const FACES: [Face; 6] = [
    Face { axis: 0, sign: 1.0, lateral: [1, 2] },
    Face { axis: 0, sign: -1.0, lateral: [1, 2] },
    Face { axis: 1, sign: 1.0, lateral: [0, 2] },
    Face { axis: 1, sign: -1.0, lateral: [0, 2] },
    Face { axis: 2, sign: 1.0, lateral: [0, 1] },
    Face { axis: 2, sign: -1.0, lateral: [0, 1] },
];

impl Face {
    /// The unit direction through the face point (u, v) ∈ [−1, 1]² (u along b, v along c).
    pub fn direction(&self, u: f64, v: f64) -> DVec3 {
        let mut w = [0.0; 3];
        w[self.axis] = self.sign;
        w[self.lateral[0]] = u;
        w[self.lateral[1]] = v;
        DVec3::from_array(w).normalize()
    }
}

/// Bounds of cell `i` of `k` along one face axis.
pub fn cell_bounds(i: u32, k: u32) -> (f64, f64) {
    let w = 2.0 / k as f64;
    (-1.0 + w * i as f64, -1.0 + w * (i + 1) as f64)
}

/// The cell of `k` holding coordinate `u` ∈ [−1, 1] (the upper edge belongs to the last cell).
pub fn cell_of(u: f64, k: u32) -> u32 {
    let c = ((u + 1.0) * 0.5 * k as f64).floor();
    c.clamp(0.0, (k - 1) as f64) as u32
}

/// The face a direction falls on and its (u, v) coordinates there. Ties between axes go to the
/// lower axis index, so every direction has exactly one face.
pub fn project(omega: DVec3) -> (usize, f64, f64) {
    let a = omega.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let w = omega.to_array();
    let face = 2 * axis + usize::from(w[axis] < 0.0);
    let f = FACES[face];
    let m = w[axis].abs();
    (face, w[f.lateral[0]] / m, w[f.lateral[1]] / m)
}

/// Exact solid angle subtended by the rectangle [u0, u1]×[v0, v1] on a cube face at unit distance.
pub fn cell_solid_angle(u0: f64, u1: f64, v0: f64, v1: f64) -> f64 {
    let g = |u: f64, v: f64| (u * v).atan2((1.0 + u * u + v * v).sqrt());
    g(u1, v1) - g(u0, v1) - g(u1, v0) + g(u0, v0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn whole_face_is_a_sixth_of_the_sphere() {
        let w = cell_solid_angle(-1.0, 1.0, -1.0, 1.0);
        assert!((w - 4.0 * std::f64::consts::PI / 6.0).abs() < 1e-14);
    }

    #[test]
    fn projection_round_trips() {
        for (fi, f) in FACES.iter().enumerate() {
            let d = f.direction(0.3, -0.7);
            let (face, u, v) = project(d);
            assert_eq!(face, fi);
            assert!((u - 0.3).abs() < 1e-14 && (v + 0.7).abs() < 1e-14);
        }
    }
}
