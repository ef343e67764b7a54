//! Emission's uncollided light traced from the emitting voxels (`solver.emission_uncollided`): a
//! first-collision source, so small emitters light the volume without ray effects.
//!
//! Swept, an emitting voxel's light leaves it only along the k×k×6 propagation directions, each
//! carrying a whole solid-angle patch: far from a small emitter the light breaks into streaks
//! (Kobayashi 2001's pure absorber: C/E from 0.60 to 3.4 at k = 5, `benches/RESULTS.md`). Traced,
//! the uncollided fluence of every emitting voxel s at every voxel v is computed on the host (by
//! the GPU backend on the device: "On the GPU" below), as [`super::point`] does for a point light,
//!
//! `φ_unc(v) = h·Σ_s J_s·G(s, v)`,  `G` = the mean over both voxels of `T/r²` (voxel units),
//!
//! `J_s = ρσa·Le·e` the emission's source (W/m³/sr, the f32 value the swept path writes), T the
//! transmittance of the plan's σt (δ-M scaled where the plan scales) along the segment, by the
//! exact 3-D DDA of [`super::point::optical_path`]. Near pairs (every offset |c_i| ≤ 2, the
//! emitter itself included) take [`kernel`]'s exact polar integration of the two cubes'
//! autocorrelation, tabulated over σ (within 0.05 % of a 6-D quadrature; σ the pair segment's
//! mean). Far pairs take the source voxel at its 2³ Gauss points, each with its own segment (a
//! segment that grazes a face of the medium bends the transmittance sharply across the voxel:
//! at Kobayashi's source corner the centre alone was 15 % off for one voxel, 3.5 % at a detector),
//! and the target voxel's mean to second order ([`clusters`]). Against the exact voxel means of
//! one emitting voxel in a uniform absorber (σt·h = 0.3): within 0.13 % everywhere from 3 voxels
//! on (`tests/it/emission_uncollided.rs`).
//!
//! It joins order 0 as a point light's does: `φ_unc` goes into order 0's fluence, its first
//! scattering `J_d(v) = ρσs·φ_unc·row_d` into order 0's new source (row: that of the received
//! flux's mean direction blended with the isotropic row by `1 − |flux|/φ`, the point light's rule;
//! a near pair's flux is taken along the centres' offset), and the emission's swept source is
//! not written (the kernels' uniform emission is off, `solver::emission`'s source is not
//! written): nothing counts twice.
//!
//! **Scaling.** The emitters form an octree of clusters ([`clusters`]). A target takes a cluster
//! as one source when it lies at least [`clusters::KAPPA`] = 4 cluster radii R away, the
//! cluster's optical radius σ_max·R is at most [`clusters::TAU`] = 0.5, no member lies on a face of
//! the medium (a face neighbour's σt·h differs by more than [`clusters::EDGE_STEP`] = 0.02: a segment grazing that face
//! bends the transmittance within the voxel, which only the voxel's own Gauss points see), and the
//! transmittance does not bend across it (the children's mean optical depth to the target and the
//! centroid's differ by at most [`clusters::SPREAD`] = 0.02);
//! it then costs one segment per child (each child's transmittance and distance its own, the
//! spread within the children to second order, both of 1/r² and of the members' own depth in the
//! child's medium: a member δ nearer the target along u has s·(u·δ) less optical depth, s the
//! child's σt·h, so the child's term takes the factor 1 + ⟨(u·δ)²⟩·s·(s/2 + 2/r)) instead of one
//! per emitter. The error this allows is the third order of R/r and of s·R within the children
//! and the transmittance's bend below SPREAD: measured against every pair exact, a 12³ block of
//! uneven emitters in a uniform medium (σt·h = 0.02 and 0.1) is within 0.10 % and 0.25 % at every
//! target of a 40³ region (`clusters::tests::clusters_agree_with_exact_pairs`, 20–50× fewer
//! segments; 0.5 % at σt·h = 0.1 without the depth factor); a flame-like ball of 515 emitters whose
//! source falls off steeply from its centre, in smooth uneven smoke of σt·h 0.03–0.17 (the fire
//! scene's range), within **1.4 % worst, 0.31 % rms** at every 5th target of a 40³ region, with 14×
//! fewer segments (`…::clusters_agree_with_exact_pairs_in_uneven_smoke`; 1.9 % and 0.54 % without
//! the depth factor; what remains is the transmittance's bend through uneven smoke, which SPREAD
//! bounds: 0.005 instead of 0.02 gave 0.8 %, at up to twice the segments); and Kobayashi's source
//! (σt·h = 0.2, grazing segments at its corner) within 0.06 % at the detectors
//! (`clusters::tests::a_source_corner_whose_segments_graze_its_faces`). The cost: a compact
//! emitter's faces are never clustered, so a target walks a few Gauss-point segments per face
//! voxel of each near or compact emitter (Kobayashi problem 1's octant, 1000 emitters with their
//! images, half of them on the source's faces: 22 min on two cores, `benches/RESULTS.md`); a large
//! emission's interior is clustered.
//!
//! **Mirror faces** (the method of images): an emitter next to a mirror lights the volume also as
//! its image beyond the mirror. The trace runs in the volume unfolded by its mirrors (a mirror on
//! the low face of x: cells −n..n, the density at −1 − i that of i), with every emitter's images
//! as emitters; a mirror on both faces of an axis, or a periodic axis (an infinite row of images),
//! is not traced (the plan sweeps).
//!
//! **The plan's choice** (`solver.emission_uncollided`, [`choose`]): `"traced"`, `"swept"`, or
//! `"auto"`, which traces when the emission is compact — at most [`AUTO_MAX_EMITTING_FRACTION`] (a
//! quarter) of the medium's voxels emit, so there is a small emitter to streak and the trace's
//! cost (emitters × voxels, less the clusters' savings) stays near a point light's — and its light
//! leaves it: the emitters' source-weighted σt·h is at most [`AUTO_MAX_SIGMA_H`] (1; thicker
//! emitters absorb or scatter their own light within a voxel, and the swept first scattering has
//! no streaks to lose). A periodic axis or mirrors on both faces of an axis always sweep. The
//! plan's reasons say which and why with the numbers, and `report.json`'s phases give the trace's
//! time (`"emission trace"`). Where the medium scatters, the light the trace hands to order 0's
//! new source is itself compact, and swept along the k×k it streaks where it dominates (Kobayashi's
//! case ii: every detector within 10 % only from k = [`SCATTERED_STREAK_FREE_K`] = 12): so orders
//! 1 and 2 sweep it along directions of their own, at least 12 per face (`solver::plan`, "The
//! scattered light's own directions"); with `solver.scattered_directions_per_face = k` the reason
//! says it still streaks. `auto` also sweeps where the trace would cost more than
//! [`AUTO_MAX_PAIRS`] emitter–voxel pairs (the fire scene's grid): `"traced"` forces it.
//!
//! **The Monte-Carlo reference** samples an emission photon's voxel by its ρ·σa·e and its position
//! uniformly within the voxel, and tallies voxel means by track length (`reference::fluence`): its
//! near field is the exact voxel mean of a uniform voxel source, what [`kernel`] integrates.
//!
//! **Energy.** The emission puts out `P = Σ_s 4π·J_s·h³` (the books' `emitted`). The medium takes
//! `Σ_v ρσt·φ_unc·h³` of it, counted from the f32 values written (absorbed through the fluence,
//! scattered through order 0's new source), and the rest leaves without interacting: the books'
//! `uncollided_escaped`, `P` minus what the medium takes (so they close to round-off; that the
//! taking is right is the kernel's conservation, `kernel::tests`, and the analytic emitter's test).
//!
//! A long trace logs its progress in bricks ([`super::progress_lines`]): it runs inside the plan's
//! stage, whose progress says nothing meanwhile.
//!
//! Written once here for both backends, before order 0, into the fields order 0 accumulates
//! (after the point lights': it adds to them). Brick by brick over the occupied bricks, in parallel
//! (rayon), in groups of [`RELEASE_UNITS`] bricks whose pages are then handed back; the emitters
//! are a list (one entry per emitting voxel and image: the only array that grows with the scene,
//! with the emission rather than the volume). Each voxel's values depend only on the scene: bitwise
//! the same at any thread count.
//!
//! **On the GPU** ([`gpu`]). The GPU backend computes what each voxel receives on the device:
//! `glsl/uncollided_trace.comp` is [`clusters::Clusters::receive`] in f32, one invocation per voxel
//! of a batch of target bricks, over the same tree (flattened, with the edge flags made here), the
//! same acceptance tests ([`clusters::KAPPA`], [`clusters::TAU`], [`clusters::SPREAD`], passed from
//! the host), the same near table, Gauss points, target ends and exact DDA through the unfolded
//! frame's density; the host's walk is its CPU twin, and the bookkeeping above takes either's
//! values (one copy of it). Where both walks take the same pairs, every voxel's fluence and flux
//! agree within 1e-5 relative (f32 rounding; 7.8e-7 measured on a mirrored, heterogeneous,
//! three-channel scene, `tests/it/uncollided_gpu.rs`); where an acceptance test sits on its
//! threshold the f32 walk may take a cluster whole that the f64 walk opens, or the reverse, and
//! that voxel then differs by the clustering's own error (within 0.5 %). It is bitwise the same run
//! to run. On the device it needs the tree (84 bytes a node, about two nodes an emitter), the
//! emitters (36 bytes each), the volume's density as one dense f32 array (4 bytes a voxel) and, per
//! batch of [`gpu::BATCH_BRICKS`] bricks, 5.2 MB of results (on a CPU implementation, whose
//! shaders leave loops after 65535 iterations, also each walk's stack, saved between the rounds it
//! runs in); every buffer must fit the device's `maxStorageBufferRange` (128 MiB on lavapipe: at
//! most 2²⁵ voxels), and the dense density with its staging copy half the host memory available.
//! Where one does not, where the tree is deeper than the kernel's stack, a
//! voxel's σt·h is beyond 64 or (on lavapipe) the unfolded frame too long for a round, the kernel
//! declines and the host walks: a log line and the report's note say so (`… on the host, N threads
//! (the GPU kernel declined: why)`); else the note says `on the GPU (device)`.

pub mod clusters;
pub mod gpu;
pub mod kernel;

use super::cancel::CancelFlag;
use super::emission::{scales, Factors};
use super::passes::RELEASE_UNITS;
use super::plan::Plan;
use super::point::{optical_path_in, RowTable};
use super::progress_lines::StepProgress;
use super::SolveError;
use crate::quadrature::phase::BeamRows;
use crate::scene::EmissionUncollided;
use crate::store::{BrickStore, Field, BRICK_EDGE, BRICK_VOXELS};
use crate::vk::Context;
use clusters::{Clusters, Emitter, Received, Work};
use glam::DVec3;
use kernel::NearTable;
use rayon::prelude::*;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// `auto` traces only while emitting voxels × medium voxels is at most this: the trace costs about
/// that many ray walks (fewer where clusters form), 2.5·10⁷ pairs some minutes on two cores
/// (Kobayashi problem 1 at 2 cm, 1.6·10⁷ pairs, took 22 min with its source's faces never
/// clustered); beyond, the solve would wait far longer on the trace than on its orders (the fire
/// scene, ~10⁹ pairs, did not finish in 20 min), so `auto` sweeps and says so.
pub const AUTO_MAX_PAIRS: f64 = 2.5e7;

/// `auto` traces when at most this fraction of the medium's voxels (density > 0) emit.
pub const AUTO_MAX_EMITTING_FRACTION: f64 = 0.25;

/// `auto` traces when the emitters' source-weighted σt·h is at most this: their light leaves them.
pub const AUTO_MAX_SIGMA_H: f64 = 1.0;

/// The volume unfolded by its mirrors: per axis the cells `lo..hi`, and where a cell images.
#[derive(Clone, Copy, Debug)]
pub struct Unfolded {
    pub dims: [u32; 3],
    pub lo: [i64; 3],
    pub hi: [i64; 3],
}

impl Unfolded {
    /// `None` when some axis has mirrors on both faces (infinitely many images).
    pub fn new(dims: [u32; 3], reflective: [[bool; 2]; 3]) -> Option<Unfolded> {
        let mut lo = [0i64; 3];
        let mut hi = dims.map(|n| n as i64);
        for a in 0..3 {
            match reflective[a] {
                [true, true] => return None,
                [true, false] => lo[a] = -(dims[a] as i64),
                [false, true] => hi[a] = 2 * dims[a] as i64,
                [false, false] => {}
            }
        }
        Some(Unfolded { dims, lo, hi })
    }

    /// The volume's cell a cell of the unfolded frame images.
    pub fn source(&self, c: [i64; 3]) -> [u32; 3] {
        std::array::from_fn(|a| {
            let n = self.dims[a] as i64;
            let i = if c[a] < 0 {
                -1 - c[a]
            } else if c[a] >= n {
                2 * n - 1 - c[a]
            } else {
                c[a]
            };
            i as u32
        })
    }

    /// Every image of the volume's cell `v` (itself first).
    pub fn images(&self, v: [u32; 3]) -> Vec<[i64; 3]> {
        let mut out = vec![v.map(|x| x as i64)];
        for a in 0..3 {
            let n = self.dims[a] as i64;
            if self.lo[a] < 0 || self.hi[a] > n {
                let more: Vec<[i64; 3]> = out
                    .iter()
                    .map(|c| {
                        let mut m = *c;
                        m[a] = if self.lo[a] < 0 { -1 - c[a] } else { 2 * n - 1 - c[a] };
                        m
                    })
                    .collect();
                out.extend(more);
            }
        }
        out
    }
}

/// What the plan decided, and the numbers it decided from.
#[derive(Clone, Debug)]
pub struct Choice {
    pub traced: bool,
    pub reason: String,
}

/// Whether `plan`'s emission is traced under `setting`, from the store's emitters (module docs:
/// `auto` traces a compact emission whose light leaves its voxels, where the boundary faces allow).
pub fn choose(store: &BrickStore, plan: &Plan, setting: EmissionUncollided) -> Result<Choice, SolveError> {
    let emits = plan.emission || plan.emission_field;
    if !emits {
        return Ok(Choice { traced: false, reason: String::new() });
    }
    if setting == EmissionUncollided::Swept {
        return Ok(Choice {
            traced: false,
            reason: "emission's uncollided light swept (solver.emission_uncollided = \"swept\")".into(),
        });
    }
    if plan.periodic.contains(&true) || Unfolded::new(plan.dims, plan.reflective).is_none() {
        return Ok(Choice {
            traced: false,
            reason: "emission's uncollided light swept: a periodic axis or mirrors on both faces of an axis \
                     image the emitters without end, which the trace does not follow"
                .into(),
        });
    }
    let (emitting, occupied, sigma_h) = emission_extent(store, plan)?;
    let fraction = emitting as f64 / occupied.max(1) as f64;
    let hint = scattered_light_hint(plan);
    if setting == EmissionUncollided::Traced {
        return Ok(Choice {
            traced: true,
            reason: format!(
                "emission's uncollided light traced from its {emitting} emitting voxels (solver.emission_uncollided \
                 = \"traced\"): no ray effects around small emitters{hint}"
            ),
        });
    }
    let compact = fraction <= AUTO_MAX_EMITTING_FRACTION;
    let leaves = sigma_h <= AUTO_MAX_SIGMA_H;
    let pairs = emitting as f64 * occupied as f64;
    let affordable = pairs <= AUTO_MAX_PAIRS;
    let traced = compact && leaves && affordable && emitting > 0;
    let why = format!(
        "{emitting} of the medium's {occupied} voxels emit ({:.3} %, traced up to {} %), their source-weighted σt·h {sigma_h:.3} \
         (traced up to {AUTO_MAX_SIGMA_H})",
        100.0 * fraction,
        100.0 * AUTO_MAX_EMITTING_FRACTION
    );
    Ok(Choice {
        traced,
        reason: if traced {
            format!(
                "emission's uncollided light traced (auto): {why}: a compact emission whose light leaves it would \
                 streak along the swept directions{hint}"
            )
        } else {
            format!(
                "emission's uncollided light swept (auto): {why}: {}",
                if !compact {
                    "the emission fills the medium (no small emitter to streak; the trace would cost E × N)".to_string()
                } else if !leaves {
                    "the emitters are optically thick: their light is absorbed or scattered within a voxel".to_string()
                } else {
                    format!(
                        "the trace would pair the emitters with the medium's voxels {pairs:.2e} times (auto traces up \
                         to {AUTO_MAX_PAIRS:.1e}; solver.emission_uncollided = \"traced\" traces anyway)"
                    )
                }
            )
        },
    })
}

/// The directions per face from which a traced compact emitter's *scattered* light no longer
/// streaks at detector accuracy: Kobayashi's case ii, traced, reads rms ln(C/E) 0.085–0.115 at
/// k = 5 and 0.030–0.031 at k = 12, every detector within 10 % (`benches/RESULTS.md`). The plan
/// sweeps the first- and second-scattered light along at least this many per face of their own
/// (`solver::plan`, "The scattered light's own directions").
pub const SCATTERED_STREAK_FREE_K: u32 = 12;

/// What the plan adds to a traced emission's reason when the medium scatters, k is below
/// [`SCATTERED_STREAK_FREE_K`] and the first scattering was kept on the k×k
/// (`solver.scattered_directions_per_face = k`): its ray effects remain where it dominates.
fn scattered_light_hint(plan: &Plan) -> String {
    let k = plan.propagation.k;
    let scatters = plan.medium.albedo.iter().any(|&a| a > 0.0);
    if !scatters || k >= SCATTERED_STREAK_FREE_K || plan.scattered_directions_per_face() > k {
        return String::new();
    }
    format!(
        "; its first scattering is swept along the {k}×{k} and still streaks where it dominates (Kobayashi's case ii: \
         within 10 % everywhere only from {SCATTERED_STREAK_FREE_K} directions per face): leave \
         solver.scattered_directions_per_face to the plan where that matters"
    )
}

/// Emitting voxels, the medium's voxels (density > 0), and the emitters' source-weighted σt·h
/// (channel mean).
fn emission_extent(store: &BrickStore, plan: &Plan) -> Result<(u64, u64, f64), SolveError> {
    let mut emitting = 0u64;
    let mut occupied = 0u64;
    let (mut weighted, mut total) = (0.0f64, 0.0f64);
    let c = plan.channels as usize;
    let h = plan.voxel_size;
    let st: f64 = (0..c).map(|ch| plan.coefficients(ch).0).sum::<f64>() / c as f64;
    each_emitter(store, plan, &mut |_, rho, j| {
        let s: f64 = j[..c].iter().sum();
        // The medium's voxels (empty space inside an occupied brick is no medium).
        if rho > 0.0 {
            occupied += 1;
        }
        if s > 0.0 {
            emitting += 1;
            weighted += s * rho * st * h;
            total += s;
        }
    })?;
    Ok((emitting, occupied, if total > 0.0 { weighted / total } else { 0.0 }))
}

/// Calls `visit(voxel, density, J per channel)` for every voxel of the occupied bricks, in brick
/// order (J as the swept path would write it, f32).
fn each_emitter(
    store: &BrickStore,
    plan: &Plan,
    visit: &mut dyn FnMut([u32; 3], f64, [f64; 3]),
) -> Result<(), SolveError> {
    let factors = Factors::open(store, plan)?;
    let c = plan.channels as usize;
    let scale = scales(plan);
    let grid = *store.grid();
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut values = vec![[0.0f64; 3]; BRICK_VOXELS];
    for brick in bricks {
        let Some(density) = store.density_brick(brick) else { continue };
        for ch in 0..c {
            factors.each(brick, density, ch, scale[ch], &mut |l, v| values[l][ch] = v as f64);
        }
        let b = grid.brick_coords(brick);
        let origin = grid.brick_origin(b);
        let extent = grid.brick_extent(b);
        for lz in 0..extent[2] {
            for ly in 0..extent[1] {
                for lx in 0..extent[0] {
                    let l = (lx + BRICK_EDGE * (ly + BRICK_EDGE * lz)) as usize;
                    visit([origin[0] + lx, origin[1] + ly, origin[2] + lz], density[l] as f64, values[l]);
                }
            }
        }
    }
    store.release_all_density();
    Ok(())
}

/// What the trace did: the powers for the books, and its size, time and where it ran for the
/// report.
#[derive(Clone, Debug, Default)]
pub struct Traced {
    /// `Σ 4π·J·h³` per channel: what the emission puts out.
    pub emitted: [f64; 3],
    /// `Σ ρσt·φ_unc·h³` per channel, from the f32 values written: what the medium takes.
    pub interacting: [f64; 3],
    /// Emitting voxels with their mirror images, and tree nodes.
    pub emitters: usize,
    pub nodes: usize,
    pub work: Work,
    /// Wall time of the trace.
    pub seconds: f64,
    /// The device the kernel ran on ([`gpu`]); `None`: the host walked the tree.
    pub device: Option<String>,
    /// The host's threads, where it walked.
    pub threads: usize,
    /// Why the device was asked and declined (the host walked instead).
    pub fallback: Option<String>,
}

impl Traced {
    /// The report's line on the trace, when there was one.
    pub fn note(&self) -> Option<String> {
        (self.emitters > 0).then(|| {
            format!(
                "emission trace: {} emitters (mirror images included), {} tree nodes; {} clusters taken whole, {} exact \
                 near pairs, {} far pairs, in {:.2} s {}",
                self.emitters,
                self.nodes,
                self.work.clusters,
                self.work.near,
                self.work.far,
                self.seconds,
                self.ran_on()
            )
        })
    }

    /// Where the trace ran: "on the GPU (device)" or "on the host, N threads" (and why the GPU
    /// did not, where it was asked).
    pub fn ran_on(&self) -> String {
        match (&self.device, &self.fallback) {
            (Some(device), _) => format!("on the GPU ({device})"),
            (None, Some(why)) => format!("on the host, {} threads (the GPU kernel declined: {why})", self.threads),
            (None, None) => format!("on the host, {} threads", self.threads),
        }
    }

    /// What leaves without interacting: `emitted − interacting` per channel (module docs).
    pub fn escaped(&self) -> [f64; 3] {
        std::array::from_fn(|ch| self.emitted[ch] - self.interacting[ch])
    }
}

/// Adds the emission's uncollided fluence into `fluence` (order 0's) and its first scattering into
/// `source_next` (order 0's new source), both as the point lights left them ([module docs](self)).
pub fn add_order0(
    store: &BrickStore,
    plan: &Plan,
    fluence: &mut Field,
    source_next: &mut Field,
) -> Result<Traced, SolveError> {
    add_order0_with(store, plan, fluence, source_next, false)
}

/// [`add_order0`], with `exact` taking every pair exactly (no clusters; tests).
pub fn add_order0_with(
    store: &BrickStore,
    plan: &Plan,
    fluence: &mut Field,
    source_next: &mut Field,
    exact: bool,
) -> Result<Traced, SolveError> {
    add_order0_on(store, plan, fluence, source_next, exact, None, None)
}

/// [`add_order0_with`], the voxels' light computed by the device kernel on `device` where given
/// ([`gpu`]; the host walks the tree where the kernel declines, and the report says why), else
/// by the host's walk; the bookkeeping is the same. Once `cancel` is raised the trace stops
/// within a voxel's walk (the host looks before each voxel, the device before each batch) and
/// returns [`SolveError::Cancelled`]: a trace of a large fire takes minutes (issue 57: a SIGTERM
/// waited 30 s to 10 minutes for it).
pub fn add_order0_on(
    store: &BrickStore,
    plan: &Plan,
    fluence: &mut Field,
    source_next: &mut Field,
    exact: bool,
    device: Option<&Arc<Context>>,
    cancel: Option<CancelFlag>,
) -> Result<Traced, SolveError> {
    let stopped = || super::cancel::raised(cancel);
    let started = Instant::now();
    let Some(frame) = Unfolded::new(plan.dims, plan.reflective) else {
        return Ok(Traced::default());
    };
    let c = plan.channels as usize;
    let comps = plan.source_components() as usize;
    let h = plan.voxel_size;
    let h3 = h * h * h;
    let four_pi: f64 = plan.storage.solid_angle.iter().sum();
    let coefficients: Vec<(f64, f64, f64)> = (0..c).map(|ch| plan.coefficients(ch)).collect();
    let mut extinction = [0.0; 3];
    for ch in 0..c {
        extinction[ch] = coefficients[ch].0 * h;
    }
    let largest_extinction = extinction[..c].iter().cloned().fold(0.0, f64::max);
    // The emitters and their images.
    let mut emitters = Vec::new();
    let mut emitted = [0.0f64; 3];
    each_emitter(store, plan, &mut |v, rho, j| {
        if j[..c].iter().all(|&x| x <= 0.0) {
            return;
        }
        for ch in 0..c {
            emitted[ch] += four_pi * j[ch] * h3;
        }
        let sigma = std::array::from_fn(|ch| extinction[ch] * rho);
        // On a face of the medium: a face neighbour's (its image's beyond a mirror) σt·h differs
        // by more than clusters::EDGE_STEP.
        let edge = (0..3).any(|a| {
            [-1i64, 1].iter().any(|&step| {
                let mut c = v.map(|x| x as i64);
                c[a] += step;
                let inside = c[a] >= frame.lo[a] && c[a] < frame.hi[a];
                let other = if inside { store.density_at(frame.source(c)) as f64 } else { 0.0 };
                largest_extinction * (other - rho).abs() > clusters::EDGE_STEP
            })
        });
        for cell in frame.images(v) {
            emitters.push(Emitter { cell, j, sigma, edge });
        }
    })?;
    let mut traced = Traced { emitted, emitters: emitters.len(), ..Traced::default() };
    if emitters.is_empty() {
        return Ok(traced);
    }
    let tree = Clusters::new(emitters);
    traced.nodes = tree.nodes();
    let table = NearTable::new();
    let exact_rows = BeamRows::new(&plan.propagation, &plan.storage, &plan.phase);
    let isotropic = exact_rows.isotropic_row();
    let rows = (!exact_rows.is_isotropic()).then(|| RowTable::new(&exact_rows));
    let density = |cell: [i64; 3]| store.density_at(frame.source(cell));
    let path = |a: DVec3, b: DVec3| optical_path_in(frame.lo, frame.hi, &density, a, b);
    let storage = plan.storage.solid_angle.clone();
    let grid = *store.grid();
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    traced.threads = rayon::current_num_threads();
    let mut device = match device {
        Some(ctx) => {
            match gpu::DeviceTrace::for_store(ctx, store, &tree, &table, frame, extinction, c, h, exact, &bricks)? {
                Ok(d) => Some(d),
                Err(why) => {
                    tracing::warn!("emission trace on the host: the GPU kernel declined: {why}");
                    traced.fallback = Some(why);
                    None
                }
            }
        }
        None => None,
    };
    traced.device = device.as_ref().map(|d| d.device.clone());
    // One brick: adds into its fluence and source blocks what each voxel receives (`given`, the
    // device's, or else the host's walk); its power taken and work per channel.
    let brick_pass = |brick: usize, fl: &mut [f32], src: &mut [f32], given: Option<&[Received]>| -> ([f64; 3], Work) {
        let mut p = [0.0f64; 3];
        let mut work = Work::default();
        let Some(rho) = store.density_brick(brick) else { return (p, work) };
        let b = grid.brick_coords(brick);
        let origin = grid.brick_origin(b);
        let extent = grid.brick_extent(b);
        let mut directed = isotropic.clone();
        for lz in 0..extent[2] as usize {
            for ly in 0..extent[1] as usize {
                for lx in 0..extent[0] as usize {
                    // One voxel's walk over the emitters' tree takes up to a tenth of a second in a
                    // large fire: looked at every voxel (an atomic load, nothing beside the walk).
                    if stopped() {
                        return (p, work);
                    }
                    let local = lx + BRICK_EDGE as usize * (ly + BRICK_EDGE as usize * lz);
                    let cell = [
                        (origin[0] as usize + lx) as i64,
                        (origin[1] as usize + ly) as i64,
                        (origin[2] as usize + lz) as i64,
                    ];
                    let density = rho[local] as f64;
                    let sigma_v = std::array::from_fn(|ch| extinction[ch] * density);
                    let got = match given {
                        Some(values) => values[local],
                        None => tree.receive(cell, sigma_v, c, extinction, h, &table, &path, exact, &mut work),
                    };
                    for ch in 0..c {
                        let k = ch * BRICK_VOXELS + local;
                        let before = fl[k];
                        fl[k] = (before as f64 + got.fluence[ch]) as f32;
                        p[ch] += density * coefficients[ch].2 * (fl[k] as f64 - before as f64) * h3;
                    }
                    let total: f64 = got.fluence[..c].iter().sum();
                    let scatters = density > 0.0 && (0..c).any(|ch| coefficients[ch].1 > 0.0 && got.fluence[ch] > 0.0);
                    if !scatters {
                        continue;
                    }
                    let weight = if total > 0.0 { (got.flux.length() / total).min(1.0) } else { 0.0 };
                    if let (Some(rows), true) = (&rows, weight > 0.0) {
                        rows.row_into(got.flux / got.flux.length(), &mut directed);
                    }
                    for (d, (&rd, &ri)) in directed.iter().zip(&isotropic).enumerate() {
                        let row = weight * rd + (1.0 - weight) * ri;
                        for ch in 0..c {
                            let k = (d * c + ch) * BRICK_VOXELS + local;
                            let before = src[k];
                            src[k] = (before as f64 + density * coefficients[ch].1 * got.fluence[ch] * row) as f32;
                            p[ch] += storage[d] * (src[k] as f64 - before as f64) * h3;
                        }
                    }
                }
            }
        }
        (p, work)
    };
    let (fl_len, src_len) = (c * BRICK_VOXELS, comps * BRICK_VOXELS);
    // It runs inside the plan's stage, which reports nothing meanwhile.
    let progress = Mutex::new(StepProgress::new("emission trace", "bricks", bricks.len() as u32));
    for first in (0..bricks.len()).step_by(RELEASE_UNITS) {
        let last = (first + RELEASE_UNITS).min(bricks.len());
        let fl = &mut fluence.as_mut_slice()[first * fl_len..last * fl_len];
        let src = &mut source_next.as_mut_slice()[first * src_len..last * src_len];
        // The host walks the group at once, the device computes it in batches of its own.
        let step = device.as_ref().map_or(last - first, |d| d.batch());
        for start in (first..last).step_by(step) {
            if stopped() {
                return Err(SolveError::Cancelled { resumable: false });
            }
            let end = (start + step).min(last);
            let given = match device.as_mut() {
                Some(d) => {
                    let (values, work) = d.receive(start, end - start)?;
                    traced.work.clusters += work.clusters;
                    traced.work.near += work.near;
                    traced.work.far += work.far;
                    Some(values)
                }
                None => None,
            };
            let fl = &mut fl[(start - first) * fl_len..(end - first) * fl_len];
            let src = &mut src[(start - first) * src_len..(end - first) * src_len];
            let results: Vec<([f64; 3], Work)> = fl
                .par_chunks_mut(fl_len)
                .zip(src.par_chunks_mut(src_len))
                .zip(&bricks[start..end])
                .enumerate()
                .map(|(i, ((fl, src), &brick))| {
                    // Cancelled: the rest of the group is skipped, and the trace returns below.
                    if stopped() {
                        return ([0.0; 3], Work::default());
                    }
                    let given = given.as_ref().map(|v| &v[i * BRICK_VOXELS..(i + 1) * BRICK_VOXELS]);
                    let result = brick_pass(brick, fl, src, given);
                    if let Ok(mut p) = progress.lock() {
                        p.step_done();
                    }
                    result
                })
                .collect();
            if stopped() {
                return Err(SolveError::Cancelled { resumable: false });
            }
            // Summed in slot order: the same at any thread count.
            for (p, w) in results {
                for ch in 0..c {
                    traced.interacting[ch] += p[ch];
                }
                traced.work.clusters += w.clusters;
                traced.work.near += w.near;
                traced.work.far += w.far;
            }
        }
        fluence.release_stored(first, RELEASE_UNITS);
        source_next.release_stored(first, RELEASE_UNITS);
        store.release_all_density();
    }
    fluence.flush()?;
    source_next.flush()?;
    traced.seconds = started.elapsed().as_secs_f64();
    Ok(traced)
}
