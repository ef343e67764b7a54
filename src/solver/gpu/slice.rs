//! One slice of bricks on its way through a slot: which bricks, where each lands in the staging
//! buffers, and the copy regions between the store and the staging.
//!
//! Upload staging: `[slot table, padded to 16 B][density: occupied][previous source: occupied, only
//! when rays gain it][new source: occupied][fluence: all bricks]`; the device slot buffers hold the
//! same blocks, each at offset 0 of its own buffer. Download staging: `[new source][fluence]`.

use super::copier::Region;
use crate::solver::fields::StoreFields;
use crate::solver::sweep::{FaceSweep, SliceRange};
use crate::store::{BrickStore, BRICK_VOXELS};

pub const BRICK_BYTES: u64 = BRICK_VOXELS as u64 * 4;

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
}

impl SliceLayout {
    pub fn new(store: &BrickStore, sweep: &FaceSweep, range: SliceRange, gain: bool, channels: u64, comps: u64) -> Self {
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
        SliceLayout { range, bricks, occupied, slots, bricks_b, bricks_c, gain, channels, comps }
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
        self.slot_table_bytes().next_multiple_of(16)
    }

    pub fn density_bytes(&self) -> u64 {
        self.occ() * BRICK_BYTES
    }

    pub fn source_bytes(&self) -> u64 {
        self.occ() * self.comps * BRICK_BYTES
    }

    pub fn fluence_bytes(&self) -> u64 {
        self.dense() * self.channels * BRICK_BYTES
    }

    pub fn prev_offset(&self) -> u64 {
        self.density_offset() + self.density_bytes()
    }

    pub fn next_offset(&self) -> u64 {
        self.prev_offset() + if self.gain { self.source_bytes() } else { 0 }
    }

    pub fn fluence_offset(&self) -> u64 {
        self.next_offset() + self.source_bytes()
    }

    pub fn upload_bytes(&self) -> u64 {
        self.fluence_offset() + self.fluence_bytes()
    }

    /// Regions that fill the upload staging (at `staging`) from the store, all but the slot table
    /// (the caller writes that small table itself).
    pub fn gather(&self, store: &BrickStore, fields: &mut StoreFields, staging: *mut u8) -> Vec<Region> {
        let mut regions = Vec::with_capacity(self.occupied.len() * 3 + self.bricks.len());
        let block = (self.comps * BRICK_BYTES) as usize;
        let next_base = fields.source_next.as_mut_slice().as_mut_ptr() as *const u8;
        let prev_base = fields.source_prev.as_mut_slice().as_mut_ptr() as *const u8;
        let fluence_base = fields.fluence.as_mut_slice().as_mut_ptr() as *const u8;
        let at = |offset: u64| -> *mut u8 { staging.wrapping_add(offset as usize) };
        for (i, &b) in self.occupied.iter().enumerate() {
            if let Some(density) = store.density_brick(b) {
                regions.push(Region { src: density.as_ptr() as *const u8, dst: at(self.density_offset() + i as u64 * BRICK_BYTES), len: BRICK_BYTES as usize });
            }
            if let Some(k) = fields.source_next.stored_index(b) {
                if self.gain {
                    regions.push(Region { src: prev_base.wrapping_add(k * block), dst: at(self.prev_offset() + (i * block) as u64), len: block });
                }
                regions.push(Region { src: next_base.wrapping_add(k * block), dst: at(self.next_offset() + (i * block) as u64), len: block });
            }
        }
        let fblock = (self.channels * BRICK_BYTES) as usize;
        for (i, &b) in self.bricks.iter().enumerate() {
            if let Some(k) = fields.fluence.stored_index(b) {
                regions.push(Region { src: fluence_base.wrapping_add(k * fblock), dst: at(self.fluence_offset() + (i * fblock) as u64), len: fblock });
            }
        }
        regions
    }

    /// Regions that return the download staging (at `staging`) to the store.
    pub fn scatter(&self, fields: &mut StoreFields, staging: *const u8) -> Vec<Region> {
        let mut regions = Vec::with_capacity(self.occupied.len() + self.bricks.len());
        let block = (self.comps * BRICK_BYTES) as usize;
        let next_base = fields.source_next.as_mut_slice().as_mut_ptr() as *mut u8;
        let fluence_base = fields.fluence.as_mut_slice().as_mut_ptr() as *mut u8;
        for (i, &b) in self.occupied.iter().enumerate() {
            if let Some(k) = fields.source_next.stored_index(b) {
                regions.push(Region { src: staging.wrapping_add(i * block), dst: next_base.wrapping_add(k * block), len: block });
            }
        }
        let fblock = (self.channels * BRICK_BYTES) as usize;
        let off = self.source_bytes() as usize;
        for (i, &b) in self.bricks.iter().enumerate() {
            if let Some(k) = fields.fluence.stored_index(b) {
                regions.push(Region { src: staging.wrapping_add(off + i * fblock), dst: fluence_base.wrapping_add(k * fblock), len: fblock });
            }
        }
        regions
    }
}
