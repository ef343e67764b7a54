#version 450
// diffusion_prolong.comp: the prolongation of the diffusion acceleration, on the device-resident
// fields. Per medium voxel of the grid, the change g of its cell's correction is added to the
// order's fluence and its scattered share σs·a·g/4π (a: the voxel's albedo factor, 1 without an
// albedo grid) to every storage direction of the new source,
// in f64 and rounded back to f32 as the host's `Acceleration::prolong` does, bit for bit
// (exact.glsl). One invocation per voxel of the occupied bricks. Host side:
// src/solver/gpu/accelerate.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"
#include "diffusion.glsl"

layout(std430, binding = 0) readonly buffer Density { uint density[]; };
layout(std430, binding = 1) buffer Source { uint source[]; };
layout(std430, binding = 2) buffer Fluence { uint fluence[]; };
// Per cell of the grid (x fastest), its unknown or NONE.
layout(std430, binding = 3) readonly buffer UnknownOf { uint unknown_of[]; };
layout(std430, binding = 4) readonly buffer Origins { uvec4 origin[]; };
// Channel after channel: change[ch * unknowns + u].
layout(std430, binding = 5) readonly buffer Change { double change[]; };
// The albedo factor per voxel (bound to the density, unread, without an albedo grid).
layout(std430, binding = 6) readonly buffer Albedo { uint albedo[]; };

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    uint slot = i / BRICK_VOXELS;
    uint local = i % BRICK_VOXELS;
    double rho = f64_of_f32_bits(density[i]);
    if (!in_grid(rho)) return;
    uvec3 v = origin[slot].xyz + uvec3(local % BRICK_EDGE, (local / BRICK_EDGE) % BRICK_EDGE, local / (BRICK_EDGE * BRICK_EDGE));
    uvec3 at = v / pc.edge;
    uint u = unknown_of[at.x + pc.cells[0] * (at.y + pc.cells[1] * at.z)];
    if (u == NONE) return;
    double a = pc.albedo_grid != 0u ? f64_of_f32_bits(albedo[i]) : 1.0;
    for (uint ch = 0u; ch < pc.channels; ch++) {
        double g = change[ch * pc.unknowns + u];
        uint f = (slot * pc.channels + ch) * BRICK_VOXELS + local;
        precise double phi = f64_of_f32_bits(fluence[f]) + g;
        fluence[f] = f32_bits_of(phi);
        precise double numerator = rho * pc.scatter[ch] * a * g;
        precise double add = div_rn(numerator, pc.four_pi);
        for (uint k = ch; k < pc.comps; k += pc.channels) {
            uint s = (slot * pc.comps + k) * BRICK_VOXELS + local;
            precise double j = f64_of_f32_bits(source[s]) + add;
            source[s] = f32_bits_of(j);
        }
    }
}
