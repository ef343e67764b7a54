#version 450
// Propagate: one thread per ray per direction. Each thread marches its ray through the planes of
// the slice, gathers the medium and the source from the (up to) two-by-two voxels it lies between
// with the plane's lattice weights, writes its segment-average radiance into its lattice cell of T,
// and carries the ray's radiance to the next slice in the ray buffer (after the last slice: what
// leaves through the far face). A ray leaving through a side adds its radiance to the side's tally
// of its axis (half to each across an edge); the births need no tally, the host counts them from
// the offsets (src/solver/sweep.rs, side_births). With FLAG_EXITS it also records each side exit
// where it happened, for the per-face exitance maps (src/solver/gpu/face_maps.rs): per pass
// direction and channel, the exits through a b side by (plane t − 1, c column at t − 1), then those
// through a c side by (plane t − 1, b column at t − 1). A direction's slots wrap along an axis in at
// most one slot column (row) per plane, and its rays hold distinct columns in every plane, so each
// entry has one writer: plain stores, no atomics, the same bits on every run. The rays of one direction
// occupy distinct lattice cells in every plane (see src/solver/sweep.rs), so no two threads write
// the same T entry; collect.comp pulls each voxel's share from the cells around it.
// CPU twin: CpuTwin::sweep in src/solver/cpu.rs.
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x = 16, local_size_y = 4, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Directions { Direction dirs[]; };
layout(std430, binding = 1) readonly buffer Offsets { ivec4 offsets[]; };        // [dir][na]: o_b, o_c, w_b, w_c bits
layout(std430, binding = 2) readonly buffer SlotTable { int medium_slot[]; };    // [slice brick] → slot or −1
layout(std430, binding = 3) readonly buffer Density { float density[]; };        // [slot][slab voxel]
// The previous source: f32 bits, or f16 pairs with FLAG_HALF_SOURCE (see gained_source).
layout(std430, binding = 4) readonly buffer SourcePrev { uint j_prev[]; };       // [slot][d·C+ch][slab voxel]
layout(std430, binding = 5) buffer Rays { float ray_l[]; };                      // [dir][ch][ray]
layout(std430, binding = 6) buffer RaysOutB { float ray_out_b[]; };              // [dir][ch][ray]: left through a b side
layout(std430, binding = 7) buffer RaysOutC { float ray_out_c[]; };              // [dir][ch][ray]: left through a c side
layout(std430, binding = 8) writeonly buffer Deposit { float deposit[]; };       // [dispatch dir][ch][plane][lc][lb]
// [pass dir][ch]: [plane][lc] (b sides), then [plane][lb] (c sides); written only with FLAG_EXITS.
layout(std430, binding = 12) writeonly buffer SideExits { float side_exits[]; };

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
    // n + 1 rays (lattice columns) per lateral axis of n voxels; n on a periodic axis, where a
    // ray whose column wraps goes on (src/solver/periodic.rs).
    bool per_b = periodic_b(), per_c = periodic_c();
    int lb_n = int(pc.nb) + (per_b ? 0 : 1);
    int lc_n = int(pc.nc) + (per_c ? 0 : 1);
    if (p >= uint(lb_n) || q >= uint(lc_n) || local_dir >= pc.dir_count) return;
    uint di = pc.dir_base + local_dir;   // index into the sweep's tables
    uint ri = pc.ray_base + local_dir;   // index into the pass's ray buffers

    uint rays = uint(lb_n * lc_n);
    uint ray = q * uint(lb_n) + p;
    uint C = pc.channels;
    Direction dir = dirs[di];
    bool boundary = (pc.flags & FLAG_BOUNDARY) != 0u;
    vec3 birth = boundary ? dir.boundary.rgb : vec3(0.0);

    // What left through the sides is read and written only by rays that wrap in this dispatch
    // (few do): loaded at the first wrap, added to in the same order as ever, stored at the end.
    vec3 l = vec3(0.0), out_b = vec3(0.0), out_c = vec3(0.0);
    bool touched_b = false, touched_c = false;
    for (uint ch = 0u; ch < C; ++ch) {
        l[ch] = ray_l[(ri * C + ch) * rays + ray];
    }

    uint planes = pc.t1 - pc.t0;
    // The ray's lattice column, tracked incrementally: the offset moves by at most one column per
    // plane, so stepping out of [0, n] is exactly a wrap (a new ray). Divisions only once per slice.
    uint base = di * pc.na;
    ivec2 prev_o = offsets[base + (pc.t0 == 0u ? 0u : pc.t0 - 1u)].xy;
    int cb = wrap_mod(int(p) + prev_o.x + 1, lb_n);
    int cc = wrap_mod(int(q) + prev_o.y + 1, lc_n);
    // Vacuum: the radiance does not change, only wraps matter. Offsets are monotonic in t, so a ray
    // whose column stays inside [0, n] at the slice's last plane stayed inside all along: nothing
    // happens to it in this slice and the plane loop is skipped (rays born at plane 0 still loop).
    uint t_start = pc.t0;
    if ((pc.flags & FLAG_VACUUM) != 0u && pc.t0 > 0u) {
        ivec2 o_end = offsets[base + pc.t1 - 1u].xy;
        int eb = cb + o_end.x - prev_o.x;
        int ec = cc + o_end.y - prev_o.y;
        if ((per_b || (eb >= 0 && eb < lb_n)) && (per_c || (ec >= 0 && ec < lc_n))) t_start = pc.t1;
    }
    uint sv = slab_voxels();
    for (uint t = t_start; t < pc.t1; ++t) {
        ivec4 entry = offsets[base + t];
        ivec2 o = entry.xy;
        // On a periodic sweep axis the ray enters plane 0 with what it was given (FLAG_CARRY).
        bool born = (t == 0u) && (pc.flags & FLAG_CARRY) == 0u;
        if (t > 0u) {
            // The ray's columns at plane t − 1, where a side exit is recorded.
            int last_b = cb, last_c = cc;
            cb += o.x - prev_o.x;
            cc += o.y - prev_o.y;
            bool wrapped_b = false, wrapped_c = false;
            if (cb >= lb_n) { cb -= lb_n; wrapped_b = true; } else if (cb < 0) { cb += lb_n; wrapped_b = true; }
            if (cc >= lc_n) { cc -= lc_n; wrapped_c = true; } else if (cc < 0) { cc += lc_n; wrapped_c = true; }
            // A periodic axis has no side: its ray goes on.
            wrapped_b = wrapped_b && !per_b;
            wrapped_c = wrapped_c && !per_c;
            if (wrapped_b || wrapped_c) {
                // The ray left through a side (half through each across an edge): a new one
                // enters from the opposite side.
                float share = (wrapped_b && wrapped_c) ? 0.5 : 1.0;
                if (wrapped_b && !touched_b) {
                    for (uint ch = 0u; ch < C; ++ch) out_b[ch] = ray_out_b[(ri * C + ch) * rays + ray];
                    touched_b = true;
                }
                if (wrapped_c && !touched_c) {
                    for (uint ch = 0u; ch < C; ++ch) out_c[ch] = ray_out_c[(ri * C + ch) * rays + ray];
                    touched_c = true;
                }
                if (wrapped_b) out_b += share * l;
                if (wrapped_c) out_c += share * l;
                if ((pc.flags & FLAG_EXITS) != 0u) {
                    uint stride = pc.na * uint(lb_n + lc_n);
                    for (uint ch = 0u; ch < C; ++ch) {
                        uint rec = (ri * C + ch) * stride;
                        if (wrapped_b) side_exits[rec + (t - 1u) * uint(lc_n) + uint(last_c)] = share * l[ch];
                        if (wrapped_c) {
                            side_exits[rec + pc.na * uint(lc_n) + (t - 1u) * uint(lb_n) + uint(last_b)] = share * l[ch];
                        }
                    }
                }
                born = true;
            }
        }
        prev_o = o;
        if (born) l = birth;
        // Vacuum slices hold no medium: the ray keeps its radiance and nothing is deposited.
        if ((pc.flags & FLAG_VACUUM) != 0u) continue;
        // Gather from voxel columns (cb − 1, cb) × (cc − 1, cc) with weights (1 − w, w) per axis;
        // columns outside the volume and empty bricks hold vacuum. Fixed order: bitwise reproducible.
        vec2 w = intBitsToFloat(entry.zw);
        float rho = 0.0;
        vec3 j = vec3(0.0);
        bool gain = (pc.flags & FLAG_GAIN) != 0u;
        for (int dc = 0; dc < 2; ++dc) {
            int vc = cc - 1 + dc;
            if (vc < 0 && per_c) vc += int(pc.nc);
            float wc = dc == 0 ? 1.0 - w.y : w.y;
            if (wc == 0.0 || vc < 0 || vc >= int(pc.nc)) continue;
            for (int db = 0; db < 2; ++db) {
                int vb = cb - 1 + db;
                if (vb < 0 && per_b) vb += int(pc.nb);
                float wb = db == 0 ? 1.0 - w.x : w.x;
                if (wb == 0.0 || vb < 0 || vb >= int(pc.nb)) continue;
                int slot = medium_slot[slice_brick(uint(vb), uint(vc))];
                if (slot < 0) continue;
                float wt = wb * wc;
                uint local = slab_index(voxel_of(t, uint(vb), uint(vc)));
                rho += wt * density[uint(slot) * sv + local];
                if (gain) {
                    uint comps = pc.storage * C;
                    for (uint ch = 0u; ch < C; ++ch) {
                        j[ch] += wt * gained_source((uint(slot) * comps + dir.gain_storage * C + ch) * sv + local);
                    }
                }
            }
        }
        uint cell = ((t - pc.t0) * uint(lc_n) + uint(cc)) * uint(lb_n) + uint(cb);
        for (uint ch = 0u; ch < C; ++ch) {
            float jc = j[ch];
            if (gain && (pc.flags & FLAG_EMIT) != 0u) jc += rho * pc.emission[ch];
            float s = dir.path_length;
            float x = rho * pc.sigma_t[ch] * s;
            float e1 = seg_e1(x);
            float avg = l[ch] * e1 + jc * s * seg_e2(x);
            l[ch] = exp(-x) * l[ch] + jc * s * e1;
            // Every cell of a non-vacuum plane is written (collect may read any of them).
            deposit[(local_dir * C + ch) * planes * rays + cell] = avg;
        }
    }
    for (uint ch = 0u; ch < C; ++ch) {
        uint r = (ri * C + ch) * rays + ray;
        ray_l[r] = l[ch];
        if (touched_b) ray_out_b[r] = out_b[ch];
        if (touched_c) ray_out_c[r] = out_c[ch];
    }
}
