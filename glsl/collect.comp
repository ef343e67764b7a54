#version 450
// Collect: one thread per voxel of the slice. Pulls, for every direction of the dispatch, the
// voxel's share of the segment averages its rays deposited in T (the two-by-two lattice cells
// around it, with the plane's lattice weights: src/solver/sweep.rs) into the fluence (weighted by
// the direction's solid angle) and, where the medium scatters, into the next order's source
// (J^d += σs·Σ_i M[i][d]·L̄_i). Summation order is fixed, so results are bitwise reproducible.
// CPU twin: the deposit in CpuTwin::sweep.
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x = 16, local_size_y = 4, local_size_z = 1) in;

// One descriptor-set layout for both kernels (src/solver/gpu/encoder.rs SWEEP_BINDINGS): the
// bindings propagate.comp uses keep its numbers, collect's own ones follow from 9.
layout(std430, binding = 0) readonly buffer Directions { Direction dirs[]; };
layout(std430, binding = 1) readonly buffer Offsets { ivec4 offsets[]; };        // [dir][na]: o_b, o_c, w_b, w_c bits
layout(std430, binding = 2) readonly buffer SlotTable { int medium_slot[]; };
layout(std430, binding = 3) readonly buffer Density { float density[]; };
layout(std430, binding = 8) readonly buffer Deposit { float deposit[]; };        // [dispatch dir][ch][plane][lc][lb]
layout(std430, binding = 9) readonly buffer CollectRows { float rows[]; };       // [dir][storage]
layout(std430, binding = 10) buffer SourceNext { float j_next[]; };              // [slot][d·C+ch][slab voxel]
layout(std430, binding = 11) buffer Fluence { float fluence[]; };                // [slot][ch][slab voxel]

// The voxel's share of what direction `di` of the dispatch deposited in channel `ch`: lattice
// column c + 1 meets voxel column c with weight 1 − w, column c with weight w (per axis). Terms of
// weight 0 are left out (adding 0 would change nothing), in a fixed order.
// Directions whose pulled shares are held at once (registers or local memory).
const uint PULL_CHUNK = 16u;

float pulled(uint di, uint ch, uint tt, uint vb, uint vc, vec2 w, uint planes, uint rays) {
    uint lb_n = pc.nb + (periodic_b() ? 0u : 1u);
    uint lc_n = pc.nc + (periodic_c() ? 0u : 1u);
    uint base = (di * pc.channels + ch) * planes * rays + tt * rays;
    float sum = 0.0;
    for (uint dc = 0u; dc < 2u; ++dc) {
        float wc = dc == 0u ? 1.0 - w.y : w.y;
        if (wc == 0.0) continue;
        for (uint db = 0u; db < 2u; ++db) {
            float wb = db == 0u ? 1.0 - w.x : w.x;
            if (wb == 0.0) continue;
            // On a periodic axis lattice column n is column 0 (never reached on an open one).
            uint lb = vb + 1u - db, lc = vc + 1u - dc;
            if (lb == lb_n) lb = 0u;
            if (lc == lc_n) lc = 0u;
            sum += (wb * wc) * deposit[base + lc * lb_n + lb];
        }
    }
    return sum;
}

void main() {
    uint vb = gl_GlobalInvocationID.x;
    uint vc = gl_GlobalInvocationID.y;
    uint tt = gl_GlobalInvocationID.z;
    uint planes = pc.t1 - pc.t0;
    if (vb >= pc.nb || vc >= pc.nc || tt >= planes) return;

    // Empty bricks are not solved: no medium, no source, no fluence stored.
    int slot = medium_slot[slice_brick(vb, vc)];
    if (slot < 0) return;

    uint rays = (pc.nb + (periodic_b() ? 0u : 1u)) * (pc.nc + (periodic_c() ? 0u : 1u));
    uint C = pc.channels;
    uvec3 v = voxel_of(pc.t0 + tt, vb, vc);
    uint sv = slab_voxels();
    uint local = slab_index(v);
    float rho = density[uint(slot) * sv + local];

    // Each direction's contribution is added on its own, in direction order: whatever grouping of
    // directions or planes the memory budget chooses, every voxel sees the same sequence of f32
    // additions, so results are bitwise identical at any budget. Each direction's share is pulled
    // from the deposit once (for a chunk of directions at a time) and serves the fluence and every
    // storage direction's source: an anisotropic medium's 6·k_s² storage directions would
    // otherwise read the deposit that many times over.
    for (uint ch = 0u; ch < C; ++ch) {
        uint fi = (uint(slot) * C + ch) * sv + local;
        float phi = fluence[fi];
        float sigma_s = rho * pc.sigma_s[ch];
        uint comps = pc.storage * C;
        if (pc.storage == 1u) {
            // One storage direction (an isotropic medium): both sums in one pass, no chunks.
            uint ji = (uint(slot) * comps + ch) * sv + local;
            float j = sigma_s > 0.0 ? j_next[ji] : 0.0;
            for (uint di = 0u; di < pc.dir_count; ++di) {
                vec2 w = intBitsToFloat(offsets[(pc.dir_base + di) * pc.na + pc.t0 + tt].zw);
                float share = pulled(di, ch, tt, vb, vc, w, planes, rays);
                phi += dirs[pc.dir_base + di].fluence_weight * share;
                if (sigma_s > 0.0) j += sigma_s * (rows[pc.dir_base + di] * share);
            }
            fluence[fi] = phi;
            if (sigma_s > 0.0) j_next[ji] = j;
            continue;
        }
        for (uint d0 = 0u; d0 < pc.dir_count; d0 += PULL_CHUNK) {
            uint n = min(PULL_CHUNK, pc.dir_count - d0);
            float share[PULL_CHUNK];
            for (uint i = 0u; i < n; ++i) {
                uint di = d0 + i;
                vec2 w = intBitsToFloat(offsets[(pc.dir_base + di) * pc.na + pc.t0 + tt].zw);
                share[i] = pulled(di, ch, tt, vb, vc, w, planes, rays);
                phi += dirs[pc.dir_base + di].fluence_weight * share[i];
            }
            if (sigma_s > 0.0) {
                for (uint d = 0u; d < pc.storage; ++d) {
                    uint ji = (uint(slot) * comps + d * C + ch) * sv + local;
                    float j = j_next[ji];
                    for (uint i = 0u; i < n; ++i) {
                        j += sigma_s * (rows[(pc.dir_base + d0 + i) * pc.storage + d] * share[i]);
                    }
                    j_next[ji] = j;
                }
            }
        }
        fluence[fi] = phi;
    }
}
