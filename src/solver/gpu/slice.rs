//! One slice (or sub-slice) of bricks on its way through a slot: which bricks, where each lands in
//! the staging buffers, and the copy regions between the store and the staging.
//!
//! Only occupied bricks travel: empty bricks hold no medium, no source and no fluence. Of each
//! occupied brick the slot holds the slab of local planes the (sub-)slice covers: `planes × 256`
//! voxels per component, in the brick's own x-fastest order with the sweep axis cut to the slab (a
//! whole slice's slab of a y or z sweep is the whole brick, copied as is). The x sweeps' slabs are
//! lateral-major instead (y fastest, then z, then x: `FLAG_LATERAL_MAJOR`, so that neighbouring
//! rays read neighbouring words; see [`super::transpose`]): the copy workers transpose them plane
//! by plane on the way up and back on the way home. See `slab_index` in `glsl/common.glsl`.
//!
//! Upload staging: `[slot table, padded to 16 B][density][previous source, only when rays gain it]
//! [new source][fluence]`, each block over the occupied bricks in slice order; the device slot
//! buffers hold the same blocks, each at offset 0 of its own buffer. The resident mode's load
//! ([`SliceLayout::resident_load`]) leaves out the accumulators, and the density after the first
//! load; its copies put each brick at its store slot in the resident buffers ([`Self::resident_slots`]). Download staging:
//! `[new source][fluence]`. The previous source is f32 like the rest, or f16 when the plan says so
//! (the same slab layout at 2 bytes a value, rounded by the copy workers during the gather; a slab
//! holds a multiple of 256 voxels, so its f16 values pair up into whole 32-bit words).

use super::copier::{Convert, Region};
use super::sizes::{slab_bytes, slot_table_bytes, BRICK_BYTES};
use crate::solver::fields::StoreFields;
use crate::solver::sweep::{FaceSweep, SliceRange};
use crate::store::{BrickStore, BRICK_EDGE};

#[derive(PartialEq)]
pub struct SliceLayout {
    pub range: SliceRange,
    /// Every brick of the slice, b fastest (the order of the slot table and of the fluence).
    pub bricks: Vec<usize>,
    /// Occupied bricks in slice order (the order of density and sources).
    pub occupied: Vec<usize>,
    /// Per brick of the slice: its index among `occupied`, or −1 when empty.
    pub slots: Vec<i32>,
    pub bricks_b: u32,
    pub bricks_c: u32,
    pub gain: bool,
    pub channels: u64,
    pub comps: u64,
    /// The sweep axis (0, 1, 2 for x, y, z).
    pub axis: usize,
    /// The slabs are lateral-major (an x sweep's; `FLAG_LATERAL_MAJOR`), else in brick order.
    pub lateral_major: bool,
    /// `Some(scale)`: the previous source travels as f16, times `scale` (a power of two).
    pub prev_half_scale: Option<f32>,
    /// Whether the upload carries the density, and the order's accumulators (new source, fluence).
    pub density_up: bool,
    pub accumulators_up: bool,
}

impl SliceLayout {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        store: &BrickStore,
        sweep: &FaceSweep,
        range: SliceRange,
        gain: bool,
        channels: u64,
        comps: u64,
        prev_half_scale: Option<f32>,
    ) -> Self {
        let grid = *store.grid();
        let face = sweep.geometry();
        let bricks_b = grid.bricks[face.lateral[0]];
        let bricks_c = grid.bricks[face.lateral[1]];
        let mut bricks = Vec::with_capacity((bricks_b * bricks_c) as usize);
        for bc in 0..bricks_c {
            for bb in 0..bricks_b {
                let mut b = [0; 3];
                b[face.axis] = range.brick_a;
                b[face.lateral[0]] = bb;
                b[face.lateral[1]] = bc;
                bricks.push(grid.brick_index(b));
            }
        }
        let mut slots = Vec::with_capacity(bricks.len());
        let mut occupied = Vec::new();
        for &b in &bricks {
            if store.slot(b).is_some() {
                slots.push(occupied.len() as i32);
                occupied.push(b);
            } else {
                slots.push(-1);
            }
        }
        SliceLayout {
            range,
            bricks,
            occupied,
            slots,
            bricks_b,
            bricks_c,
            gain,
            channels,
            comps,
            axis: face.axis,
            lateral_major: face.axis == 0,
            prev_half_scale,
            density_up: true,
            accumulators_up: true,
        }
    }

    /// The upload of the resident mode's load: the previous source; the density only when
    /// `with_density` (it stays on the device from the first load on); the accumulators only when
    /// `accumulators` (the host seeded them). Whole slices only.
    /// Bricks travel in brick order, as the resident buffers hold them between the x sweeps.
    pub fn resident_load(mut self, with_density: bool, accumulators: bool) -> Self {
        debug_assert_eq!(self.range.slab_planes, BRICK_EDGE, "the resident mode moves whole bricks");
        self.density_up = with_density;
        self.accumulators_up = accumulators;
        self.lateral_major = false;
        self
    }

    /// The resident mode's unload: bricks come home in brick order.
    pub fn resident_unload(mut self) -> Self {
        debug_assert_eq!(self.range.slab_planes, BRICK_EDGE, "the resident mode moves whole bricks");
        self.lateral_major = false;
        self
    }

    /// Per brick of the slice: its store slot (its place in the resident buffers), or −1 when
    /// empty. The resident mode's slot table.
    pub fn resident_slots(&self, store: &BrickStore) -> Vec<i32> {
        self.bricks.iter().map(|&b| store.slot(b).map_or(-1, |k| k as i32)).collect()
    }

    /// Whether the two slices share an occupied brick (the copies of one may not run while the
    /// other's do).
    pub fn shares_bricks(&self, other: &SliceLayout) -> bool {
        let (small, large) = if self.occupied.len() <= other.occupied.len() { (self, other) } else { (other, self) };
        let bricks: std::collections::HashSet<usize> = small.occupied.iter().copied().collect();
        large.occupied.iter().any(|b| bricks.contains(b))
    }

    /// No occupied brick: the rays cross vacuum, nothing travels and nothing is collected.
    pub fn is_vacuum(&self) -> bool {
        self.occupied.is_empty()
    }

    fn slab(&self) -> u64 {
        slab_bytes(self.range.slab_planes)
    }

    pub fn dense(&self) -> u64 {
        self.bricks.len() as u64
    }

    pub fn occ(&self) -> u64 {
        self.occupied.len() as u64
    }

    pub fn slot_table_bytes(&self) -> u64 {
        self.dense() * 4
    }

    pub fn density_offset(&self) -> u64 {
        slot_table_bytes(self.dense())
    }

    pub fn density_bytes(&self) -> u64 {
        self.occ() * self.slab()
    }

    pub fn source_bytes(&self) -> u64 {
        self.occ() * self.comps * self.slab()
    }

    /// Bytes of the previous source (f16: half of [`Self::source_bytes`]).
    pub fn prev_bytes(&self) -> u64 {
        if self.prev_half_scale.is_some() {
            self.source_bytes() / 2
        } else {
            self.source_bytes()
        }
    }

    pub fn fluence_bytes(&self) -> u64 {
        self.occ() * self.channels * self.slab()
    }

    pub fn prev_offset(&self) -> u64 {
        self.density_offset() + if self.density_up { self.density_bytes() } else { 0 }
    }

    pub fn next_offset(&self) -> u64 {
        self.prev_offset() + if self.gain { self.prev_bytes() } else { 0 }
    }

    pub fn fluence_offset(&self) -> u64 {
        self.next_offset() + if self.accumulators_up { self.source_bytes() } else { 0 }
    }

    pub fn upload_bytes(&self) -> u64 {
        self.fluence_offset() + if self.accumulators_up { self.fluence_bytes() } else { 0 }
    }

    /// Regions that fill the upload staging (at `staging`) from the store, all but the slot table
    /// (the caller writes that small table itself).
    pub fn gather(&self, store: &BrickStore, fields: &mut StoreFields, staging: *mut u8) -> Vec<Region> {
        let mut regions = Vec::new();
        let (c, comps, slab) = (self.channels as usize, self.comps as usize, self.slab() as usize);
        let next_base = fields.source_next.as_mut_slice().as_mut_ptr() as *mut u8;
        let prev_base = fields.source_prev.as_mut_slice().as_mut_ptr() as *mut u8;
        let fluence_base = fields.fluence.as_mut_slice().as_mut_ptr() as *mut u8;
        let at = |offset: u64| -> *mut u8 { staging.wrapping_add(offset as usize) };
        let (prev, next, fluence) = (self.prev_offset(), self.next_offset(), self.fluence_offset());
        for (i, &b) in self.occupied.iter().enumerate() {
            if let Some(density) = store.density_brick(b).filter(|_| self.density_up) {
                let dst = at(self.density_offset() + (i * slab) as u64);
                self.slab_regions(density.as_ptr() as *mut u8, dst, 1, true, None, &mut regions);
            }
            if let Some(k) = fields.source_next.stored_index(b) {
                let block = comps * BRICK_BYTES as usize;
                if self.gain {
                    let prev_slab = if self.prev_half_scale.is_some() { slab / 2 } else { slab };
                    let dst = at(prev + (i * comps * prev_slab) as u64);
                    self.slab_regions(
                        prev_base.wrapping_add(k * block),
                        dst,
                        comps,
                        true,
                        self.prev_half_scale,
                        &mut regions,
                    );
                }
                if self.accumulators_up {
                    let dst = at(next + (i * comps * slab) as u64);
                    self.slab_regions(next_base.wrapping_add(k * block), dst, comps, true, None, &mut regions);
                }
            }
            if let Some(k) = fields.fluence.stored_index(b).filter(|_| self.accumulators_up) {
                let dst = at(fluence + (i * c * slab) as u64);
                self.slab_regions(
                    fluence_base.wrapping_add(k * c * BRICK_BYTES as usize),
                    dst,
                    c,
                    true,
                    None,
                    &mut regions,
                );
            }
        }
        regions
    }

    /// Regions that return the download staging (at `staging`) to the store.
    pub fn scatter(&self, fields: &mut StoreFields, staging: *const u8) -> Vec<Region> {
        let mut regions = Vec::new();
        let (c, comps, slab) = (self.channels as usize, self.comps as usize, self.slab() as usize);
        let next_base = fields.source_next.as_mut_slice().as_mut_ptr() as *mut u8;
        let fluence_base = fields.fluence.as_mut_slice().as_mut_ptr() as *mut u8;
        let staging = staging as *mut u8;
        let fluence = self.source_bytes() as usize;
        for (i, &b) in self.occupied.iter().enumerate() {
            if let Some(k) = fields.source_next.stored_index(b) {
                let block = comps * BRICK_BYTES as usize;
                let src = staging.wrapping_add(i * comps * slab);
                self.slab_regions(next_base.wrapping_add(k * block), src, comps, false, None, &mut regions);
            }
            if let Some(k) = fields.fluence.stored_index(b) {
                let src = staging.wrapping_add(fluence + i * c * slab);
                self.slab_regions(
                    fluence_base.wrapping_add(k * c * BRICK_BYTES as usize),
                    src,
                    c,
                    false,
                    None,
                    &mut regions,
                );
            }
        }
        regions
    }

    /// The copies between `components` brick blocks at `brick` (4096 f32 voxels each, x fastest)
    /// and their slabs at `slab` (this range's planes, component after component, lateral-major
    /// when [`Self::lateral_major`]): brick → slab
    /// when `to_slab`, else back. `half = Some(scale)` (brick → slab only): the slab holds the
    /// values times `scale`, rounded to f16 (2 bytes a voxel, same layout).
    #[allow(clippy::too_many_arguments)]
    fn slab_regions(
        &self,
        brick: *mut u8,
        slab: *mut u8,
        components: usize,
        to_slab: bool,
        half: Option<f32>,
        out: &mut Vec<Region>,
    ) {
        debug_assert!(to_slab || half.is_none(), "only the gather converts");
        let (lo, n) = (self.range.slab_lo as usize, self.range.slab_planes as usize);
        let edge = BRICK_EDGE as usize;
        let (convert, sb) = match half {
            Some(scale) => (Convert::F32ToF16 { scale }, 2),
            None => (Convert::Copy, 4),
        };
        // `len`: bytes a run reads on the brick side (4 a voxel); the slab side has `sb` a voxel.
        let pair = |b: *mut u8, s: *mut u8, len, runs, b_stride, s_stride| {
            if to_slab {
                Region { src: b, dst: s, len, runs, src_stride: b_stride, dst_stride: s_stride, convert }
            } else {
                Region { src: s, dst: b, len, runs, src_stride: s_stride, dst_stride: b_stride, convert }
            }
        };
        let slab_voxels = edge * edge * n;
        if self.lateral_major {
            // Plane x = lo + p of the brick is its values x + 16·(y + 16z): one voxel every 64
            // bytes, landing at y + 16z of the slab's plane p.
            for k in 0..components {
                let b = brick.wrapping_add(k * BRICK_BYTES as usize);
                let s = slab.wrapping_add(k * slab_voxels * sb);
                for p in 0..n {
                    let plane = s.wrapping_add(p * edge * edge * sb);
                    out.push(pair(b.wrapping_add((lo + p) * 4), plane, 4, edge * edge, edge * 4, sb));
                }
            }
            return;
        }
        if n == edge {
            let len = components * BRICK_BYTES as usize;
            out.push(pair(brick, slab, len, 1, 0, 0));
            return;
        }
        for k in 0..components {
            let b = brick.wrapping_add(k * BRICK_BYTES as usize);
            let s = slab.wrapping_add(k * slab_voxels * sb);
            // Runs along x: whole x–y planes for z, rows of 16 for y, n voxels for x.
            let region = match self.axis {
                2 => pair(b.wrapping_add(lo * edge * edge * 4), s, slab_voxels * 4, 1, 0, 0),
                1 => pair(b.wrapping_add(lo * edge * 4), s, n * edge * 4, edge, edge * edge * 4, n * edge * sb),
                _ => pair(b.wrapping_add(lo * 4), s, n * 4, edge * edge, edge * 4, n * sb),
            };
            out.push(region);
        }
    }
}
