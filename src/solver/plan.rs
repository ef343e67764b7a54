//! The plan: what this scene needs, decided once before solving and reported.
//!
//! - channels: 1 when the medium and every light are grey, else 3 (RGB);
//! - storage directions for the source: 1 when the medium is isotropic (g = 0), else k_s×k_s per face;
//! - emission: only when some channel emits;
//! - empty bricks: known from the store; they hold no medium and no source;
//! - the sun(s): each a collimated beam swept along its own direction.
//!
//! Everything both backends need to sweep a face is derived here ([`SweepDirection`]) so that the
//! CPU twin and the GPU driver consume identical tables.

use super::sweep::{lateral_slope, offsets, plane_path_length, FaceSweep};
use crate::quadrature::{cube_face_of, phase, PropagationSet, StorageSet};
use crate::scene::{Light, Medium, Scene};
use glam::DVec3;
use serde::Serialize;

/// One direction to sweep, with everything a backend needs.
#[derive(Clone, Debug)]
pub struct SweepDirection {
    pub face: usize,
    pub omega: DVec3,
    /// Path length through one plane (h/|ω_a|).
    pub path_length: f64,
    /// Lateral offsets per plane (see [`super::sweep::offsets`]).
    pub offsets: Vec<[i32; 2]>,
    /// Weight of the segment-average radiance in the fluence: Ω_i, or 1 for a beam.
    pub fluence_weight: f64,
    /// Radiance (irradiance for a beam) of rays born at the boundary in the sweep that carries
    /// boundary light, per channel.
    pub boundary: [f64; 3],
    /// Storage direction whose source this direction gains along the way.
    pub gain_storage: u32,
    /// Collect row: J^d += σs · row[d] · L̄.
    pub collect_row: Vec<f64>,
    /// Power of a ray per unit radiance: h²·|ω_a|·Ω_i (·1 for a beam).
    pub power_per_radiance: f64,
}

#[derive(Clone, Debug)]
pub struct Plan {
    pub dims: [u32; 3],
    pub voxel_size: f64,
    pub channels: u32,
    pub propagation: PropagationSet,
    pub storage: StorageSet,
    /// Per face, the k² swept directions of that face.
    pub faces: Vec<Vec<SweepDirection>>,
    /// The sun beams (each a single direction swept once, before the first order).
    pub beams: Vec<SweepDirection>,
    pub medium: Medium,
    pub emission: bool,
    pub max_orders: u32,
    pub tolerance: f64,
    /// Add the geometric tail of the order series once it is settled (see `orders::tail_estimate`).
    pub extrapolate_tail: bool,
    pub bricks_total: usize,
    pub bricks_empty: usize,
    /// Why each choice was made, for the report.
    pub reasons: Vec<String>,
}

/// The plan as it appears in `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct PlanSummary {
    pub dims: [u32; 3],
    pub voxel_size: f64,
    pub channels: u32,
    pub directions_per_face: u32,
    pub propagation_directions: usize,
    pub storage_directions: usize,
    pub storage_directions_per_face: u32,
    pub suns: usize,
    pub emission: bool,
    pub bricks_total: usize,
    pub bricks_empty: usize,
    pub max_orders: u32,
    pub tolerance: f64,
    pub extrapolate_tail: bool,
    pub reasons: Vec<String>,
}

impl Plan {
    /// Decides the plan for `scene`; `bricks_empty` comes from the brick store.
    pub fn new(scene: &Scene, bricks_total: usize, bricks_empty: usize) -> Plan {
        let mut reasons = Vec::new();
        let dims = scene.volume.dims;
        let h = scene.volume.voxel_size;
        let medium = scene.medium.clone();
        let grey = medium.is_grey() && scene.lights.iter().all(Light::is_grey);
        let channels = if grey { 1 } else { 3 };
        reasons.push(if grey {
            "1 channel: the medium and every light are grey".to_string()
        } else {
            "3 channels: the medium or a light differs between r, g and b".to_string()
        });

        let k = scene.solver.directions_per_face;
        let propagation = PropagationSet::new(k);
        let storage = if medium.g == 0.0 {
            reasons.push("1 storage direction: the medium scatters isotropically (g = 0)".into());
            StorageSet::isotropic(&propagation)
        } else {
            let ks = scene.solver.storage_directions_per_face.unwrap_or(k.min(2));
            reasons.push(format!(
                "{} storage directions ({ks}×{ks} per face): the medium is anisotropic (g = {})",
                6 * ks * ks,
                medium.g
            ));
            StorageSet::per_face(&propagation, ks)
        };
        let collect = phase::collect_matrix(&propagation, &storage, medium.g);
        let s = storage.len();

        let mut sky = [0.0; 3];
        for light in &scene.lights {
            if let Light::Sky { radiance } = light {
                (0..3).for_each(|c| sky[c] += radiance[c]);
            }
        }
        // Everything about one swept direction that follows from its geometry; `weight` is its
        // solid angle (a beam: 1, its boundary value being an irradiance).
        let swept = |face: usize, omega: DVec3, weight: f64, boundary: [f64; 3], gain_storage: u32, collect_row: Vec<f64>| {
            let path_length = plane_path_length(face, omega, h);
            SweepDirection {
                face,
                omega,
                path_length,
                offsets: offsets(lateral_slope(face, omega), FaceSweep::new(face, dims).n[0]),
                fluence_weight: weight,
                boundary,
                gain_storage,
                collect_row,
                // A ray's tube has cross-section h²·|ω_a| = h³/path_length.
                power_per_radiance: h * h * h / path_length * weight,
            }
        };
        let faces = (0..6)
            .map(|face| {
                let start = face * propagation.per_face();
                propagation
                    .face(face)
                    .iter()
                    .enumerate()
                    .map(|(j, d)| {
                        let i = start + j;
                        let row = collect[i * s..(i + 1) * s].to_vec();
                        swept(face, d.omega, d.solid_angle, sky, storage.owner[i], row)
                    })
                    .collect()
            })
            .collect();

        let beams: Vec<SweepDirection> = scene
            .lights
            .iter()
            .filter_map(|light| match light {
                Light::Sun { direction, irradiance } => {
                    let travel = -*direction;
                    let row = phase::beam_row(&propagation, &storage, medium.g, travel);
                    Some(swept(cube_face_of(travel), travel, 1.0, *irradiance, 0, row))
                }
                Light::Sky { .. } => None,
            })
            .collect();
        if !beams.is_empty() {
            reasons.push(format!(
                "{} sun beam(s) swept along their exact directions: no ray effects in direct light",
                beams.len()
            ));
        }
        let emission = medium.has_emission();
        reasons.push(if emission {
            "emission on: the medium emits σa·Le".into()
        } else {
            "no emission term: the medium does not emit".into()
        });
        reasons.push(format!("{bricks_empty} of {bricks_total} bricks are empty: no medium or source stored"));
        reasons.push("fields stored in f32 (f16 storage is not implemented yet)".into());

        Plan {
            dims,
            voxel_size: h,
            channels,
            propagation,
            storage,
            faces,
            beams,
            medium,
            emission,
            max_orders: scene.solver.max_orders,
            tolerance: scene.solver.tolerance,
            extrapolate_tail: scene.solver.extrapolate_tail,
            bricks_total,
            bricks_empty,
            reasons,
        }
    }

    /// Source components per voxel: storage directions × channels (component = d·channels + ch).
    pub fn source_components(&self) -> u32 {
        self.storage.len() as u32 * self.channels
    }

    /// Extinction, scattering and absorption coefficients per unit density for channel `ch`.
    pub fn coefficients(&self, ch: usize) -> (f64, f64, f64) {
        let st = self.medium.sigma_t[ch];
        let ss = st * self.medium.albedo[ch];
        (st, ss, st - ss)
    }

    pub fn summary(&self) -> PlanSummary {
        PlanSummary {
            dims: self.dims,
            voxel_size: self.voxel_size,
            channels: self.channels,
            directions_per_face: self.propagation.k,
            propagation_directions: self.propagation.len(),
            storage_directions: self.storage.len(),
            storage_directions_per_face: self.storage.per_face,
            suns: self.beams.len(),
            emission: self.emission,
            bricks_total: self.bricks_total,
            bricks_empty: self.bricks_empty,
            max_orders: self.max_orders,
            tolerance: self.tolerance,
            extrapolate_tail: self.extrapolate_tail,
            reasons: self.reasons.clone(),
        }
    }
}
