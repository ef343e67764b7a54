//! Energy bookkeeping: what enters, what leaves, what is absorbed, what is still in flight, and
//! through which face of the volume the boundary power goes.
//!
//! Per channel, in watts up to the common factor of the world unit: rays born at the boundary carry
//! `L·h²|ω_a|Ω_i` (a beam: `E·h²|ω_a|`), emission adds `4π·σa·Le·h³` per voxel, absorption takes
//! `σa·φ·h³`, rays leaving the volume take their power with them, and the source of the last order
//! (computed but not propagated) holds `Σ_d Ω_d J^d·h³`. A point light gives the medium
//! `Σ ρσt·E·h³` (its uncollided light's interactions, `solver::point`); what of it never
//! interacts is in neither side. A traced emission (`solver::uncollided`) counts all it puts out
//! as emitted, and what of its uncollided light leaves without interacting as
//! `uncollided_escaped`. The discretisation conserves energy exactly, so
//! `in + emitted + point lights = out + uncollided escaped + absorbed + unpropagated` to round-off. The per-face
//! tallies hold only what crosses the faces as rays: not the uncollided point light.
//!
//! The boundary power is also split by the six faces of the volume ([`VOLUME_FACES`]): a sweep's
//! rays are born on its near face (plane 0) and leave through its far face (after the last plane)
//! or, when their lattice slot wraps, through a lateral side (a wrap past n is the + side, below 0
//! the − side, [`super::sweep`]); the ray born in the wrapped slot enters through the opposite
//! side. A ray whose slot wraps in both lateral axes in one plane crosses an edge: its power is
//! split evenly between the two sides (rule kept by both backends and `sweep::side_births`).

use serde::{Deserialize, Serialize};

/// The six faces of the volume in report order: index `2·axis + 1` for the + side of an axis,
/// `2·axis` for the − side ([`volume_face`]).
pub const VOLUME_FACES: [&str; 6] = ["-x", "+x", "-y", "+y", "-z", "+z"];

/// The index in [`VOLUME_FACES`] of the face of `axis` on the + side (`positive`) or the − side.
pub const fn volume_face(axis: usize, positive: bool) -> usize {
    2 * axis + positive as usize
}

/// The face across the volume from face `f`.
pub const fn opposite_face(f: usize) -> usize {
    f ^ 1
}

/// Power tallies of one sweep (or of the whole solve so far), already multiplied by the ray power
/// factors: the totals, and the same split by the face the power crossed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Tallies {
    pub boundary_in: [f64; 3],
    pub boundary_out: [f64; 3],
    /// Per face ([`VOLUME_FACES`] order) and channel: the power rays carried in through it.
    pub face_in: [[f64; 3]; 6],
    /// Per face and channel: the power rays carried out through it.
    pub face_out: [[f64; 3]; 6],
}

impl Tallies {
    pub fn add(&mut self, other: &Tallies) {
        for c in 0..3 {
            self.boundary_in[c] += other.boundary_in[c];
            self.boundary_out[c] += other.boundary_out[c];
            for f in 0..6 {
                self.face_in[f][c] += other.face_in[f][c];
                self.face_out[f][c] += other.face_out[f][c];
            }
        }
    }
}

/// The power through one face of the volume, per channel, as `report.json` gives it.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FacePower {
    /// `-x`, `+x`, `-y`, `+y`, `-z` or `+z`.
    pub face: &'static str,
    pub power_in: [f64; 3],
    pub power_out: [f64; 3],
    /// `power_out / power_in` of this face (null where nothing entered): the reflectance when the
    /// light enters through this face alone (a sun or a sky on one side).
    pub reflectance: [Option<f64>; 3],
    /// The opposite face's `power_out` over this face's `power_in`: the transmittance in that case.
    pub transmittance: [Option<f64>; 3],
}

impl FacePower {
    fn new(f: usize, tallies: &Tallies, channels: usize) -> Self {
        let mut p = FacePower {
            face: VOLUME_FACES[f],
            power_in: tallies.face_in[f],
            power_out: tallies.face_out[f],
            ..FacePower::default()
        };
        for c in 0..channels {
            let incoming = tallies.face_in[f][c];
            if incoming > 0.0 {
                p.reflectance[c] = Some(tallies.face_out[f][c] / incoming);
                p.transmittance[c] = Some(tallies.face_out[opposite_face(f)][c] / incoming);
            }
        }
        p
    }
}

/// The whole solve's balance, per channel (only the first `channels` entries are meaningful;
/// `report.json` gives only those: one entry per array for a grey solve).
#[derive(Clone, Copy, Debug, Default, Serialize)]
#[serde(into = "EnergyJson")]
pub struct EnergyBalance {
    pub boundary_in: [f64; 3],
    pub emitted: [f64; 3],
    /// The power point lights give the medium, `Σ ρσt·E·h³` (their uncollided light that
    /// interacts; what passes through or misses the volume is not counted anywhere).
    pub point_lights: [f64; 3],
    /// Of `emitted`, what a traced emission's uncollided light carried out of the volume without
    /// interacting (`solver::uncollided`; zero when the emission is swept, whose rays count in
    /// `boundary_out`).
    pub uncollided_escaped: [f64; 3],
    pub boundary_out: [f64; 3],
    pub absorbed: [f64; 3],
    /// `absorbed / (boundary_in + emitted + point_lights)` (0 where nothing came in).
    pub absorptance: [f64; 3],
    /// Scattered power of the last computed order, not propagated further.
    pub unpropagated: [f64; 3],
    /// max over channels of |in + emitted + point lights − out − absorbed − unpropagated| /
    /// (in + emitted + point lights).
    pub relative_imbalance: f64,
    /// The boundary power split by the face of the volume it crossed (`-x`, `+x`, `-y`, `+y`,
    /// `-z`, `+z`); the faces' sums are `boundary_in` and `boundary_out`.
    pub faces: [FacePower; 6],
    /// How many channels the solve had (1 grey, or 3).
    pub channels: usize,
}

/// [`EnergyBalance`] as `report.json` writes it: each per-channel array cut to the solve's channels.
#[derive(Serialize)]
struct EnergyJson {
    boundary_in: Vec<f64>,
    emitted: Vec<f64>,
    point_lights: Vec<f64>,
    uncollided_escaped: Vec<f64>,
    boundary_out: Vec<f64>,
    absorbed: Vec<f64>,
    absorptance: Vec<f64>,
    unpropagated: Vec<f64>,
    relative_imbalance: f64,
    faces: Vec<FaceJson>,
}

#[derive(Serialize)]
struct FaceJson {
    face: &'static str,
    power_in: Vec<f64>,
    power_out: Vec<f64>,
    reflectance: Vec<Option<f64>>,
    transmittance: Vec<Option<f64>>,
}

impl From<EnergyBalance> for EnergyJson {
    fn from(e: EnergyBalance) -> Self {
        // A balance never computed (Default) has no channel count: give all three.
        let n = if e.channels == 0 { 3 } else { e.channels.min(3) };
        let cut = |v: [f64; 3]| v[..n].to_vec();
        EnergyJson {
            boundary_in: cut(e.boundary_in),
            emitted: cut(e.emitted),
            point_lights: cut(e.point_lights),
            uncollided_escaped: cut(e.uncollided_escaped),
            boundary_out: cut(e.boundary_out),
            absorbed: cut(e.absorbed),
            absorptance: cut(e.absorptance),
            unpropagated: cut(e.unpropagated),
            relative_imbalance: e.relative_imbalance,
            faces: e
                .faces
                .iter()
                .map(|f| FaceJson {
                    face: f.face,
                    power_in: cut(f.power_in),
                    power_out: cut(f.power_out),
                    reflectance: f.reflectance[..n].to_vec(),
                    transmittance: f.transmittance[..n].to_vec(),
                })
                .collect(),
        }
    }
}

impl EnergyBalance {
    pub fn new(
        tallies: &Tallies,
        emitted: [f64; 3],
        point_lights: [f64; 3],
        uncollided_escaped: [f64; 3],
        absorbed: [f64; 3],
        unpropagated: [f64; 3],
        channels: usize,
    ) -> Self {
        let mut worst: f64 = 0.0;
        let mut absorptance = [0.0; 3];
        for c in 0..channels {
            let source = tallies.boundary_in[c] + emitted[c] + point_lights[c];
            let sink = tallies.boundary_out[c] + uncollided_escaped[c] + absorbed[c] + unpropagated[c];
            if source > 0.0 {
                worst = worst.max((source - sink).abs() / source);
                absorptance[c] = absorbed[c] / source;
            } else if sink > 0.0 {
                worst = f64::INFINITY;
            }
        }
        EnergyBalance {
            boundary_in: tallies.boundary_in,
            emitted,
            point_lights,
            uncollided_escaped,
            boundary_out: tallies.boundary_out,
            absorbed,
            absorptance,
            unpropagated,
            relative_imbalance: worst,
            faces: std::array::from_fn(|f| FacePower::new(f, tallies, channels)),
            channels,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faces_are_indexed_by_axis_and_side() {
        for (axis, name) in ["x", "y", "z"].iter().enumerate() {
            assert_eq!(VOLUME_FACES[volume_face(axis, true)], format!("+{name}"));
            assert_eq!(VOLUME_FACES[volume_face(axis, false)], format!("-{name}"));
            assert_eq!(opposite_face(volume_face(axis, true)), volume_face(axis, false));
        }
    }

    #[test]
    fn reflectance_and_transmittance_are_fractions_of_the_face_input() {
        let mut t = Tallies::default();
        t.face_in[5] = [10.0, 0.0, 0.0];
        t.face_out[5] = [2.0, 0.0, 0.0];
        t.face_out[4] = [5.0, 0.0, 0.0];
        t.boundary_in = [10.0, 0.0, 0.0];
        t.boundary_out = [7.0, 0.0, 0.0];
        let e = EnergyBalance::new(&t, [0.0; 3], [0.0; 3], [0.0; 3], [3.0, 0.0, 0.0], [0.0; 3], 1);
        assert_eq!(e.faces[5].face, "+z");
        assert_eq!(e.faces[5].reflectance[0], Some(0.2));
        assert_eq!(e.faces[5].transmittance[0], Some(0.5));
        assert_eq!(e.faces[4].reflectance[0], None);
        assert_eq!(e.absorptance[0], 0.3);
        assert!(e.relative_imbalance < 1e-15);
    }

    /// A grey balance writes one entry per array (not `[x, 0, 0]` or `[x, null, null]`); an RGB one three.
    #[test]
    fn the_json_has_one_entry_per_channel() {
        let mut t = Tallies::default();
        t.face_in[5] = [10.0, 0.0, 0.0];
        t.boundary_in = [10.0, 0.0, 0.0];
        let grey =
            serde_json::to_value(EnergyBalance::new(&t, [0.0; 3], [0.0; 3], [0.0; 3], [3.0, 0.0, 0.0], [0.0; 3], 1))
                .expect("json");
        assert_eq!(grey["absorbed"], serde_json::json!([3.0]));
        assert_eq!(grey["faces"][5]["reflectance"], serde_json::json!([0.0]));
        assert_eq!(grey["faces"][4]["transmittance"], serde_json::json!([null]));
        assert_eq!(grey["faces"][5]["face"], "+z");
        let rgb =
            serde_json::to_value(EnergyBalance::new(&t, [0.0; 3], [0.0; 3], [0.0; 3], [3.0, 1.0, 0.0], [0.0; 3], 3))
                .expect("json");
        assert_eq!(rgb["absorbed"], serde_json::json!([3.0, 1.0, 0.0]));
        assert_eq!(rgb["faces"].as_array().map(Vec::len), Some(6));
    }
}
