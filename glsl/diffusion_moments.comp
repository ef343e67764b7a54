#version 450
// diffusion_moments.comp: the restriction of the diffusion acceleration, on the device-resident
// fields. Per unknown (a cell of the diffusion grid holding medium), per channel, the scattered
// moment Σ_k Ω_k J_k of the order's new source summed over the cell's medium voxels, in the
// host's order (`Acceleration::moments`): the cell's bricks in slot order, each brick's voxels of
// the cell in their index order, the components in theirs; one invocation per unknown, so the
// f64 sums are the host's to the bit (f32 values read from their bits: exact.glsl). The host
// solves the diffusion equation with them (src/solver/gpu/accelerate.rs).
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"
#include "diffusion.glsl"

layout(std430, binding = 0) readonly buffer Density { uint density[]; };
layout(std430, binding = 1) readonly buffer Source { uint source[]; };
layout(std430, binding = 2) readonly buffer SolidAngles { double solid_angle[]; };
layout(std430, binding = 3) readonly buffer CellOfUnknown { uint cell_of_unknown[]; };
// The bricks (slots) overlapping unknown u's cell, in slot order: bricks[brick_start[u] .. brick_start[u + 1]].
layout(std430, binding = 4) readonly buffer BrickStart { uint brick_start[]; };
layout(std430, binding = 5) readonly buffer Bricks { uint bricks[]; };
layout(std430, binding = 6) readonly buffer Origins { uvec4 origin[]; };
// Channel after channel: moments[ch * unknowns + u] (zeros before the first round).
layout(std430, binding = 7) buffer Moments { double moments[]; };

void main() {
    uint u = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (u >= pc.count) return;
    uint cell = cell_of_unknown[u];
    uvec3 at = uvec3(cell % pc.cells[0], (cell / pc.cells[0]) % pc.cells[1], cell / (pc.cells[0] * pc.cells[1]));
    uvec3 lo = at * pc.edge;
    // The cell's voxels in each of its bricks form a box `e` voxels a side: the cell (cells no
    // larger than bricks lie in one brick) or the whole brick (larger cells hold whole bricks).
    uint e = min(pc.edge, BRICK_EDGE);
    uint box = e * e * e;
    uint first_brick = brick_start[u];
    uint end = min(pc.first + pc.round_voxels, box * (brick_start[u + 1u] - first_brick));
    if (pc.first >= end) return;
    precise double m[3];
    for (uint ch = 0u; ch < pc.channels; ch++) {
        m[ch] = moments[ch * pc.unknowns + u];
    }
    for (uint p = pc.first; p < end; p++) {
        uint slot = bricks[first_brick + p / box];
        uvec3 o = origin[slot].xyz;
        uvec3 from = max(lo, o) - o;
        uint i = p % box;
        uint x = from.x + i % e;
        uint y = from.y + (i / e) % e;
        uint z = from.z + i / (e * e);
        uint local = x + BRICK_EDGE * (y + BRICK_EDGE * z);
        if (in_grid(f64_of_f32_bits(density[slot * BRICK_VOXELS + local]))) {
            for (uint k = 0u; k < pc.comps; k++) {
                double j = f64_of_f32_bits(source[(slot * pc.comps + k) * BRICK_VOXELS + local]);
                m[k % pc.channels] += solid_angle[k / pc.channels] * j;
            }
        }
    }
    for (uint ch = 0u; ch < pc.channels; ch++) {
        moments[ch * pc.unknowns + u] = m[ch];
    }
}
