#version 450
// Collect: one thread per voxel of the slice. Sums the segment-average radiance every direction of
// the dispatch deposited in T into the fluence (weighted by the direction's solid angle) and, where
// the medium scatters, into the next order's source (J^d += σs·Σ_i M[i][d]·L̄_i). Summation order is
// fixed, so results are bitwise reproducible. CPU twin: the deposit in CpuTwin::sweep.
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x = 16, local_size_y = 4, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Directions { Direction dirs[]; };
layout(std430, binding = 1) readonly buffer CollectRows { float rows[]; };       // [dir][storage]
layout(std430, binding = 2) readonly buffer SlotTable { int medium_slot[]; };
layout(std430, binding = 3) readonly buffer Density { float density[]; };
layout(std430, binding = 4) readonly buffer Deposit { float deposit[]; };        // [dispatch dir][ch][plane][vc][vb]
layout(std430, binding = 5) buffer SourceNext { float j_next[]; };               // [slot][d·C+ch][slab voxel]
layout(std430, binding = 6) buffer Fluence { float fluence[]; };                 // [slot][ch][slab voxel]

void main() {
    uint vb = gl_GlobalInvocationID.x;
    uint vc = gl_GlobalInvocationID.y;
    uint tt = gl_GlobalInvocationID.z;
    uint planes = pc.t1 - pc.t0;
    if (vb >= pc.nb || vc >= pc.nc || tt >= planes) return;

    // Empty bricks are not solved: no medium, no source, no fluence stored.
    int slot = medium_slot[slice_brick(vb, vc)];
    if (slot < 0) return;

    uint rays = pc.nb * pc.nc;
    uint C = pc.channels;
    uvec3 v = voxel_of(pc.t0 + tt, vb, vc);
    uint sv = slab_voxels();
    uint local = slab_index(v);
    float rho = density[uint(slot) * sv + local];
    uint cell = (tt * pc.nc + vc) * pc.nb + vb;

    // Each direction's contribution is added on its own, in direction order: whatever grouping of
    // directions or planes the memory budget chooses, every voxel sees the same sequence of f32
    // additions, so results are bitwise identical at any budget.
    for (uint ch = 0u; ch < C; ++ch) {
        uint fi = (uint(slot) * C + ch) * sv + local;
        float phi = fluence[fi];
        for (uint di = 0u; di < pc.dir_count; ++di) {
            phi += dirs[pc.dir_base + di].fluence_weight * deposit[(di * C + ch) * planes * rays + cell];
        }
        fluence[fi] = phi;

        float sigma_s = rho * pc.sigma_s[ch];
        if (sigma_s > 0.0) {
            uint comps = pc.storage * C;
            for (uint d = 0u; d < pc.storage; ++d) {
                uint ji = (uint(slot) * comps + d * C + ch) * sv + local;
                float j = j_next[ji];
                for (uint di = 0u; di < pc.dir_count; ++di) {
                    j += sigma_s * (rows[(pc.dir_base + di) * pc.storage + d] * deposit[(di * C + ch) * planes * rays + cell]);
                }
                j_next[ji] = j;
            }
        }
    }
}
