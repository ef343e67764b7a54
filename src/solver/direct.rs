//! The direct light's first scattering split off the source an image is made from (issue 38,
//! item 1): what the renderer needs to evaluate the suns' and point lights' single scattering
//! exactly along each camera ray instead of reading it from the binned, δ-M-scaled source.
//!
//! **What counts as direct light.** The collimated beams of the plan ([`Plan::beams`]): every
//! `[[lights]] kind = "sun"` and an environment map's sun-like peak. Their first scattering is a
//! delta in incident direction, so its angular shape is the phase function itself, which storage
//! cells a few tens of degrees wide cannot hold (g = 0.8: half the forward lobe lies within 20°
//! of the sun). Point lights too: their light reaches each voxel from one direction (the light's),
//! and [`super::point`] computed it exactly there; their first scattering, what
//! [`super::point::write_order0`] put into order 0's source, is written again into a scratch field
//! (the same values) and taken off, and each light's irradiance is kept (true extinction; under
//! δ-M the scaled one after it). The sky's diffuse light, the environment map's diffuse part and
//! the emission stay in the solve (their first scattering is smooth in angle).
//!
//! **What the solve put in.** Order 0 sweeps each beam along its exact direction; every voxel of
//! an occupied brick pulls the segment-average irradiance Ē(v) of the rays through it into the
//! fluence (weight 1) and `ρ(v)·σs*·row[d]·Ē(v)` into the next source (the twin's `cpu_sweep`,
//! `collect.comp`), with σs* and the beam's phase row of the plan's medium and phase (δ-M scaled
//! where the plan scales, [`super::plan`]); the commit multiplies it by the voxel's albedo factor
//! a(v) before the total takes it ([`super::passes`]). [`split`] sweeps each beam once more on the
//! host with the twin's own sweep (the GPU's discretisation, in f64, the same for both backends)
//! and takes exactly that off the solve's source total, per voxel and storage direction:
//! `render source = source_total − Σ_beams a(v)·ρ(v)·σs*·row_b[d]·Ē*_b(v)`. What is left is every
//! order ≥ 2 (and the sky's, the environment's diffuse part's, the point lights' and the
//! emission's first scattering). The exported `source` is not touched: only the image's copy is.
//!
//! **What the renderer adds.** Per beam, the uncollided irradiance E_b(v) attenuated by the
//! scene's **true** extinction, traced to each voxel's centre along the beam's exact direction
//! through the density the renderer sees, for every voxel of an occupied brick
//! ([`super::beam_trace`]: the sweep's staircase is too coarse at the edge of a cloud's shadow,
//! which is its rim seen towards the sun, and the renderer interpolates the centres' optical
//! depth, where a voxel average interpolated linearly overstates the light between the centres;
//! past the trace's step limit, a second host sweep with the unscaled medium, as before), kept in
//! `render-data/` in bricks; along a camera ray the
//! renderer adds `σs(x)·p_HG(g; ω_b·ω_camera)·E_b(x)` with the true σs and the scene's g,
//! attenuated towards the camera by the true extinction ([`crate::render::march`]). Under δ-M the
//! field also keeps the scaled irradiance E*_b (the extinction the solve swept with, traced
//! alike): the light E*_b − E_b that the truncated forward peak deflected and kept in the beam,
//! whose first scattering was taken off with the rest, is scattered towards the camera by the
//! renderer too, with the peak's chains ([`crate::render::peak`]); without it a camera looking
//! towards the sun through a forward-scattering cloud misses much of its light.
//!
//! The split is left out (the image is made from the whole source total, as before) where the
//! beams are swept with more than order 0's boundary light: periodic axes carry a beam's light
//! into later orders and mirror faces hand it over, so order 0's sweep is not all of the beams'
//! first scattering there. It is also left out where the host sweep's dense arrays would exceed
//! [`HOST_LIMIT_BYTES`]. Each case is logged and said in the plan's reasons of `report.json`.

use super::cpu_sweep::{sweep_direction, SweepInputs, SweepMode, SweepOutputs};
use super::exitance::ExitMaps;
use super::plan::{Plan, SweepDirection};
use super::SolveError;
use crate::scene::Medium;
use crate::store::{BrickGrid, BrickStore, Coverage, Field, BRICK_EDGE, BRICK_VOXELS};
use glam::DVec3;
use std::time::Instant;

/// Most bytes the host sweeps' dense arrays (density, irradiance) may take: beyond, the split is
/// left out (the CPU twin's own limit is larger, but this runs beside a GPU solve's host fields).
pub const HOST_LIMIT_BYTES: u64 = 4 << 30;

/// The name of the image's source field in the store (and, linked, `render-data/source.field`).
pub const RENDER_SOURCE: &str = "render_source";

/// The store field of beam `b`'s uncollided irradiance.
pub fn irradiance_field_name(b: usize) -> String {
    format!("direct_{b}")
}

/// Removes what [`split`] writes into the store (the image's source, each light's irradiance, the
/// point lights' scratch fields) where a killed job left it: a resumed job makes it again after
/// its solve, and until then it is no part of the store (`report.json`'s `store_bytes` counts the
/// store's fields). A file that cannot be removed is only left behind (and logged).
pub fn remove_fields(store: &BrickStore) {
    let Ok(entries) = std::fs::read_dir(store.dir()) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(stem) = name.to_str().and_then(|n| n.strip_suffix(".field")) else { continue };
        if stem == RENDER_SOURCE || stem.starts_with("direct_") {
            if let Err(e) = std::fs::remove_file(entry.path()) {
                tracing::warn!("could not remove {} (a killed render's): {e}", entry.path().display());
            }
        }
    }
}

/// The direct light split off the image's source.
pub struct DirectSplit {
    /// The source total less the beams' first scattering (occupied bricks, the plan's components).
    pub render_source: Field,
    /// Per beam, the direction its light travels.
    pub travel: Vec<DVec3>,
    /// Per point light, its position (voxel units, the volume's corner at 0); its field follows
    /// the beams' in [`fields`](Self::fields).
    pub points: Vec<DVec3>,
    /// Per beam, its uncollided irradiance per voxel with the true extinction (occupied bricks,
    /// `plan.channels` components), followed, when [`peak_chains`](Self::peak_chains), by the
    /// δ-M scaled irradiance the solve swept (`plan.channels` more).
    pub fields: Vec<Field>,
    /// The scene's medium, unscaled: what the exact single scattering uses.
    pub medium: Medium,
    /// The plan applied δ-M: each field also holds the scaled irradiance, from which the renderer
    /// scatters the light the forward peak kept in the beam ([`crate::render::peak`]).
    pub peak_chains: bool,
    /// How the beams' irradiance for the image was made.
    pub irradiance: BeamIrradiance,
}

/// How [`split`] made the beams' irradiance the image scatters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BeamIrradiance {
    /// No sun: only point lights (traced by [`super::point`] in any case).
    NoBeams,
    /// Traced per voxel along each beam ([`super::beam_trace`]), in this many seconds in all.
    Traced { seconds: f64 },
    /// Order 0's sweep's: tracing would have taken about this many DDA steps, more than
    /// [`super::beam_trace::TRACE_LIMIT_STEPS`].
    Swept { steps: u64 },
}

/// Why the split was left out, for the plan's reasons; `None` when it can be made.
pub fn left_out_because(plan: &Plan) -> Option<String> {
    if plan.beams.is_empty() && plan.point_lights.is_empty() {
        return Some("no sun or point light".into());
    }
    if plan.periodic.iter().any(|&p| p) || plan.reflective.iter().flatten().any(|&r| r) {
        return Some(
            "periodic or mirror faces carry the beams' light into later orders: the image's source keeps \
             the suns' first scattering (binned), as before"
                .into(),
        );
    }
    let voxels: u64 = plan.dims.iter().map(|&d| u64::from(d)).product();
    // Density, one sweep's irradiance and the image's (true and scaled), f64 per voxel.
    let bytes = voxels.saturating_mul(1 + 3 * u64::from(plan.channels)).saturating_mul(8);
    if bytes > HOST_LIMIT_BYTES {
        return Some(format!(
            "the host sweep of the beams would need {} MiB (more than {} MiB): the image's source keeps the \
             suns' first scattering (binned), as before",
            bytes >> 20,
            HOST_LIMIT_BYTES >> 20
        ));
    }
    None
}

/// Splits the beams' first scattering off `source_total` (see the [module docs](self)); `None`
/// where [`left_out_because`] says why not. `medium` is the scene's (unscaled) medium.
pub fn split(
    plan: &Plan,
    medium: &Medium,
    store: &BrickStore,
    source_total: &Field,
) -> Result<Option<DirectSplit>, SolveError> {
    if left_out_because(plan).is_some() {
        return Ok(None);
    }
    let c = plan.channels as usize;
    let comps = plan.source_components() as usize;
    let grid = *store.grid();
    let [nx, ny, nz] = plan.dims;
    let voxels = nx as usize * ny as usize * nz as usize;
    let index = |v: [u32; 3]| v[0] as usize + nx as usize * (v[1] as usize + ny as usize * v[2] as usize);
    // As the twin reads the store.
    let (density, occupied) = super::cpu::dense_density(plan.dims, |v| store.density_at(v));
    store.release_all_density();
    let albedo = if plan.albedo_field { Some(crate::store::albedo::open_albedo(store)?) } else { None };
    // The plan with the scene's own extinction: the uncollided irradiance the exact single
    // scattering needs (the plan's is the δ-M scaled one where the plan scales).
    let scaled = plan.delta_m().is_some() && plan.medium != *medium;
    let true_plan = scaled.then(|| Plan { medium: medium.clone(), ..plan.clone() });
    let mut render_source = store.create_field(RENDER_SOURCE, comps as u32, Coverage::Occupied)?;
    render_source.copy_from(source_total)?;
    let mut fields = Vec::with_capacity(plan.beams.len());
    // Whether the beams' irradiance for the image is traced exactly (`super::beam_trace`).
    // Every voxel of an occupied brick is traced (the field keeps those bricks; the renderer
    // interpolates between the centres, empty ones included).
    let (mut stored, mut traced_bricks) = (vec![false; grid.brick_count()], Vec::new());
    for b in store.occupied_bricks() {
        stored[b] = true;
        let coords = grid.brick_coords(b);
        traced_bricks.push((grid.brick_origin(coords), grid.brick_extent(coords)));
    }
    let in_stored = |v: [u32; 3]| stored[grid.locate(v).0];
    let live = super::beam_trace::LiveCells::new(plan.dims, &density);
    let steps = plan
        .beams
        .iter()
        .map(|beam| super::beam_trace::estimated_steps(&live, &traced_bricks, beam.omega))
        .fold(0u64, u64::saturating_add);
    // The swept path's test hook (tests/it/single_scatter.rs): only in `test-hooks` builds.
    #[cfg(feature = "test-hooks")]
    let limit = std::env::var("LPM_TEST_TRACE_LIMIT_STEPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(super::beam_trace::TRACE_LIMIT_STEPS);
    #[cfg(not(feature = "test-hooks"))]
    let limit = super::beam_trace::TRACE_LIMIT_STEPS;
    let traced = steps <= limit;
    let mut trace_seconds = 0.0;
    let mut irradiance = vec![0.0f64; voxels * c];
    // σs per channel at density 1, as the collect step multiplies it.
    let coefficients: Vec<f64> = (0..c).map(|ch| plan.coefficients(ch).1).collect();
    for (b, beam) in plan.beams.iter().enumerate() {
        // What order 0's sweep of this beam deposited: Ē*(v) per channel.
        sweep_beam(plan, beam, &density, &occupied, &mut irradiance);
        for brick in store.occupied_bricks().collect::<Vec<_>>() {
            let a = albedo.as_ref().and_then(|f| f.brick(brick));
            let origin = grid.brick_origin(grid.brick_coords(brick));
            let Some(out) = render_source.brick_mut(brick) else { continue };
            for_each_local(&grid, brick, |local, l| {
                let v = [origin[0] + l[0], origin[1] + l[1], origin[2] + l[2]];
                let i = index(v);
                let rho = density[i];
                for ch in 0..c {
                    // The collect step's own product, σs·row·Ē, then the commit's albedo factor.
                    let sigma_s = rho * coefficients[ch];
                    if sigma_s <= 0.0 {
                        continue;
                    }
                    let e = irradiance[i * c + ch];
                    for (d, m) in beam.collect_row.iter().enumerate() {
                        let mut first = sigma_s * m * e;
                        if let Some(a) = a {
                            first *= a[local] as f64;
                        }
                        let k = (d * c + ch) * BRICK_VOXELS + local;
                        out[k] = (out[k] as f64 - first) as f32;
                    }
                }
            });
        }
        // The image's irradiance per voxel, `[voxel][component]`: the true extinction's per
        // channel, which the renderer scatters exactly, then under δ-M the scaled extinction's
        // (the peak's chains, `crate::render::peak`). Traced along the beam
        // (`super::beam_trace`), or the sweep's where that would take too long.
        let passes: Vec<&Plan> = true_plan.iter().chain([plan]).collect();
        let components = passes.len() * c;
        let mut image_irradiance = vec![0.0f64; voxels * components];
        if traced {
            let t = Instant::now();
            let sigma: Vec<f64> =
                passes.iter().flat_map(|p| (0..c).map(|ch| p.coefficients(ch).0 * p.voxel_size)).collect();
            let boundary: Vec<f64> = passes.iter().flat_map(|_| beam.boundary[..c].iter().copied()).collect();
            super::beam_trace::trace_beam(
                &density,
                &live,
                &in_stored,
                beam.omega,
                &boundary,
                &sigma,
                &mut image_irradiance,
            );
            trace_seconds += t.elapsed().as_secs_f64();
        } else {
            // The plan's own last: `irradiance` holds its sweep already (taken off above).
            for (pass, p) in passes.iter().enumerate().rev() {
                if !std::ptr::eq(*p, plan) {
                    sweep_beam(p, beam, &density, &occupied, &mut irradiance);
                }
                for (i, e) in irradiance.chunks(c).enumerate() {
                    image_irradiance[i * components + pass * c..][..c].copy_from_slice(e);
                }
            }
        }
        let mut field = store.create_field(&irradiance_field_name(b), components as u32, Coverage::Occupied)?;
        for brick in store.occupied_bricks().collect::<Vec<_>>() {
            let origin = grid.brick_origin(grid.brick_coords(brick));
            let Some(out) = field.brick_mut(brick) else { continue };
            for_each_local(&grid, brick, |local, l| {
                let i = index([origin[0] + l[0], origin[1] + l[1], origin[2] + l[2]]);
                for k in 0..components {
                    out[k * BRICK_VOXELS + local] = image_irradiance[i * components + k] as f32;
                }
            });
        }
        field.flush()?;
        fields.push(field);
    }
    if !plan.point_lights.is_empty() {
        split_point_lights(plan, true_plan.as_ref(), store, albedo.as_ref(), &mut render_source, &mut fields)?;
    }
    render_source.flush()?;
    let travel = plan.beams.iter().map(|b| b.omega).collect();
    let points = plan.point_lights.iter().map(|l| l.position).collect();
    Ok(Some(DirectSplit {
        render_source,
        travel,
        points,
        fields,
        medium: medium.clone(),
        peak_chains: true_plan.is_some(),
        irradiance: if plan.beams.is_empty() {
            BeamIrradiance::NoBeams
        } else if traced {
            BeamIrradiance::Traced { seconds: trace_seconds }
        } else {
            BeamIrradiance::Swept { steps }
        },
    }))
}

/// The point lights' share of [`split`]: their first scattering, exactly what
/// [`super::point::write_order0`] put into order 0's new source (written again into a scratch
/// field: the same f32 values), times the albedo factor as the commit applied it, taken off
/// `render_source`; then per light its irradiance with the true extinction (and, under δ-M, the
/// scaled one after it), appended to `fields`. The irradiance passes scatter isotropically: the
/// phase rows do not change the fluence, and an isotropic row needs no table.
fn split_point_lights(
    plan: &Plan,
    true_plan: Option<&Plan>,
    store: &BrickStore,
    albedo: Option<&Field>,
    render_source: &mut Field,
    fields: &mut Vec<Field>,
) -> Result<(), SolveError> {
    let c = plan.channels as usize;
    let comps = plan.source_components();
    let scratch = |name: &str, components: u32| store.create_field(name, components, Coverage::Occupied);
    {
        // (Scoped: each scratch field is unmapped before the next pass creates it afresh.)
        let mut fluence = scratch("direct_scratch_fluence", c as u32)?;
        let mut source = scratch("direct_scratch_source", comps)?;
        super::point::write_order0(store, plan, &mut fluence, &mut source)?;
        for brick in store.occupied_bricks().collect::<Vec<_>>() {
            let (Some(first), Some(out)) = (source.brick(brick), render_source.brick_mut(brick)) else { continue };
            let a = albedo.and_then(|f| f.brick(brick));
            for (k, (o, &j)) in out.iter_mut().zip(first).enumerate() {
                let factor = a.map_or(1.0, |a| a[k % BRICK_VOXELS] as f64);
                *o = (*o as f64 - j as f64 * factor) as f32;
            }
        }
    }
    let isotropic = crate::quadrature::phase::Phase::HenyeyGreenstein { g: 0.0 };
    for (l, light) in plan.point_lights.iter().enumerate() {
        let alone = |p: &Plan| Plan { point_lights: vec![*light], phase: isotropic, ..p.clone() };
        let mut passes = vec![alone(true_plan.unwrap_or(plan))];
        if true_plan.is_some() {
            passes.push(alone(plan));
        }
        let mut field = store.create_field(
            &irradiance_field_name(plan.beams.len() + l),
            (passes.len() * c) as u32,
            Coverage::Occupied,
        )?;
        for (pass, p) in passes.iter().enumerate() {
            // (`e` and `j` are unmapped at the end of each pass.)
            let mut e = scratch("direct_scratch_fluence", c as u32)?;
            let mut j = scratch("direct_scratch_source", p.source_components())?;
            super::point::write_order0(store, p, &mut e, &mut j)?;
            for brick in store.occupied_bricks().collect::<Vec<_>>() {
                let (Some(from), Some(out)) = (e.brick(brick), field.brick_mut(brick)) else { continue };
                out[pass * c * BRICK_VOXELS..(pass + 1) * c * BRICK_VOXELS].copy_from_slice(from);
            }
        }
        field.flush()?;
        fields.push(field);
    }
    for name in ["direct_scratch_fluence", "direct_scratch_source"] {
        let _ = std::fs::remove_file(store.dir().join(format!("{name}.field")));
    }
    Ok(())
}

/// Calls `visit(local index, local coordinates)` for each voxel of `brick` inside the volume.
fn for_each_local(grid: &BrickGrid, brick: usize, mut visit: impl FnMut(usize, [u32; 3])) {
    let extent = grid.brick_extent(grid.brick_coords(brick));
    for z in 0..extent[2] {
        for y in 0..extent[1] {
            for x in 0..extent[0] {
                let local = (x + BRICK_EDGE * (y + BRICK_EDGE * z)) as usize;
                visit(local, [x, y, z]);
            }
        }
    }
}

/// Order 0's sweep of `beam` alone, with `plan`'s medium: its fluence deposit (the segment-average
/// irradiance Ē per voxel of an occupied brick, `[voxel][ch]`) into `irradiance`, which is zeroed
/// first. Nothing is gained and no source is collected (an empty collect row).
fn sweep_beam(plan: &Plan, beam: &SweepDirection, density: &[f64], occupied: &[bool], irradiance: &mut [f64]) {
    irradiance.iter_mut().for_each(|e| *e = 0.0);
    let alone = SweepDirection { collect_row: Vec::new(), ..beam.clone() };
    let inputs = SweepInputs { density, gained: &[], occupied };
    let mut exits = ExitMaps::new(plan.dims, plan.channels as usize);
    let mut outputs = SweepOutputs { fluence_order: irradiance, j_next: &mut [], exits: &mut exits };
    let mode = SweepMode { boundary: true, gain: false, emit: false };
    sweep_direction(plan, &alone, mode, None, None, &inputs, &mut outputs);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use std::path::Path;

    fn scene(extra: &str) -> Scene {
        let text = format!(
            "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.9\n\
             g = 0.85\n[[lights]]\nkind = \"sun\"\ndirection = [0.2, 0.3, 1.0]\nirradiance = 1.0\n{extra}"
        );
        Scene::from_toml_str(&text, Path::new("t.toml")).expect("scene")
    }

    #[test]
    fn the_split_is_left_out_without_suns_and_across_periodic_faces() {
        let plan = Plan::new(&scene(""), 1, 0);
        assert_eq!(left_out_because(&plan), None);
        let mut periodic = plan.clone();
        periodic.periodic = [true, false, false];
        assert!(left_out_because(&periodic).is_some_and(|w| w.contains("periodic")));
        let mut none = plan.clone();
        none.beams.clear();
        assert!(left_out_because(&none).is_some());
    }
}
