//! The plan: what this scene needs, decided once before solving and reported.
//!
//! (About 800 lines: every choice the plan makes sits beside the reason it reports, so one file
//! says what a solve will model.)
//!
//! - channels: 1 when the medium, every light and the emission grid are grey (a temperature grid's
//!   blackbody colour never is), else 3 (RGB);
//! - storage directions for the source: 1 when the medium is isotropic (g = 0), else k_s×k_s per face;
//! - emission: only when some channel emits;
//! - empty bricks: known from the store; they hold no medium and no source;
//! - the sun(s): each a collimated beam swept along its own direction;
//! - the spatial scheme (`solver.spatial = "auto"`): "constant" for a medium that scatters or
//!   emits, "linear" for a pure absorber with open faces (`choose_spatial`);
//! - the sky: its radiance is the boundary value of the k×k directions per face that carry all
//!   light; with `solver.sky_directions_per_face` = k_sky > k it has directions of its own instead
//!   ("The sky's own directions" below), which the plan chooses itself (4k, at most 32) where
//!   nothing scatters and the scheme is "linear": there order 0 is the whole answer;
//! - point lights: their uncollided light computed exactly from each point on the host, its first
//!   scattering order 0's source (see `solver::point`);
//! - an environment map: its mean over each direction's cell joins the sky's boundary radiance, and
//!   its sun-like peak, when it has one, is one more beam (see `solver::environment`);
//! - the storage precision of the source the rays gain (the previous order's): f16 when the
//!   tolerance is at least [`F16_MIN_TOLERANCE`] (`solver.storage_precision = "auto"`), else f32.
//!   Only that source is rounded, once per order as the rays gain it, and scaled by a power of two
//!   chosen per order from its largest value ([`half_scale_exponent`]) so that f16's range never
//!   clips it; the accumulators and the brick store stay f32.
//!
//! `solver.plan = "full"` turns the reductions off (3 channels, k_s×k_s storage directions per
//! face, f32 unless `storage_precision` names f16) so that `lpm bench accuracy --plans auto,full`
//! can show what they save and that they cost no accuracy. It keeps what is exact: empty bricks
//! are still skipped (no medium, no source: rays cross them unchanged) and no emission term is
//! added when nothing emits.
//!
//! **The sky's own directions.** Next to a face, the sky's uncollided light is the integral over
//! the sphere of L·e^{−τ(ω)}, and τ jumps from nearly 0 to the width of the volume across the
//! directions grazing that face. A k×k set per face integrates that poorly: even with every
//! direction transported exactly, k = 8 leaves the fluence at a face centre of a thin box 1.75 %
//! off, k = 16 0.38 % (benches/RESULTS.md). The scattered light is smooth in angle and does not
//! need more directions, so with k_sky > k the sky is swept in order 0 only, along the 6·k_sky²
//! directions of its own set ([`Plan::sky_faces`]), each with its solid angle as weight and the
//! collect row of its exact direction (as a beam's, times that solid angle), on the plan's spatial
//! scheme; the k×k directions then carry no boundary light. Order 0 costs (k_sky/k)² more sweeps;
//! every other order is unchanged. It pays with `spatial = "linear"` in media that fill the volume
//! up to its faces (the absorber box at k = 8: worst voxel 1.8 % → 1.06 % at k_sky = 16, 0.76 % at
//! 32); under `"constant"` the nearest column's plane-sized error where light enters through a side
//! grows with the grazing directions a fine set has (2.7 % → 3.3 %), and around a cloud in vacuum
//! the k×k scattered light's own error, which the coarse sky's partly cancelled, shows (RESULTS).
//! An environment map's light takes the same directions (its means over their cells; its sun-like
//! peak stays a beam). Not with periodic or mirror faces (the sky's rays would have to be carried
//! on to later orders).
//!
//! **The scattered light's own directions.** A traced emission ([`super::uncollided`]) reaches
//! every voxel without ray effects, but what it first scatters is as compact as the emitter, and
//! swept along the k×k from there it streaks again where it dominates (Kobayashi's case ii at k =
//! 5: rms ln(C/E) 0.085–0.115, every detector within 10 % only from k = 12). So where the emission
//! is traced and the medium scatters, orders 1 and 2 ([`SCATTERED_OWN_ORDERS`]: whose sources are
//! the first and second scattering, with any other light's) are swept along k_1×k_1 directions per
//! face of their own ([`Plan::scattered_faces`]) instead of the k×k:
//! `solver.scattered_directions_per_face`, by default the smallest multiple of k from 12 on (15 at
//! the default k = 5; a multiple so that every fine cell lies in one propagation cell and gains its
//! storage direction's source), each with its solid angle as weight and the collect row of its
//! exact direction, as the sky's. Each costs (k_1/k)² an order's sweeps (9× at k = 5); every later
//! order is unchanged, its light spread enough for the k×k. Why two: Kobayashi's problem 3 case ii
//! (published octant, k = 5) reads rms ln(C/E) 0.115 with the k×k, 0.044 with order 1 alone on its
//! own directions (two detectors at C/E 1.11, at the duct's far end and deep in the shield, where
//! twice-scattered light streams), 0.022 with orders 1 and 2, every detector within 5 %
//! (benches/RESULTS.md). The fine directions have no periodic or mirror hand-over, so with mirror
//! faces the solve unfolds them ([`super::unfold`], [`Plan::unfolds_for_scattered`]; the GPU always
//! does), and a periodic axis or mirrors on both faces of an axis (where the trace itself sweeps)
//! keep the k×k.
//!
//! Everything both backends need to sweep a face is derived here ([`SweepDirection`]) so that the
//! CPU twin and the GPU driver consume identical tables.

use super::environment::environment_boundary;
use super::periodic::{periodic_lattice, periodic_slope};
use super::point::PointLight;
use super::sweep::{lateral_slope, lattice, plane_path_length, FaceSweep};
use super::uncollided::SCATTERED_STREAK_FREE_K;
use crate::quadrature::phase::{self, Phase, Truncation};
use crate::quadrature::{cube_face_of, PropagationSet, StorageSet, FACES};
use crate::scene::{
    Acceleration, DiffusionCorrection, ForwardPeak, Light, Medium, PlanMode, Scene, SpatialScheme, StoragePrecision,
};
use glam::DVec3;
use serde::Serialize;

/// One direction to sweep, with everything a backend needs.
#[derive(Clone, Debug)]
pub struct SweepDirection {
    pub face: usize,
    pub omega: DVec3,
    /// Path length through one plane (h/|ω_a|).
    pub path_length: f64,
    /// Lattice offsets per plane (see [`super::sweep::lattice`]).
    pub offsets: Vec<[i32; 2]>,
    /// Lattice weights per plane: a ray meets its lower column with 1 − w, its upper one with w.
    pub weights: Vec<[f64; 2]>,
    /// Weight of the segment-average radiance in the fluence: Ω_i, or 1 for a beam.
    pub fluence_weight: f64,
    /// Radiance (irradiance for a beam) of rays born at the boundary in the sweep that carries
    /// boundary light, per channel.
    pub boundary: [f64; 3],
    /// Storage direction whose source this direction gains along the way.
    pub gain_storage: u32,
    /// Collect row: J^d += σs · row\[d\] · L̄.
    pub collect_row: Vec<f64>,
    /// Power of a ray per unit radiance: h²·|ω_a|·Ω_i (·1 for a beam).
    pub power_per_radiance: f64,
    /// When the sweep axis is periodic: the whole lattice columns M (per lateral axis) the rays
    /// move over one period of the axis ([`super::periodic`]); zeros otherwise.
    pub period_shift: [i32; 2],
}

/// The smallest tolerance at which `storage_precision = "auto"` stores the gained source in f16:
/// f16 rounds to within 2^-11 ≈ 4.9e-4 relative, about half of it, and the rounding errors of
/// neighbouring voxels and directions average out further in the fluence.
pub const F16_MIN_TOLERANCE: f64 = 1e-3;

/// How the source the rays gain is stored on the device (and rounded in the CPU twin).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    F16,
    F32,
}

impl Precision {
    /// "f16" or "f32".
    pub fn name(self) -> &'static str {
        match self {
            Precision::F16 => "f16",
            Precision::F32 => "f32",
        }
    }

    /// Bytes of one stored value.
    pub fn bytes(self) -> u64 {
        match self {
            Precision::F16 => 2,
            Precision::F32 => 4,
        }
    }
}

/// The power of two e such that `max · 2^e` lies in [2^13, 2^14): values scaled by it fit f16
/// (largest finite 65504) with room to spare, and keep f16's full relative precision down to
/// 2^-27 of the largest. `max` ≤ 0 (a zero source) gives 0. The result lies in [−114, 127], so
/// 2^e and 2^−e are normal f32 numbers (the scaling is exact) and e fits the shader's 8-bit field.
pub fn half_scale_exponent(max: f32) -> i32 {
    if max.is_nan() || max <= 0.0 || max == f32::INFINITY {
        return 0;
    }
    let m = max.max(f32::MIN_POSITIVE);
    // m ∈ [2^(k−1), 2^k) with k = biased exponent − 126.
    let k = ((m.to_bits() >> 23) & 0xff) as i32 - 126;
    (14 - k).clamp(-126, 127)
}

/// 2^e as an f32, exactly (e in [−126, 127], the range of [`half_scale_exponent`]).
pub fn power_of_two(e: i32) -> f32 {
    f32::from_bits(((e.clamp(-126, 127) + 127) as u32) << 23)
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
    /// Per face, the sky's own k_sky² directions, swept in order 0 only with the sky as boundary
    /// radiance and no gained source; empty unless `solver.sky_directions_per_face` > k (the sky
    /// is then no part of [`Plan::faces`]' boundary radiance). See the module docs.
    pub sky_faces: Vec<Vec<SweepDirection>>,
    /// Per face, the scattered light's own directions (k_1 > k, a multiple of k), swept in orders
    /// 1 to [`SCATTERED_OWN_ORDERS`] instead of [`Plan::faces`] with the gained source and nothing
    /// else; empty unless the emission is traced and the medium scatters ("The scattered light's
    /// own directions" in the module docs).
    pub scattered_faces: Vec<Vec<SweepDirection>>,
    /// Some(k_1): mirror faces that the solve unfolds (the volume doubled by its images,
    /// [`super::unfold`]) so that a traced emission's scattered light can take k_1×k_1 directions
    /// per face of its own, which have no mirror hand-overs; the doubled volume's plan then has
    /// them as [`Plan::scattered_faces`].
    pub unfolds_for_scattered: Option<u32>,
    /// The point lights, positions in voxel units (see [`super::point`]).
    pub point_lights: Vec<PointLight>,
    pub medium: Medium,
    /// The medium emits `medium.emission` uniformly (the kernels add it in order 0).
    pub emission: bool,
    /// The medium emits per voxel (`volume.emission_*`, or a uniform emission over a per-voxel
    /// albedo, whose σa varies per voxel): the order-0 source is written from the store's fields
    /// before the orders start (see `solver::emission`).
    pub emission_field: bool,
    /// The store holds an emission factor field (`volume.emission_*` / `temperature_*`).
    pub emission_grid: bool,
    /// The emission's uncollided light is traced from the emitting voxels before order 0
    /// ([`super::uncollided`]); `emission` and `emission_field` are then off (nothing swept).
    pub emission_traced: bool,
    /// The albedo varies per voxel (`volume.albedo_*`): each order's scattered source is multiplied
    /// by the store's albedo factor before it is committed, and absorption is counted with it (see
    /// `solver::passes`).
    pub albedo_field: bool,
    pub max_orders: u32,
    pub tolerance: f64,
    /// Add the geometric tail of the order series once it is settled (see `orders::tail_estimate`).
    pub extrapolate_tail: bool,
    pub bricks_total: usize,
    pub bricks_empty: usize,
    /// Storage precision of the source the rays gain (the previous order's).
    pub source_precision: Precision,
    /// `solver.plan`: whether the reductions above were allowed.
    pub mode: PlanMode,
    /// `solver.spatial`: how rays meet the voxels of a plane.
    pub spatial: SpatialScheme,
    /// κ per volume axis (voxels²) of the anti-diffusive fluxes applied to each order's scattered
    /// source (`solver.diffusion_correction`, [`super::antidiffusion`]); zero: none.
    pub diffusion_correction: [f64; 3],
    /// Each order is followed by a diffusion correction of the light still to come
    /// (`solver.acceleration`, [`super::acceleration`]).
    pub acceleration: bool,
    /// The most cells the acceleration's diffusion grid may have (`solver.diffusion_cells`).
    pub diffusion_cells: usize,
    /// The scene's Henyey–Greenstein g (the medium above holds the mean cosine of the one solved,
    /// after δ-M).
    pub phase_g: f64,
    /// The phase function the collect rows discretise: HG(g), or its remainder after δ-M.
    pub phase: Phase,
    /// The mean cosine of the discrete scattering (see `phase::effective_mean_cosine`).
    pub effective_g: f64,
    /// Per volume axis (x, y, z): periodic (`[boundary]`, [`super::periodic`]).
    pub periodic: [bool; 3],
    /// Per volume axis, whether its low and high faces are mirrors ([`super::mirror`]).
    pub reflective: [[bool; 2]; 3],
    /// With mirror faces: per face and direction of the face, its mirror image across the x, y
    /// and z planes as (face, direction) ([`super::mirror::mirror_images`]); empty otherwise.
    pub mirrors: Vec<Vec<[(usize, usize); 3]>>,
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
    /// k_sky: the sky's own directions per face axis (`solver.sky_directions_per_face`); equal to
    /// `directions_per_face` when the sky travels with the other light.
    pub sky_directions_per_face: u32,
    /// k_1: the scattered light's own directions per face axis, swept in orders 1 and 2
    /// (`solver.scattered_directions_per_face`); equal to k when those sweep the k×k.
    pub scattered_directions_per_face: u32,
    pub suns: usize,
    /// Point lights (their uncollided light computed on the host, see `solver::point`).
    pub point_lights: usize,
    pub emission: bool,
    /// The emission's source is written per voxel (an emission grid, or σa varying with an albedo
    /// grid).
    pub emission_per_voxel: bool,
    /// How the emission's uncollided light reaches the volume: "traced", "swept" or "none" (no
    /// emission); the reasons say why.
    pub emission_uncollided: &'static str,
    /// The albedo varies per voxel (`volume.albedo_*`).
    pub albedo_per_voxel: bool,
    pub bricks_total: usize,
    pub bricks_empty: usize,
    pub max_orders: u32,
    pub tolerance: f64,
    pub extrapolate_tail: bool,
    /// "f16" or "f32": how the source the rays gain is stored on the device.
    pub storage_precision: Precision,
    /// "auto" (model only what the scene needs) or "full" (`solver.plan`: reductions off).
    pub mode: String,
    /// "linear" or "constant" (`solver.spatial`).
    pub spatial: String,
    /// κ per axis of the diffusion correction (zeros: off).
    pub diffusion_correction: [f64; 3],
    /// "diffusion" (each order followed by a diffusion synthetic acceleration step) or "off".
    pub acceleration: &'static str,
    /// With the acceleration: its diffusion grid's cells per axis and their edge in voxels (at most
    /// `solver.diffusion_cells` cells; the cells without medium are left out of the solve).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diffusion_grid: Option<DiffusionGrid>,
    /// The scene's g, the g solved (after δ-M scaling) and the g the discrete scattering behaves
    /// like; the δ-M forward fraction f when applied.
    pub phase_g: f64,
    pub solved_g: f64,
    pub effective_g: f64,
    pub delta_m_fraction: Option<f64>,
    /// Per axis (x, y, z): "open", "periodic", "reflective", "reflective low" or "reflective high".
    pub boundary: [&'static str; 3],
    pub reasons: Vec<String>,
}

/// The acceleration's diffusion grid in the plan's summary.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct DiffusionGrid {
    pub cells: [u32; 3],
    pub cell_edge: u32,
}

impl Plan {
    /// Decides the plan for `scene`; `bricks_empty` comes from the brick store.
    pub fn new(scene: &Scene, bricks_total: usize, bricks_empty: usize) -> Plan {
        let mut reasons = Vec::new();
        let full = scene.solver.plan == PlanMode::Full;
        if full {
            reasons.push(FULL_PLAN_REASON.into());
        }
        let dims = scene.volume.dims;
        let h = scene.volume.voxel_size;
        let channels = choose_channels(scene, full, &mut reasons);
        let scatters = medium_scatters(&scene.medium);
        let (spatial, chosen) = choose_spatial(scene, scatters);
        let periodic = scene.boundary.periodic;
        let reflective = scene.boundary.reflective;
        if scene.boundary.any_reflective() {
            let faces: Vec<String> = (0..3)
                .flat_map(|a| (0..2).filter(move |&s| reflective[a][s]).map(move |s| (a, s)))
                .map(|(a, s)| format!("{}{}", ["-", "+"][s], ["x", "y", "z"][a]))
                .collect();
            reasons.push(format!(
                "mirror faces {}: what reaches them comes back in the mirror-image direction in the next order \
                 (exact on the nearest-column lattice); directions swept across a mirror are nudged to move \
                 whole voxels over the volume",
                faces.join(", ")
            ));
        }
        if scene.boundary.any_periodic() {
            let axes: Vec<&str> =
                ["x", "y", "z"].into_iter().zip(periodic).filter(|(_, p)| *p).map(|(a, _)| a).collect();
            reasons.push(format!(
                "periodic along {}: rays wrap across those faces; directions swept along a periodic axis are \
                 nudged to move whole voxels per period and carry what leaves into the next order",
                axes.join(", ")
            ));
        }
        reasons.push(match spatial {
            SpatialScheme::Linear => format!(
                "spatial scheme \"linear\"{chosen}: rays at their exact lateral positions gather and deposit \
                 bilinearly (second-order across the rays, no plane-sized error where light enters through a side)"
            ),
            SpatialScheme::Constant => {
                format!("spatial scheme \"constant\"{chosen}: each ray meets the one voxel under it (first order)")
            }
        });

        let k = scene.solver.directions_per_face;
        let propagation = PropagationSet::new(k);
        let storage = choose_storage(scene, &propagation, full, &mut reasons);
        let (medium, phase) = choose_forward_peak(scene, &propagation, &storage, &mut reasons);
        // For g = 0 the matrix is uniform over the storage directions whatever their number, so a
        // full plan's per-face source of an isotropic medium holds the same value in every
        // direction (to rounding) and the rays gain what the single isotropic value would give.
        let collect = phase::collect_matrix(&propagation, &storage, &phase);
        let s = storage.len();
        let effective_g = phase::effective_mean_cosine(&propagation, &storage, &collect);
        if medium.g != 0.0 {
            reasons.push(format!(
                "the discrete scattering behaves like g = {effective_g:.3} (the phase function solved has g = {:.3})",
                medium.g
            ));
        }

        let mut sky = [0.0; 3];
        for light in &scene.lights {
            if let Light::Sky { radiance } = light {
                (0..3).for_each(|c| sky[c] += radiance[c]);
            }
        }
        // An environment map adds its mean over each direction's cell to the sky, and its
        // sun-like peak, when it has one, becomes one more beam.
        let environment = scene.lights.iter().find_map(|l| match l {
            Light::Environment(env) => Some((env, environment_boundary(env, &propagation))),
            _ => None,
        });
        // The sky's own directions (module docs), when asked for and there is a sky or an
        // environment map to sweep: then the k×k directions carry no boundary light.
        let sky_k = scene.solver.sky_directions_per_face.or_else(|| auto_sky_directions(k, spatial, scatters));
        let sky_k = sky_k.filter(|&n| n > k);
        let own_sky = sky_k.filter(|_| sky.iter().any(|&l| l > 0.0) || environment.is_some());
        let boundary_of = |i: usize| match (&environment, own_sky) {
            (_, Some(_)) => [0.0; 3],
            (Some((_, b)), None) => [0, 1, 2].map(|c| sky[c] + b.radiance[i][c]),
            (None, None) => sky,
        };
        if let Some((env, b)) = &environment {
            reasons.push(format!(
                "environment map {} ({} × {} pixels): each direction's boundary radiance is the map's \
                 mean over its cell",
                env.map.path.display(),
                env.map.width,
                env.map.height
            ));
            reasons.push(match &b.sun {
                Some(s) => format!(
                    "the map's sun-like peak ({} pixels, {:.2e} sr, {:.1} % of its power) is swept as a beam \
                     toward [{:.4}, {:.4}, {:.4}] with irradiance [{:.4e}, {:.4e}, {:.4e}]: no ray effects",
                    s.pixels,
                    s.solid_angle,
                    100.0 * s.share,
                    s.direction.x,
                    s.direction.y,
                    s.direction.z,
                    s.irradiance[0],
                    s.irradiance[1],
                    s.irradiance[2]
                ),
                None => "the map has no sun-like peak (a region of at most 0.01 sr at least 100 times \
                         brighter than the rest): nothing extracted"
                    .into(),
            });
        }
        // Everything about one swept direction that follows from its geometry; `weight` is its
        // solid angle (a beam: 1, its boundary value being an irradiance).
        let swept =
            |face: usize, omega: DVec3, weight: f64, boundary: [f64; 3], gain_storage: u32, collect_row: Vec<f64>| {
                let sweep = FaceSweep::with_boundary(face, dims, periodic, reflective);
                let planes = sweep.n[0];
                let slope = lateral_slope(face, omega);
                // Across a mirror of the sweep axis the rays hand over to their mirror images'
                // lattice, which must line up as a periodic one does (super::mirror).
                let (omega, (offsets, weights), period_shift) = if sweep.periodic[0] || sweep.mirror[0] != [false; 2] {
                    // Nudged to whole columns per period (super::periodic); ω follows the slope.
                    let (nudged, m) = periodic_slope(slope, planes);
                    let f = FACES[face];
                    let mut w = [0.0; 3];
                    w[f.axis] = f.sign;
                    w[f.lateral[0]] = nudged[0];
                    w[f.lateral[1]] = nudged[1];
                    (DVec3::from_array(w).normalize(), periodic_lattice(m, planes, spatial), m)
                } else {
                    (omega, lattice(slope, planes, spatial), [0; 2])
                };
                let path_length = plane_path_length(face, omega, h);
                SweepDirection {
                    face,
                    omega,
                    path_length,
                    offsets,
                    weights,
                    fluence_weight: weight,
                    boundary,
                    gain_storage,
                    collect_row,
                    // A ray's tube has cross-section h²·|ω_a| = h³/path_length.
                    power_per_radiance: h * h * h / path_length * weight,
                    period_shift,
                }
            };
        let faces = per_face(&propagation, |face, i, d| {
            let row = collect[i * s..(i + 1) * s].to_vec();
            swept(face, d.omega, d.solid_angle, boundary_of(i), storage.owner[i], row)
        });

        let sky_faces: Vec<Vec<SweepDirection>> = match own_sky {
            Some(n) => {
                let fine = PropagationSet::new(n);
                let rows = phase::BeamRows::new(&propagation, &storage, &phase);
                // The map's means over the fine cells (its sun-like peak, taken from the map's
                // pixels whatever the cells, is the same beam as above).
                let fine_map = environment.as_ref().map(|(env, _)| environment_boundary(env, &fine));
                let chosen = match scene.solver.sky_directions_per_face {
                    Some(_) => "",
                    None => " (auto: nothing scatters, so order 0 is the whole answer)",
                };
                reasons.push(format!(
                    "sky: its light enters along {n}×{n} directions per face of its own in order 0 ({} sweeps, \
                     {:.1}× the {} of an order), the scattered light along the {k}×{k}: the sky's uncollided \
                     light next to a face integrated over {}× finer cells{chosen}",
                    fine.len(),
                    fine.len() as f64 / propagation.len() as f64,
                    propagation.len(),
                    (n * n) as f64 / (k * k) as f64,
                ));
                per_face(&fine, |face, i, d| {
                    let row = rows.row(d.omega).iter().map(|p| p * d.solid_angle).collect();
                    let boundary = match &fine_map {
                        Some(b) => [0, 1, 2].map(|c| sky[c] + b.radiance[i][c]),
                        None => sky,
                    };
                    swept(face, d.omega, d.solid_angle, boundary, 0, row)
                })
            }
            None => {
                if sky_k.is_some() {
                    reasons.push(
                        "sky_directions_per_face: the scene has no sky or environment map, nothing to refine".into(),
                    );
                }
                Vec::new()
            }
        };
        // The scattered light's own directions (module docs): made wherever the emission
        // may be traced; kept only when it is ([`Plan::trace_emission`]).
        let scattered_k = first_scatter_directions(scene, k, scatters);
        let b = &scene.boundary;
        let unfoldable = b.any_reflective() && !b.any_periodic() && !b.reflective.iter().any(|axis| axis[0] && axis[1]);
        let unfolds_for_scattered = scattered_k.filter(|_| unfoldable);
        let hands_on = b.any_periodic() || b.any_reflective();
        let scattered_faces = match scattered_k.filter(|_| !hands_on) {
            Some(n) => {
                let fine = PropagationSet::new(n);
                let rows = phase::BeamRows::new(&propagation, &storage, &phase);
                per_face(&fine, |face, _, d| {
                    let row = rows.row(d.omega).iter().map(|p| p * d.solid_angle).collect();
                    // n is a multiple of k: the fine cell lies in one propagation cell, so in one
                    // storage cell, whose source it gains.
                    let owner = storage.owner[propagation.containing(d.omega)];
                    swept(face, d.omega, d.solid_angle, [0.0; 3], owner, row)
                })
            }
            None => Vec::new(),
        };
        let extracted = environment.as_ref().and_then(|(_, b)| b.sun.as_ref()).map(|s| (s.direction, s.irradiance));
        let beams: Vec<SweepDirection> = scene
            .lights
            .iter()
            .filter_map(|light| match light {
                Light::Sun { direction, irradiance } => Some((*direction, *irradiance)),
                Light::Sky { .. } | Light::Environment(_) | Light::Point { .. } => None,
            })
            .chain(extracted)
            .map(|(direction, irradiance)| {
                let travel = -direction;
                let row = phase::beam_row(&propagation, &storage, &phase, travel);
                swept(cube_face_of(travel), travel, 1.0, irradiance, 0, row)
            })
            .collect();
        if !beams.is_empty() {
            reasons.push(format!(
                "{} sun beam(s) swept along their exact directions: no ray effects in direct light",
                beams.len()
            ));
        }
        let point_lights: Vec<PointLight> = scene
            .lights
            .iter()
            .filter_map(|light| match light {
                Light::Point { position, intensity } => {
                    Some(PointLight { position: *position / h, intensity: *intensity })
                }
                _ => None,
            })
            .collect();
        if !point_lights.is_empty() {
            reasons.push(format!(
                "{} point light(s): uncollided light computed exactly from each point on the host; its \
                 first scattering is order 0's source",
                point_lights.len()
            ));
        }
        let albedo_field = scene.volume.albedo.is_some();
        if albedo_field {
            reasons.push(
                "albedo per voxel: each order's scattered source is multiplied by a(v) from the albedo grid \
                 (albedo medium.albedo·a(v)), absorption counted as ρσt·(1 − albedo·a(v))"
                    .into(),
            );
        }
        let emission_grid = medium.has_emission() && scene.volume.emission.is_some();
        // With a per-voxel albedo σa varies per voxel, so even a uniform emission's source
        // σa(v)·Le is written per voxel rather than added by the kernels.
        let emission_field = medium.has_emission() && (emission_grid || albedo_field);
        let emission = medium.has_emission() && !emission_field;
        let blackbody = scene.volume.emission.as_ref().and_then(|e| e.blackbody());
        reasons.push(if let (true, Some(b)) = (emission_grid, blackbody) {
            format!(
                "emission per voxel from a temperature grid: the first order's source is σa·Le·f(T) per \
                 channel, T = {} K × the grid's value, f the blackbody colour (luminance 1 at {} K, 0 below {} K)",
                b.scale, b.reference, b.cutoff
            )
        } else if emission_grid {
            "emission per voxel: the first order's source is σa·Le·e(v) from the emission grid".into()
        } else if emission_field {
            "emission per voxel: the first order's source is σa(v)·Le, σa(v) from the albedo grid".into()
        } else if emission {
            "emission on: the medium emits σa·Le".into()
        } else {
            "no emission term: the medium does not emit".into()
        });
        reasons.push(format!(
            "{bricks_empty} of {bricks_total} bricks are empty: no medium or source stored{}",
            if full { " (kept under plan = \"full\": skipping them is exact)" } else { "" }
        ));
        let mirrors = if scene.boundary.any_reflective() { super::mirror::mirror_images(&faces) } else { Vec::new() };
        let diffusion_correction = choose_diffusion_correction(scene, &medium, &faces, spatial, &mut reasons);
        let acceleration = choose_acceleration(scene, &medium, spatial, &mut reasons);
        let source_precision = choose_precision(scene, full, acceleration, &mut reasons);

        Plan {
            dims,
            voxel_size: h,
            channels,
            propagation,
            storage,
            faces,
            beams,
            sky_faces,
            scattered_faces,
            unfolds_for_scattered,
            point_lights,
            medium,
            emission,
            emission_field,
            emission_grid,
            emission_traced: false,
            albedo_field,
            max_orders: scene.solver.max_orders,
            tolerance: scene.solver.tolerance,
            extrapolate_tail: scene.solver.extrapolate_tail,
            bricks_total,
            bricks_empty,
            source_precision,
            mode: scene.solver.plan,
            spatial,
            diffusion_correction,
            acceleration,
            diffusion_cells: scene.solver.diffusion_cells.map_or(super::acceleration::MAX_CELLS, |n| n as usize),
            phase_g: scene.medium.g,
            phase,
            effective_g,
            periodic,
            reflective,
            mirrors,
            reasons,
        }
    }

    /// The emission's uncollided light is traced ([`super::uncollided`]): nothing of it is swept
    /// (the kernels' uniform emission off, no per-voxel order-0 source); `reason` goes to the report.
    pub fn trace_emission(&mut self, reason: String) {
        self.emission_traced = true;
        self.emission = false;
        self.emission_field = false;
        for r in &mut self.reasons {
            *r = r.replace("the first order's source is", "the emission's source is");
        }
        self.reasons.push(reason);
        if let Some(dirs) = self.scattered_faces.first().map(Vec::len) {
            let (n, k) = (self.scattered_directions_per_face(), self.propagation.k);
            self.reasons.push(format!(
                "scattered light: orders 1 and 2 sweep along {n}×{n} directions per face of their own ({} sweeps \
                 each, {:.1}× an order's {}), each with the collect row of its exact direction, so the light the \
                 traced emission scatters first and second spreads without the ray effects of the {k}×{k}; later \
                 orders along the {k}×{k}",
                6 * dirs,
                dirs as f64 / self.propagation.per_face() as f64,
                self.propagation.len(),
            ));
        }
    }

    /// The emission is swept, not traced: its scattered light keeps the k×k directions (the
    /// scattered light's own directions are for a traced emission's, module docs).
    pub fn sweep_emission(&mut self) {
        self.scattered_faces.clear();
        self.unfolds_for_scattered = None;
    }

    /// k_1: the scattered light's own directions per face axis; k when orders 1 and 2 sweep the
    /// k×k.
    /// (With mirrors unfolded for them, the doubled volume's.)
    pub fn scattered_directions_per_face(&self) -> u32 {
        match self.scattered_faces.first() {
            Some(f) => f.len().isqrt() as u32,
            None => self.unfolds_for_scattered.unwrap_or(self.propagation.k),
        }
    }

    /// Whether order `order` sweeps [`Plan::scattered_faces`] instead of [`Plan::faces`].
    pub fn sweeps_scattered_in(&self, order: u32) -> bool {
        (1..=SCATTERED_OWN_ORDERS).contains(&order) && !self.scattered_faces.is_empty()
    }

    /// Order `order`'s sweeps over an ordinary order's: (k_1/k)² where it sweeps
    /// [`Plan::scattered_faces`], else 1 (the progress estimate's [`crate::progress::OrderDone::weight`]).
    pub fn order_weight(&self, order: u32) -> f64 {
        if self.sweeps_scattered_in(order) {
            let fine: usize = self.scattered_faces.iter().map(Vec::len).sum();
            fine as f64 / self.propagation.len() as f64
        } else {
            1.0
        }
    }

    /// Whether beam `b` is swept in order `order`: in order 0, and again in every order when its
    /// sweep axis is periodic, to carry what it carried out ([`super::periodic`]).
    pub fn beam_swept_in(&self, b: usize, order: u32) -> bool {
        order == 0 || FaceSweep::for_plan(self.beams[b].face, self).periodic[0]
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

    /// The forward-peak fraction f δ-M scaling counts as not scattered, when applied.
    pub fn delta_m(&self) -> Option<f64> {
        match self.phase {
            Phase::Truncated(t) => Some(t.fraction),
            Phase::HenyeyGreenstein { .. } => None,
        }
    }

    /// k_sky: the sky's directions per face axis; k when the sky travels with the other light.
    pub fn sky_directions_per_face(&self) -> u32 {
        self.sky_faces.first().map_or(self.propagation.k, |f| f.len().isqrt() as u32)
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
            // k_sky² directions per face (a cube-face set), or none: k.
            sky_directions_per_face: self.sky_directions_per_face(),
            scattered_directions_per_face: self.scattered_directions_per_face(),
            suns: self.beams.len(),
            point_lights: self.point_lights.len(),
            emission: self.emission || self.emission_field || self.emission_traced,
            emission_per_voxel: self.emission_field
                || (self.emission_traced && (self.emission_grid || self.albedo_field)),
            emission_uncollided: if self.emission_traced {
                "traced"
            } else if self.emission || self.emission_field {
                "swept"
            } else {
                "none"
            },
            albedo_per_voxel: self.albedo_field,
            bricks_total: self.bricks_total,
            bricks_empty: self.bricks_empty,
            max_orders: self.max_orders,
            tolerance: self.tolerance,
            extrapolate_tail: self.extrapolate_tail,
            storage_precision: self.source_precision,
            mode: self.mode.name().to_string(),
            spatial: self.spatial.name().to_string(),
            diffusion_correction: self.diffusion_correction,
            phase_g: self.phase_g,
            solved_g: self.medium.g,
            acceleration: if self.acceleration { "diffusion" } else { "off" },
            diffusion_grid: self.acceleration.then(|| {
                let (cell_edge, cells) = super::acceleration::grid_of(self.dims, self.diffusion_cells);
                DiffusionGrid { cells, cell_edge }
            }),
            effective_g: self.effective_g,
            delta_m_fraction: self.delta_m(),
            boundary: {
                let b = crate::scene::Boundary { periodic: self.periodic, reflective: self.reflective };
                [0, 1, 2].map(|a| b.axis_name(a))
            },
            reasons: self.reasons.clone(),
        }
    }
}

/// The swept directions of `set`, face by face: `make(face, i, direction)` with i the direction's
/// index in the whole set (where its collect row and boundary radiance are found).
fn per_face(
    set: &PropagationSet,
    mut make: impl FnMut(usize, usize, &crate::quadrature::Direction) -> SweepDirection,
) -> Vec<Vec<SweepDirection>> {
    (0..6)
        .map(|face| {
            let start = face * set.per_face();
            set.face(face).iter().enumerate().map(|(j, d)| make(face, start + j, d)).collect()
        })
        .collect()
}

/// The first reason of a `plan = "full"` plan: what it turns off and what it keeps.
pub const FULL_PLAN_REASON: &str = "plan = \"full\": the plan's reductions are off — 3 channels, \
     k_s×k_s storage directions per face and f32 storage of the gained source (unless \
     storage_precision names f16), whatever the scene needs; kept: empty bricks are skipped and \
     the emission term is left out when nothing emits (both exact: they add nothing)";

/// Whether any channel of `medium` scatters (albedo and σt both above 0). A per-voxel albedo
/// only scales the medium's, so it cannot make a non-scattering medium scatter.
fn medium_scatters(medium: &Medium) -> bool {
    medium.albedo.iter().zip(&medium.sigma_t).any(|(&a, &s)| a > 0.0 && s > 0.0)
}

/// `solver.spatial`, or the plan's choice when it is "auto": "linear" where nothing scatters,
/// nothing emits and every face is open, else "constant". There the light entering through the
/// faces in order 0 is the whole answer, and what decides its error is where light entering
/// through a side really enters, which only the linear lattice places (the 32³ absorber box: worst
/// voxel 2.7 % → 1.8 % at k = 8, benches/RESULTS.md "Spatial schemes"); the numerical diffusion
/// that makes "linear" brighten scattering cores has nothing to act on. An emitting medium keeps
/// "constant": the bilinear gather spreads a small emitter's source over the rays around it
/// (Kobayashi problem 3 case i at 10 cm, a two-voxel source: C/E at the source 0.91 → 0.74).
/// Periodic and mirror faces keep "constant": mirrors need it, and the periodic hand-over was
/// validated on it. The second value is how the plan chose, for its reason ("" when the scene named
/// the scheme).
fn choose_spatial(scene: &Scene, scatters: bool) -> (SpatialScheme, &'static str) {
    let open = !scene.boundary.any_periodic() && !scene.boundary.any_reflective();
    match scene.solver.spatial {
        Some(named) => (named, ""),
        None if scatters => (
            SpatialScheme::Constant,
            " (auto: the medium scatters, and the diffusion correction is made for this lattice)",
        ),
        None if scene.medium.has_emission() => (
            SpatialScheme::Constant,
            " (auto: the medium emits, and this lattice keeps a small emitter's light where it is)",
        ),
        None if !open => (SpatialScheme::Constant, " (auto: periodic and mirror faces are solved on this lattice)"),
        None => (
            SpatialScheme::Linear,
            " (auto: nothing scatters or emits, so the light entering through the faces is the whole answer)",
        ),
    }
}

/// The sky's own directions per face axis when `solver.sky_directions_per_face` is not given:
/// where nothing scatters (and the scheme is "linear", whose entry through a side the fine set's
/// grazing directions need), 4k, at most [`AUTO_SKY_DIRECTIONS_MAX`]. Order 0 is then the whole
/// solve, so it may cost what 16 orders would; it cuts the direction set's own error next to a face
/// (1.75 % at a face centre at k = 8, falling as 1/k²) to below the lattice's (the absorber box at
/// k = 8: worst voxel 1.8 % → 0.76 %). Where the medium scatters the scattered light's ray effects
/// partly cancel the coarse sky's (a sphere in vacuum got worse with its own sky directions), so
/// the sky stays on the k×k directions.
fn auto_sky_directions(k: u32, spatial: SpatialScheme, scatters: bool) -> Option<u32> {
    (!scatters && spatial == SpatialScheme::Linear).then(|| (4 * k).min(AUTO_SKY_DIRECTIONS_MAX).max(k))
}

/// k_1, the scattered light's own directions per face axis (module docs), where a traced
/// emission's scattered light would streak on the k×k: `solver.scattered_directions_per_face`,
/// or by default the smallest multiple of k from [`SCATTERED_STREAK_FREE_K`] on; when it exceeds
/// k and the medium emits and scatters. (Only where no face hands rays on to the next order:
/// the plan makes the directions so, and unfolds mirrors for them.)
fn first_scatter_directions(scene: &Scene, k: u32, scatters: bool) -> Option<u32> {
    let n = scene.solver.scattered_directions_per_face.unwrap_or(SCATTERED_STREAK_FREE_K.div_ceil(k) * k);
    (scene.medium.has_emission() && scatters && n > k).then_some(n)
}

/// The orders (from order 1) that sweep the scattered light's own directions (module docs).
pub const SCATTERED_OWN_ORDERS: u32 = 2;

/// The most sky directions per face axis the plan chooses by itself: beyond 32 the linear
/// lattice's own error next to a face (~0.7 %) is what is left.
pub const AUTO_SKY_DIRECTIONS_MAX: u32 = 32;

/// κ per axis of the anti-diffusive fluxes (`solver.diffusion_correction = "on"`): half
/// the spread the discretisation adds per order ([`super::antidiffusion::lattice_spread`]), when
/// the medium scatters.
fn choose_diffusion_correction(
    scene: &Scene,
    medium: &Medium,
    faces: &[Vec<SweepDirection>],
    spatial: SpatialScheme,
    reasons: &mut Vec<String>,
) -> [f64; 3] {
    if !medium_scatters(medium) {
        return [0.0; 3];
    }
    match scene.solver.diffusion_correction {
        DiffusionCorrection::Off => [0.0; 3],
        DiffusionCorrection::On => {
            let kappa = super::antidiffusion::coefficients(faces, spatial);
            reasons.push(format!(
                "diffusion correction: the rays' lattice and segments spread each order's scattered light by \
                 a variance of {:.3}/{:.3}/{:.3} voxels² along x/y/z; anti-diffusive fluxes between \
                 voxels two apart take it back (κ = half of it, less in optically thick voxels for stability; conservative, each exchange capped so no voxel goes negative)",
                2.0 * kappa[0],
                2.0 * kappa[1],
                2.0 * kappa[2]
            ));
            kappa
        }
    }
}

/// The single-scattering albedo (of the medium solved) from which `solver.acceleration = "auto"`
/// accelerates the order series: below it the orders shrink fast enough by themselves (by about
/// the albedo each), and a diffusion solve per order would cost more than the orders it saves.
pub const ACCELERATION_MIN_ALBEDO: f64 = 0.9;

/// Whether each order is followed by a diffusion synthetic acceleration step
/// ([`super::acceleration`]).
fn choose_acceleration(scene: &Scene, medium: &Medium, spatial: SpatialScheme, reasons: &mut Vec<String>) -> bool {
    let albedo =
        medium.albedo.iter().zip(&medium.sigma_t).filter(|(_, &s)| s > 0.0).map(|(&a, _)| a).fold(0.0, f64::max);
    let (on, why) = match scene.solver.acceleration {
        Acceleration::Off => (false, "off (solver.acceleration = \"off\")".to_string()),
        _ if albedo <= 0.0 => (false, "off: the medium does not scatter".into()),
        _ if scene.boundary.any_reflective() => (
            false,
            "off: with mirror faces part of each order's light comes back from the mirrors in the next \
             order, which the correction's source would not see"
                .into(),
        ),
        _ if scene.boundary.any_periodic() => (
            false,
            "off: with periodic axes part of each order's light travels on in the rays to the next order, \
             which the correction's source would not see"
                .into(),
        ),
        _ if spatial == SpatialScheme::Linear => (
            false,
            "off: under spatial = \"linear\" the rays' bilinear lattice spreads light in a way diffusion \
             does not model, and in thick voxels at high albedo the corrected series diverges (measured: a 48³ cloud at \
             σt·h = 2, albedo 0.999, grew ×1.18 an order)"
                .into(),
        ),
        _ if scene.solver.extrapolate_tail => {
            (false, "off: solver.extrapolate_tail estimates the tail of the plain series instead".into())
        }
        Acceleration::Diffusion => (true, "diffusion (solver.acceleration = \"diffusion\")".into()),
        Acceleration::Auto if albedo >= ACCELERATION_MIN_ALBEDO => (
            true,
            format!(
                "diffusion: the albedo ({albedo}) is at least {ACCELERATION_MIN_ALBEDO}, where the orders shrink \
                 slowly; a diffusion solve after each order adds the light still to come"
            ),
        ),
        Acceleration::Auto => (
            false,
            format!("off: at albedo {albedo} (below {ACCELERATION_MIN_ALBEDO}) the orders shrink fast by themselves"),
        ),
    };
    reasons.push(format!("acceleration {why}"));
    on
}

/// g from which `solver.forward_peak = "auto"` applies δ-M scaling.
pub const DELTA_M_MIN_G: f64 = 0.5;

/// The medium and phase function the solver works with: the scene's, or their δ-M scaled form
/// ([`phase::Truncation`]: the fraction f of the scattering in HG(g)'s forward peak counted as not
/// scattered, σt' = σt·(1 − f·a), a' = (1 − f)·a/(1 − f·a); absorption σt·(1 − a) and the emission
/// term are unchanged; the remainder keeps HG(g)'s shape outside a forward cone of a few storage
/// cells, and f keeps the discrete scattering's transport cross-section the true one).
fn choose_forward_peak(
    scene: &Scene,
    propagation: &PropagationSet,
    storage: &StorageSet,
    reasons: &mut Vec<String>,
) -> (Medium, Phase) {
    let m = &scene.medium;
    let g = m.g;
    let kept = Phase::HenyeyGreenstein { g };
    if scene.volume.albedo.is_some() && g > 0.0 {
        // σt' = σt·(1 − f·albedo) would vary with each voxel's albedo; the validator refuses an
        // explicit "delta-m" with an albedo grid.
        reasons.push(format!(
            "phase function kept as it is (g = {g}): δ-M scaling does not combine with a per-voxel albedo"
        ));
        return (m.clone(), kept);
    }
    let apply = match scene.solver.forward_peak {
        ForwardPeak::Keep => false,
        ForwardPeak::DeltaM => g > 0.0,
        ForwardPeak::Auto => g >= DELTA_M_MIN_G,
    };
    if !apply {
        if g > 0.0 && scene.solver.forward_peak == ForwardPeak::Auto {
            reasons.push(format!("phase function kept as it is: g = {g} is below {DELTA_M_MIN_G}, no δ-M scaling"));
        }
        return (m.clone(), kept);
    }
    let t = Truncation::for_sets(g, propagation, storage);
    let f = t.fraction;
    let mut scaled = m.clone();
    for ch in 0..3 {
        let a = m.albedo[ch];
        scaled.sigma_t[ch] = m.sigma_t[ch] * (1.0 - f * a);
        scaled.albedo[ch] = if 1.0 - f * a > 0.0 { (1.0 - f) * a / (1.0 - f * a) } else { a };
    }
    scaled.g = t.remainder_g();
    let cells = ((1.0 - t.cone) * storage.len() as f64 / 2.0).round();
    let cone = if cells == 1.0 { "one storage cell's".to_string() } else { format!("{cells} storage cells'") };
    reasons.push(format!(
        "δ-M scaling of the forward peak (g = {g}): HG(g) is kept outside a forward cone of {:.1}° ({cone} \
         solid angle); of what it scatters into the cone ({:.3}) f = {f:.3} is treated as going \
         straight on and the rest spread evenly over the cone, f chosen so that the discrete \
         scattering keeps the transport cross-section σt·(1 − a·g) (σt and the albedo scaled to match, \
         absorption unchanged; the remainder's g is {:.3}); a few storage directions cannot hold a peak this narrow",
        t.cone.acos().to_degrees(),
        t.peak,
        scaled.g
    ));
    (scaled, Phase::Truncated(t))
}

/// 1 channel when the medium and every light are grey (and the plan may reduce), else 3.
fn choose_channels(scene: &Scene, full: bool, reasons: &mut Vec<String>) -> u32 {
    let grey = scene.is_grey();
    let (channels, why) = match (grey, full) {
        (true, false) => (1, "1 channel: the medium and every light are grey"),
        (true, true) => (3, "3 channels: plan = \"full\" (the medium and every light are grey, so 1 would do)"),
        (false, _) => (3, "3 channels: the medium, a light or the emission grid differs between r, g and b"),
    };
    reasons.push(why.into());
    channels
}

/// One storage direction for an isotropic medium (when the plan may reduce), else k_s×k_s per face
/// with k_s = `solver.storage_directions_per_face` or min(k, 2).
fn choose_storage(scene: &Scene, propagation: &PropagationSet, full: bool, reasons: &mut Vec<String>) -> StorageSet {
    let g = scene.medium.g;
    if g == 0.0 && !full {
        reasons.push("1 storage direction: the medium scatters isotropically (g = 0)".into());
        return StorageSet::isotropic(propagation);
    }
    let k = propagation.k;
    let ks = scene.solver.storage_directions_per_face.unwrap_or(k.min(2));
    let why = if g == 0.0 {
        "plan = \"full\" (the medium scatters isotropically, so 1 would do)".to_string()
    } else {
        format!("the medium is anisotropic (g = {g})")
    };
    reasons.push(format!("{} storage directions ({ks}×{ks} per face): {why}", 6 * ks * ks));
    StorageSet::per_face(propagation, ks)
}

/// The storage precision of the gained source: as `solver.storage_precision` says, or under
/// `auto` f16 when the tolerance allows it, except in a full plan, which keeps f32, and in an
/// accelerated solve: there a few orders carry the whole answer, and f16's rounding of a smooth
/// source (every voxel rounded alike) no longer averages out over hundreds of orders (a 16³ box at
/// albedo 0.98 lost 2.6e-4 of its power to it).
fn choose_precision(scene: &Scene, full: bool, accelerated: bool, reasons: &mut Vec<String>) -> Precision {
    let tolerance = scene.solver.tolerance;
    let (precision, why) = match scene.solver.storage_precision {
        StoragePrecision::F16 => (Precision::F16, "storage_precision = \"f16\" in the scene".to_string()),
        StoragePrecision::F32 => (Precision::F32, "storage_precision = \"f32\" in the scene".to_string()),
        StoragePrecision::Auto if full => {
            (Precision::F32, "auto under plan = \"full\": f16 is one of the reductions it turns off".to_string())
        }
        StoragePrecision::Auto if accelerated => (
            Precision::F32,
            "auto with the acceleration on: a few orders carry the answer, and f16's rounding of each would \
             not average out over many"
                .to_string(),
        ),
        StoragePrecision::Auto if tolerance >= F16_MIN_TOLERANCE => (
            Precision::F16,
            format!(
                "auto: the tolerance {tolerance:e} is at least {F16_MIN_TOLERANCE:e}, so f16's relative \
                 rounding (2^-11 ≈ 4.9e-4) stays below it"
            ),
        ),
        StoragePrecision::Auto => (
            Precision::F32,
            format!(
                "auto: the tolerance {tolerance:e} is below {F16_MIN_TOLERANCE:e}, so f16's relative \
                 rounding (2^-11 ≈ 4.9e-4) could show in the result"
            ),
        ),
    };
    reasons.push(match precision {
        Precision::F16 => format!(
            "the source the rays gain is stored in f16, scaled per order by a power of two ({why}): \
             half the bytes of that source on the device and in the upload; accumulators and the \
             store stay f32"
        ),
        Precision::F32 => format!("the source the rays gain is stored in f32 ({why}); all fields are f32"),
    });
    precision
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plan of a 16³ emitting sphere with `solver` lines and `boundary` lines added.
    fn plan_of(albedo: f64, solver: &str, boundary: &str) -> Plan {
        let text = format!(
            "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = {albedo}\n\
             emission = 1.0\n[solver]\n{solver}\n[boundary]\n{boundary}\n"
        );
        let scene = Scene::from_toml_str(&text, std::path::Path::new("t.toml")).expect("scene");
        Plan::new(&scene, 1, 0)
    }

    #[test]
    fn the_scattered_light_takes_the_smallest_multiple_of_k_from_twelve() {
        for (k, k1) in [(5, 15), (4, 12), (3, 12), (6, 12), (8, 16), (12, 12), (16, 16)] {
            let plan = plan_of(0.5, &format!("directions_per_face = {k}"), "");
            assert_eq!(plan.scattered_directions_per_face(), k1, "k = {k}");
            let dirs: usize = plan.scattered_faces.iter().map(Vec::len).sum();
            assert_eq!(dirs, if k1 > k { 6 * (k1 * k1) as usize } else { 0 }, "k = {k}");
        }
        // Fine cells lie in one propagation cell each, whose storage direction they gain.
        let plan = plan_of(0.5, "directions_per_face = 5\nstorage_directions_per_face = 5", "");
        for dir in plan.scattered_faces.iter().flatten() {
            let owner = plan.storage.owner[plan.propagation.containing(dir.omega)];
            assert_eq!(dir.gain_storage, owner);
            assert_eq!(dir.boundary, [0.0; 3]);
        }
        // Asked for, kept on the k×k, or nothing to scatter: none.
        let asked = plan_of(0.5, "directions_per_face = 5\nscattered_directions_per_face = 10", "");
        assert_eq!(asked.scattered_directions_per_face(), 10);
        assert!(plan_of(0.5, "directions_per_face = 5\nscattered_directions_per_face = 5", "")
            .scattered_faces
            .is_empty());
        assert!(plan_of(0.0, "directions_per_face = 5", "").scattered_faces.is_empty());
        // A mirror: no directions of its own here, the solve unfolds the mirror for them; a
        // swept emission drops both.
        let mut mirrored = plan_of(0.5, "directions_per_face = 5", "x = [\"reflective\", \"open\"]");
        assert!(mirrored.scattered_faces.is_empty() && mirrored.unfolds_for_scattered == Some(15));
        assert_eq!(mirrored.scattered_directions_per_face(), 15);
        mirrored.sweep_emission();
        assert_eq!(mirrored.unfolds_for_scattered, None);
        assert_eq!(mirrored.scattered_directions_per_face(), 5);
        let both = plan_of(0.5, "directions_per_face = 5", "x = \"reflective\"");
        assert!(both.scattered_faces.is_empty() && both.unfolds_for_scattered.is_none());
    }
}
