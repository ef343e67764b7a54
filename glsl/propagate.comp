#version 450
// Propagate: one thread per ray per direction. Each thread marches its ray through the planes of
// the slice, writes its segment-average radiance for every voxel it crosses into T, and carries the
// ray's radiance to the next slice in the ray buffer. The rays of one direction occupy distinct
// voxels in every plane (see src/solver/sweep.rs), so no two threads write the same T entry.
// CPU twin: CpuTwin::sweep in src/solver/cpu.rs.
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x = 16, local_size_y = 4, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Directions { Direction dirs[]; };
layout(std430, binding = 1) readonly buffer Offsets { ivec2 offsets[]; };        // [dir][na]
layout(std430, binding = 2) readonly buffer SlotTable { int medium_slot[]; };    // [slice brick] → slot or −1
layout(std430, binding = 3) readonly buffer Density { float density[]; };        // [slot][slab voxel]
// The previous source: f32 bits, or f16 pairs with FLAG_HALF_SOURCE (see gained_source).
layout(std430, binding = 4) readonly buffer SourcePrev { uint j_prev[]; };       // [slot][d·C+ch][slab voxel]
layout(std430, binding = 5) buffer Rays { float ray_l[]; };                      // [dir][ch][ray]
layout(std430, binding = 6) buffer RaysIn { float ray_in[]; };                   // [dir][ch][ray]
layout(std430, binding = 7) buffer RaysOut { float ray_out[]; };                 // [dir][ch][ray]
layout(std430, binding = 8) writeonly buffer Deposit { float deposit[]; };       // [dispatch dir][ch][plane][vc][vb]

// Element i of the previous source. f16 values are unscaled by 2^-e (exact: a power of two); slab
// voxel counts are multiples of 256, so every brick's components start on a whole uint.
float gained_source(uint i) {
    if ((pc.flags & FLAG_HALF_SOURCE) == 0u) return uintBitsToFloat(j_prev[i]);
    vec2 pair = unpackHalf2x16(j_prev[i >> 1]);
    int e = int((pc.flags >> 16) & 255u) - 128;
    return ldexp((i & 1u) == 0u ? pair.x : pair.y, -e);
}

void main() {
    uint p = gl_GlobalInvocationID.x;
    uint q = gl_GlobalInvocationID.y;
    uint local_dir = gl_GlobalInvocationID.z;
    if (p >= pc.nb || q >= pc.nc || local_dir >= pc.dir_count) return;
    uint di = pc.dir_base + local_dir;   // index into the sweep's tables
    uint ri = pc.ray_base + local_dir;   // index into the pass's ray buffers

    uint rays = pc.nb * pc.nc;
    uint ray = q * pc.nb + p;
    uint C = pc.channels;
    Direction dir = dirs[di];
    bool boundary = (pc.flags & FLAG_BOUNDARY) != 0u;
    vec3 birth = boundary ? dir.boundary.rgb : vec3(0.0);

    vec3 l = vec3(0.0), tin = vec3(0.0), tout = vec3(0.0);
    for (uint ch = 0u; ch < C; ++ch) {
        uint r = (ri * C + ch) * rays + ray;
        l[ch] = ray_l[r];
        tin[ch] = ray_in[r];
        tout[ch] = ray_out[r];
    }

    uint planes = pc.t1 - pc.t0;
    // The ray's column, tracked incrementally: the offset moves by at most one column per plane,
    // so stepping out of [0, n) is exactly a wrap (a new ray). Divisions only once per slice.
    uint base = di * pc.na;
    ivec2 prev_o = offsets[base + (pc.t0 == 0u ? 0u : pc.t0 - 1u)];
    int vb = wrap_mod(int(p) + prev_o.x, int(pc.nb));
    int vc = wrap_mod(int(q) + prev_o.y, int(pc.nc));
    // Vacuum: the radiance does not change, only wraps matter. Offsets are monotonic in t, so a ray
    // whose column stays inside [0, n) at the slice's last plane stayed inside all along: nothing
    // happens to it in this slice and the plane loop is skipped (rays born at plane 0 still loop).
    uint t_start = pc.t0;
    if ((pc.flags & FLAG_VACUUM) != 0u && pc.t0 > 0u) {
        ivec2 o_end = offsets[base + pc.t1 - 1u];
        int eb = vb + o_end.x - prev_o.x;
        int ec = vc + o_end.y - prev_o.y;
        if (eb >= 0 && eb < int(pc.nb) && ec >= 0 && ec < int(pc.nc)) t_start = pc.t1;
    }
    for (uint t = t_start; t < pc.t1; ++t) {
        ivec2 o = offsets[base + t];
        bool born = (t == 0u);
        if (t > 0u) {
            vb += o.x - prev_o.x;
            vc += o.y - prev_o.y;
            bool wrapped = false;
            if (vb >= int(pc.nb)) { vb -= int(pc.nb); wrapped = true; } else if (vb < 0) { vb += int(pc.nb); wrapped = true; }
            if (vc >= int(pc.nc)) { vc -= int(pc.nc); wrapped = true; } else if (vc < 0) { vc += int(pc.nc); wrapped = true; }
            if (wrapped) {
                // The ray left through a side: a new one enters from the opposite side.
                tout += l;
                born = true;
            }
        }
        prev_o = o;
        if (born) {
            l = birth;
            tin += birth;
        }
        // Empty bricks (and vacuum slices) hold no medium: the ray keeps its radiance and nothing
        // is deposited (collect skips their voxels).
        if ((pc.flags & FLAG_VACUUM) != 0u) continue;
        int slot = medium_slot[slice_brick(uint(vb), uint(vc))];
        if (slot < 0) continue;
        uvec3 v = voxel_of(t, uint(vb), uint(vc));
        uint sv = slab_voxels();
        uint local = slab_index(v);
        float rho = density[uint(slot) * sv + local];
        uint cell = ((t - pc.t0) * pc.nc + uint(vc)) * pc.nb + uint(vb);
        for (uint ch = 0u; ch < C; ++ch) {
            float j = 0.0;
            if ((pc.flags & FLAG_GAIN) != 0u) {
                uint comps = pc.storage * C;
                j = gained_source((uint(slot) * comps + dir.gain_storage * C + ch) * sv + local);
                if ((pc.flags & FLAG_EMIT) != 0u) j += rho * pc.emission[ch];
            }
            float s = dir.path_length;
            float x = rho * pc.sigma_t[ch] * s;
            float e1 = seg_e1(x);
            float avg = l[ch] * e1 + j * s * seg_e2(x);
            l[ch] = exp(-x) * l[ch] + j * s * e1;
            deposit[(local_dir * C + ch) * planes * rays + cell] = avg;
        }
    }
    if ((pc.flags & FLAG_LAST_SLICE) != 0u) {
        tout += l;
        l = vec3(0.0);
    }
    for (uint ch = 0u; ch < C; ++ch) {
        uint r = (ri * C + ch) * rays + ray;
        ray_l[r] = l[ch];
        ray_in[r] = tin[ch];
        ray_out[r] = tout[ch];
    }
}
