//! Mirror faces on the GPU backend, and on the CPU for a traced emission's scattered light: the
//! method of images, carried out.
//!
//! A volume with mirror faces solves to the restriction of the volume doubled by its mirror image
//! across each mirror ([`super::mirror`]). The CPU twin hands light over at the mirrors without
//! storing the image; the GPU kernels have no hand-over, and neither have the scattered light's
//! own directions ([`super::plan`]: the CPU twin unfolds for them too), so the backend builds the
//! doubled volume itself: per axis with a mirror the volume and its image side by side (an axis with
//! mirrors on both faces repeats with period 2n: it is solved periodic), the density and any
//! emission or albedo grid copied across, the faces that are not mirrors open as they were. It
//! solves that with the ordinary kernels and copies the original's part of the fluence and the
//! source back into the scene's fields. The cost is the doubled volume's: 2, 4 or 8 times the
//! memory and time of the volume with its mirrors.
//!
//! **What it gives.** The doubled volume's answer, which the twin converges to as well (its mirror
//! hand-overs arrive an order late, so it runs more orders). The directions are the same unless the
//! twin nudges one swept across a mirror to move whole voxels over the volume
//! ([`super::periodic::periodic_slope`]): the doubled volume has open faces there and sweeps the
//! direction unnudged, a difference of the nudge's size. **Energy books.** The doubled volume's
//! powers over its 2^m copies of the volume; each of its faces counts for the open face of the
//! volume it images (so the faces add up to the totals, and an open face's books are the mean over
//! its images). The absorbed power is the twin's. The faces' in and out are the twin's where no
//! mirror borders the face; next to a mirror the twin also counts the rays its lattice keeps in the
//! vacuum column beyond the mirror (born beside the face, leaving again without meeting the
//! medium), n + 1 lattice columns across the mirrored axis against the doubled volume's 2n + 1 (or
//! 2n when periodic) over two: up to ~12 % of such a face's in and out, the lattice's bookkeeping,
//! not light. No light crosses a mirror face in these books (it crosses an interior plane of the
//! doubled volume, where nothing is tallied), where the twin counts what reaches a mirror as out
//! and what comes back as in (net zero once converged).
//!
//! **A traced emission** is traced once, in the volume with its mirror images as emitters
//! ([`super::uncollided`]): each copy of the volume in the doubled one holds the same uncollided
//! light, so the doubled volume's order 0 is the volume's imaged (2^m times cheaper than tracing
//! the doubled volume, and the same values on both backends), its books 2^m times the volume's.
//!
//! No checkpoints are written (they would be the doubled volume's), so `--resume` finds none and
//! starts afresh, and a warm start's guess is not used (the solve is cold; a warning says so).
//! The doubled store lives beside the scene's, in `unfolded/`, and is removed when the solve ends.

use super::energy::{EnergyBalance, Tallies};
use super::orders::OrderOutcome;
use super::plan::Plan;
use super::{emission, BackendRun, SolveError, StoreFields};
use crate::scene::{Acceleration, Scene};
use crate::store::{albedo, brick_voxel, BrickGrid, BrickStore, Coverage, Field, StoreError, BRICK_EDGE};
use std::path::PathBuf;

/// Where the volume and its images lie in the doubled volume.
#[derive(Clone, Copy, Debug)]
pub struct Fold {
    /// The volume's dims.
    half: [u32; 3],
    /// Per axis: whether its low and high faces are mirrors.
    mirrors: [[bool; 2]; 3],
}

impl Fold {
    /// The doubling for a volume of `dims` with the mirrors `reflective` (per axis: low, high).
    pub fn new(dims: [u32; 3], reflective: [[bool; 2]; 3]) -> Fold {
        Fold { half: dims, mirrors: reflective }
    }

    /// Whether axis `a` is doubled (a mirror on either face).
    fn doubled(&self, a: usize) -> bool {
        self.mirrors[a].contains(&true)
    }

    /// Whether the image lies below the volume along axis `a` (a mirror on the low face only).
    fn image_below(&self, a: usize) -> bool {
        self.mirrors[a] == [true, false]
    }

    /// The doubled volume's dims.
    pub fn dims(&self) -> [u32; 3] {
        [0, 1, 2].map(|a| self.half[a] * if self.doubled(a) { 2 } else { 1 })
    }

    /// Per axis: periodic in the doubled volume (mirrors on both faces).
    pub fn periodic(&self) -> [bool; 3] {
        self.mirrors.map(|m| m == [true, true])
    }

    /// Copies of the volume in the doubled one (2^m, m the mirrored axes).
    pub fn copies(&self) -> f64 {
        (0..3).filter(|&a| self.doubled(a)).map(|_| 2.0).product()
    }

    /// The voxel of the volume that voxel `u` of the doubled volume is (or images).
    pub fn source(&self, u: [u32; 3]) -> [u32; 3] {
        [0, 1, 2].map(|a| {
            let n = self.half[a];
            match (self.doubled(a), self.image_below(a)) {
                (false, _) => u[a],
                (true, true) if u[a] < n => n - 1 - u[a],
                (true, true) => u[a] - n,
                (true, false) if u[a] < n => u[a],
                (true, false) => 2 * n - 1 - u[a],
            }
        })
    }

    /// Where voxel `v` of the volume lies in the doubled one.
    pub fn place(&self, v: [u32; 3]) -> [u32; 3] {
        [0, 1, 2].map(|a| if self.image_below(a) { v[a] + self.half[a] } else { v[a] })
    }
}

/// The scene of the doubled volume: `scene` with the doubled dims, periodic where both faces of an
/// axis are mirrors, no mirrors, and the plan's choices kept (the acceleration stays off: the
/// twin's mirrors refuse it; the spatial scheme and the sky's directions are pinned to `plan`'s,
/// which the doubled volume's open faces would otherwise let the plan choose afresh).
fn doubled_scene(scene: &Scene, plan: &Plan, fold: &Fold) -> Scene {
    let mut s = scene.clone();
    s.solver.spatial = Some(plan.spatial);
    s.solver.sky_directions_per_face = Some(plan.sky_directions_per_face());
    s.volume.dims = fold.dims();
    s.boundary.periodic = [0, 1, 2].map(|a| scene.boundary.periodic[a] || fold.periodic()[a]);
    s.boundary.reflective = [[false; 2]; 3];
    s.solver.acceleration = Acceleration::Off;
    s
}

/// The doubled volume's store in `dir`: the density, and the emission and albedo grids the plan
/// uses, each voxel the value of the voxel it images.
fn doubled_store(
    store: &BrickStore,
    plan: &Plan,
    fold: &Fold,
    dir: &std::path::Path,
) -> Result<BrickStore, StoreError> {
    let grid = BrickGrid::new(fold.dims());
    let kept = folded_bricks(store, fold, &grid);
    let doubled = BrickStore::create_keeping(
        dir,
        grid.dims,
        store.voxel_size(),
        |b| kept[b],
        |b, out| {
            for (i, value) in out.iter_mut().enumerate() {
                let u = brick_voxel(grid.brick_origin(b), i);
                if grid.contains(u) {
                    *value = store.density_at(fold.source(u));
                }
            }
            Ok(())
        },
    )?;
    if plan.emission_grid {
        let from = crate::store::emission::open_emission(store)?;
        copy_field(&from, &doubled, crate::store::emission::EMISSION_FIELD, fold)?;
    }
    if plan.albedo_field {
        let from = albedo::open_albedo(store)?;
        copy_field(&from, &doubled, albedo::ALBEDO_FIELD, fold)?;
    }
    Ok(doubled)
}

/// Per brick of the doubled volume (`doubled`, its grid): whether [`fold_field`] reads it back,
/// i.e. whether it holds `place(v)` for a voxel v of one of `store`'s occupied bricks. With a
/// mirror on the low face only of an axis whose length is not a multiple of 16, the volume lies
/// shifted by n in the doubled one and its bricks straddle the doubled volume's: a doubled brick
/// whose voxels all image vacuum would be empty (never solved) while it holds vacuum voxels of an
/// occupied brick of the volume, which then read zero fluence on the GPU (issue 57).
fn folded_bricks(store: &BrickStore, fold: &Fold, doubled: &BrickGrid) -> Vec<bool> {
    let grid = *store.grid();
    let mut kept = vec![false; doubled.brick_count()];
    for brick in store.occupied_bricks() {
        let b = grid.brick_coords(brick);
        let (origin, extent) = (grid.brick_origin(b), grid.brick_extent(b));
        // `place` is a translation per axis: the brick's box maps to a box.
        let lo = fold.place(origin).map(|c| c / BRICK_EDGE);
        let hi = fold.place([0, 1, 2].map(|a| origin[a] + extent[a] - 1)).map(|c| c / BRICK_EDGE);
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    kept[doubled.brick_index([x, y, z])] = true;
                }
            }
        }
    }
    kept
}

/// Writes `name` into the doubled store: every voxel of its occupied bricks takes the value of the
/// voxel it images in `from`.
fn copy_field(from: &Field, doubled: &BrickStore, name: &str, fold: &Fold) -> Result<(), StoreError> {
    let mut to = doubled.create_field(name, from.components(), Coverage::Occupied)?;
    fill_field(&mut to, doubled, |u, c| from.value(fold.source(u), c));
    to.flush()
}

/// Sets every voxel of `store`'s occupied bricks in `field` (one of `store`'s) to `value(voxel,
/// component)`.
fn fill_field(field: &mut Field, store: &BrickStore, value: impl Fn([u32; 3], u32) -> f32) {
    let grid = *store.grid();
    let voxels = crate::store::BRICK_VOXELS;
    for brick in store.occupied_bricks().collect::<Vec<_>>() {
        let origin = grid.brick_origin(grid.brick_coords(brick));
        let Some(dst) = field.brick_mut(brick) else { continue };
        for (c, block) in dst.chunks_mut(voxels).enumerate() {
            for (i, slot) in block.iter_mut().enumerate() {
                let v = brick_voxel(origin, i);
                if grid.contains(v) {
                    *slot = value(v, c as u32);
                }
            }
        }
    }
}

/// Solves `scene` (with mirror faces; `plan` its plan) on `backend` as the volume doubled by its
/// images, and writes the volume's part of the doubled volume's committed fluence and source
/// into `fields`. A traced emission's order 0 is the volume's (`fields`' order-0 accumulators and
/// `traced`, its books, from the trace of the volume with its images), imaged. Returns the run, its
/// outcome folded back, and a reason for the plan's report.
#[allow(clippy::too_many_arguments)]
pub(super) fn solve_doubled(
    scene: &Scene,
    store: &BrickStore,
    plan: &Plan,
    fields: &mut StoreFields,
    traced: super::fields::LoopState,
    backend: super::BackendKind,
    vk_options: crate::vk::ContextOptions,
    gpu_options: super::gpu::GpuOptions,
    progress: &mut dyn crate::progress::Observer,
) -> Result<(BackendRun, String), SolveError> {
    let t = std::time::Instant::now();
    let fold = Fold::new(plan.dims, plan.reflective);
    let dir = Scratch(store.dir().join("unfolded"));
    if dir.0.exists() {
        std::fs::remove_dir_all(&dir.0).map_err(|e| StoreError::Io {
            path: dir.0.clone(),
            action: "remove the doubled volume's old store",
            source: e,
        })?;
    }
    let doubled = doubled_store(store, plan, &fold, &dir.0)?;
    let scene2 = doubled_scene(scene, plan, &fold);
    let total = doubled.grid().brick_count();
    let mut plan2 = Plan::new(&scene2, total, total - doubled.occupied_count());
    let mut fields2 = StoreFields::create(&doubled, &plan2)?;
    let mut start = super::fields::LoopState::default();
    if plan.emission_traced {
        // The volume's trace counted its images as emitters, so each copy of the volume in the
        // doubled one holds the same uncollided light: imaged, not traced again (2^m times the
        // cost), and every copy's books alike.
        plan2.trace_emission("emission's uncollided light traced in the volume with its images, imaged".into());
        fill_field(&mut fields2.fluence, &doubled, |u, c| fields.fluence.value(fold.source(u), c));
        fill_field(&mut fields2.source_next, &doubled, |u, c| fields.source_next.value(fold.source(u), c));
        // Written on the host whatever power it gives the medium (as in `solver::solve_from`).
        fields2.seeded = true;
        start.uncollided_emitted = traced.uncollided_emitted.map(|p| p * fold.copies());
        start.uncollided_escaped = traced.uncollided_escaped.map(|p| p * fold.copies());
    } else if plan2.emission_field {
        emission::write_initial_source(&doubled, &plan2, &mut fields2.source_prev)?;
    }
    let setup = t.elapsed().as_secs_f64();
    let run = match backend {
        super::BackendKind::Cpu => {
            let mut run = super::run_cpu(&plan2, &doubled, &mut fields2, start, gpu_options.cancel, progress)?;
            // The doubled volume's faces are not the scene's (a mirror is a plane inside it).
            run.exit_maps = None;
            run
        }
        super::BackendKind::Gpu => {
            // No maps: the doubled volume's faces are not the scene's.
            let options = super::gpu::GpuOptions { checkpoints: false, exit_maps: false, ..gpu_options };
            super::run_gpu(&plan2, &doubled, &mut fields2, start, vk_options, options, None, progress)?
        }
    };
    let t = std::time::Instant::now();
    fold_field(&fields2.fluence_total, &mut fields.fluence_total, store, &fold);
    fold_field(&fields2.source_total, &mut fields.source_total, store, &fold);
    let mut run = BackendRun { outcome: fold_outcome(run.outcome, plan.channels, &fold), ..run };
    run.phases.insert(0, ("doubling".to_string(), setup));
    run.phases.push(("folding".to_string(), t.elapsed().as_secs_f64()));
    let reason = format!(
        "mirror faces {}: solved as the volume doubled by its mirror images ({} × {} × {} voxels, {} copies \
         of the volume: that many times the memory and time), the volume's part kept",
        match backend {
            super::BackendKind::Gpu => "on the GPU (its kernels have no hand-over)",
            super::BackendKind::Cpu => "with the scattered light's own directions (they have no hand-over)",
        },
        fold.dims()[0],
        fold.dims()[1],
        fold.dims()[2],
        fold.copies()
    );
    // The doubled volume's own choices that the volume's plan could not make.
    let scattered = plan2.reasons.iter().filter(|r| r.starts_with("scattered light: orders"));
    let reason = std::iter::once(reason).chain(scattered.cloned()).collect::<Vec<_>>().join("; ");
    Ok((run, reason))
}

/// Removes the doubled volume's store when the solve ends, however it ends.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_dir_all(&self.0) {
            if e.kind() != std::io::ErrorKind::NotFound {
                tracing::warn!("could not remove the doubled volume's store {}: {e}", self.0.display());
            }
        }
    }
}

/// Copies the volume's part of the doubled volume's field `from` into `to` (the scene's store's
/// field of the same components), voxel by voxel over the volume's occupied bricks.
fn fold_field(from: &Field, to: &mut Field, store: &BrickStore, fold: &Fold) {
    fill_field(to, store, |v, c| from.value(fold.place(v), c));
}

/// The doubled volume's outcome as the volume's: every power over the copies of the volume, and
/// each face of the doubled volume counted for the open face of the volume it images (an axis with
/// one mirror has both its doubled faces image the volume's open face; one with two has none), so
/// the faces' books add up to the totals (module docs).
fn fold_outcome(mut outcome: OrderOutcome, channels: u32, fold: &Fold) -> OrderOutcome {
    let copies = fold.copies();
    let e = &outcome.energy;
    let mut tallies = Tallies::default();
    for (f, face) in e.faces.iter().enumerate() {
        let axis = f / 2;
        let target = match fold.mirrors[axis] {
            [false, false] => f,
            [true, true] => continue,
            // The one open face of the axis.
            [low, _] => 2 * axis + low as usize,
        };
        for ch in 0..3 {
            let (came, left) = (face.power_in[ch] / copies, face.power_out[ch] / copies);
            tallies.face_in[target][ch] += came;
            tallies.face_out[target][ch] += left;
            tallies.boundary_in[ch] += came;
            tallies.boundary_out[ch] += left;
        }
    }
    let per_copy = |v: [f64; 3]| v.map(|x| x / copies);
    outcome.energy = EnergyBalance::new(
        &tallies,
        per_copy(e.emitted),
        per_copy(e.point_lights),
        per_copy(e.uncollided_escaped),
        per_copy(e.absorbed),
        per_copy(e.unpropagated),
        channels as usize,
    );
    for record in &mut outcome.history {
        record.new_source_power /= copies;
        record.total_source_power /= copies;
    }
    if let Some(tail) = &mut outcome.tail {
        tail.power /= copies;
    }
    outcome
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_voxel_of_the_doubled_volume_images_the_volume_and_the_volume_lies_in_it_once() {
        let dims = [5, 4, 3];
        for reflective in [[[true, false], [false; 2], [false, true]], [[true, true], [true, false], [false; 2]]] {
            let fold = Fold::new(dims, reflective);
            let d = fold.dims();
            let mut hits = vec![0; (dims[0] * dims[1] * dims[2]) as usize];
            for z in 0..d[2] {
                for y in 0..d[1] {
                    for x in 0..d[0] {
                        let v = fold.source([x, y, z]);
                        assert!((0..3).all(|a| v[a] < dims[a]), "{v:?}");
                        hits[(v[0] + dims[0] * (v[1] + dims[1] * v[2])) as usize] += 1;
                    }
                }
            }
            // Each voxel of the volume appears once per copy.
            assert!(hits.iter().all(|&h| h as f64 == fold.copies()), "{hits:?}");
            for v in [[0, 0, 0], [4, 3, 2], [2, 1, 0]] {
                assert_eq!(fold.source(fold.place(v)), v);
            }
        }
        // A mirror on the low face of x: the image lies below, voxel 0 next to its own image.
        let fold = Fold::new(dims, [[true, false], [false; 2], [false; 2]]);
        assert_eq!(fold.place([0, 0, 0]), [5, 0, 0]);
        assert_eq!(fold.source([4, 0, 0]), [0, 0, 0]);
    }
}
