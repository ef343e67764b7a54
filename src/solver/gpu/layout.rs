//! Host structs and constants shared with the shaders, twins of `Push`, `Direction` and the
//! `FLAG_*` constants in `glsl/common.glsl`. `tests/it/shader_interface.rs` reads the committed SPIR-V
//! and fails when a member's offset, a struct's size or a flag differs between the two sides.

use bytemuck::{Pod, Zeroable};

pub const FLAG_BOUNDARY: u32 = 1;
pub const FLAG_GAIN: u32 = 2;
pub const FLAG_EMIT: u32 = 4;
/// `propagate.comp` records every side exit where it happened, for the exitance maps
/// (`solver::gpu::face_maps`).
pub const FLAG_EXITS: u32 = 8;
pub const FLAG_VACUUM: u32 = 16;
/// The previous source is stored as f16 pairs, scaled by 2^e with e in bits 16–23 of `flags`
/// (biased by 128; see [`half_source_flags`]).
pub const FLAG_HALF_SOURCE: u32 = 32;
/// The sweep axis is periodic: the rays enter plane 0 with the radiance the ray buffer starts
/// with (uploaded: what the direction carried out last order, `solver::periodic`), not the birth.
pub const FLAG_CARRY: u32 = 64;
/// The slot (or resident) buffers hold each brick's slab lateral-major: lateral axis b fastest,
/// then c, then the sweep axis (`slab_index` in glsl/common.glsl). The x sweeps run on this order
/// (`solver::gpu::slice`, `solver::gpu::transpose`): their rays run along y, and in the brick's own
/// x-fastest order neighbouring rays would read words 64 bytes apart.
pub const FLAG_LATERAL_MAJOR: u32 = 128;
/// `lateral` bits 4 and 5: lateral axis b, c is periodic (n slots of period n, `solver::sweep`).
pub const LATERAL_PERIODIC_B: u32 = 16;
pub const LATERAL_PERIODIC_C: u32 = 32;
pub const HALF_SCALE_SHIFT: u32 = 16;
pub const HALF_SCALE_BIAS: i32 = 128;

/// The `flags` bits that tell the shader the previous source is f16, scaled by 2^`exponent`.
/// Keep in sync with `gained_source` in glsl/common.glsl.
pub fn half_source_flags(exponent: i32) -> u32 {
    FLAG_HALF_SOURCE | (((exponent + HALF_SCALE_BIAS) as u32 & 0xff) << HALF_SCALE_SHIFT)
}

/// Push constants of `propagate.comp` and `collect.comp` (`Push` in glsl/common.glsl; the kernel
/// table's reflection test, `tests/it/shader_interface.rs`, checks it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct SweepPush {
    pub na: u32,
    pub nb: u32,
    pub nc: u32,
    pub t0: u32,
    pub t1: u32,
    /// Bits 0–1: sweep axis; bit 2: the sweep runs toward −axis.
    pub axis_sign: u32,
    /// Bits 0–1: lateral axis b; bits 2–3: lateral axis c; bit 4 (5): b (c) is periodic.
    pub lateral: u32,
    pub bricks_b: u32,
    pub bricks_c: u32,
    pub dir_count: u32,
    pub channels: u32,
    pub storage: u32,
    /// FLAG_* bits; with FLAG_HALF_SOURCE, bits 16–23 hold the f16 source's scale exponent.
    pub flags: u32,
    /// First direction of the dispatch in the sweep's tables.
    pub dir_base: u32,
    /// First direction of the dispatch in the pass's ray buffers.
    pub ray_base: u32,
    /// Bits 0–7: the first local plane of the bricks' slab along the axis; bits 8–15: its planes.
    pub slab: u32,
    pub sigma_t: [f32; 4],
    pub sigma_s: [f32; 4],
    pub emission: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<SweepPush>() == 112);

/// One swept direction (`Direction` in glsl/common.glsl, std430; the kernel table's reflection
/// test checks it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuDirection {
    pub boundary: [f32; 4],
    pub path_length: f32,
    pub fluence_weight: f32,
    pub gain_storage: u32,
    pub pad: u32,
}
const _: () = assert!(std::mem::size_of::<GpuDirection>() == 32);
