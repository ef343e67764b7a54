// Shared by propagate.comp and collect.comp.
//
// Push constants: `SweepPush` in src/solver/gpu/layout.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint na;            // planes along the sweep axis (real dims)
    uint nb;            // rays / voxels along lateral axis b
    uint nc;            // rays / voxels along lateral axis c
    uint t0;            // first plane of this slice (sweep order)
    uint t1;            // one past the last plane of this slice
    uint axis_sign;     // bits 0-1: sweep axis a; bit 2: 1 when the sweep runs toward −a
    uint lateral;       // bits 0-1: axis b, bits 2-3: axis c; bit 4 (5): b (c) periodic
    uint bricks_b;      // bricks of the slice along b
    uint bricks_c;      // bricks of the slice along c
    uint dir_count;     // directions in this dispatch (the face's, or 1 beam)
    uint channels;      // 1 or 3
    uint storage;       // storage directions of the source
    uint flags;         // FLAG_*; with FLAG_HALF_SOURCE, bits 16-23: the f16 source's scale exponent + 128
    uint dir_base;      // first direction of this dispatch within the sweep's tables
    uint ray_base;      // index of the dispatch's first direction in the pass's ray buffers
    uint slab;          // bits 0-7: first local plane of the bricks' slab along a; bits 8-15: its planes
    vec4 sigma_t;       // extinction per unit density, rgb
    vec4 sigma_s;       // scattering per unit density, rgb
    vec4 emission;      // σa·Le per unit density, rgb
} pc;

const uint FLAG_BOUNDARY = 1u;   // rays are born with the boundary radiance (else zero)
const uint FLAG_GAIN = 2u;       // rays gain the previous order's source
const uint FLAG_EMIT = 4u;       // rays gain the emission σa·Le
// propagate.comp records every side exit where it happened (SideExits; the exitance maps).
// Keep in sync with FLAG_EXITS in src/solver/gpu/layout.rs.
const uint FLAG_EXITS = 8u;
const uint FLAG_VACUUM = 16u;    // the slice has no occupied brick: rays only move (no slot buffers)
// The previous source is f16, two per uint (lower address in the low half), each the source times
// 2^e with e = ((flags >> 16) & 255) - 128. Keep in sync with `half_source_flags` in
// src/solver/gpu/layout.rs.
const uint FLAG_HALF_SOURCE = 32u;
// The sweep axis is periodic: rays enter plane 0 with the radiance the ray buffer starts with (what
// the direction carried out last order, uploaded by the host: src/solver/periodic.rs).
const uint FLAG_CARRY = 64u;
// The slot (or resident) buffers hold each brick's slab lateral-major: b fastest, then c, then the
// sweep axis. The x sweeps' order (src/solver/gpu/slice.rs, src/solver/gpu/transpose.rs): their
// rays run along y, and in the brick's own x-fastest order neighbouring rays would read words 64
// bytes apart. Keep in sync with FLAG_LATERAL_MAJOR in src/solver/gpu/layout.rs.
const uint FLAG_LATERAL_MAJOR = 128u;
// `lateral` bits 4 and 5: lateral axis b, c is periodic (n rays of period n, not n + 1).
// Keep in sync with LATERAL_PERIODIC_* in src/solver/gpu/layout.rs.
bool periodic_b() { return (pc.lateral & 16u) != 0u; }
bool periodic_c() { return (pc.lateral & 32u) != 0u; }


// `GpuDirection` in src/solver/gpu/layout.rs (checked by tests/it/shader_interface.rs).
struct Direction {
    vec4 boundary;      // rgb radiance of a ray born at the boundary
    float path_length;  // h / |ω_a|
    float fluence_weight;
    uint gain_storage;
    uint pad;
};

int floor_div(int a, int n) { return (a >= 0) ? a / n : -((-a + n - 1) / n); }
int wrap_mod(int a, int n) { return a - floor_div(a, n) * n; }

// Voxel coordinates (x, y, z) of plane t, lateral column (vb, vc).
uvec3 voxel_of(uint t, uint vb, uint vc) {
    uint a = pc.axis_sign & 3u;
    bool negative = (pc.axis_sign & 4u) != 0u;
    uint va = negative ? pc.na - 1u - t : t;
    uvec3 v;
    v[a] = va;
    v[pc.lateral & 3u] = vb;
    v[(pc.lateral >> 2) & 3u] = vc;
    return v;
}

// The brick of the slice holding lateral column (vb, vc).
uint slice_brick(uint vb, uint vc) { return (vc / 16u) * pc.bricks_b + (vb / 16u); }

// Voxels per component of one brick's slab (the slot buffers hold slabs; src/solver/gpu/slice.rs).
uint slab_voxels() { return 256u * ((pc.slab >> 8) & 255u); }

// The voxel's index inside its brick's slab: the brick's x-fastest order with the sweep axis cut to
// the slab's planes (a whole brick when the slab has 16 planes); with FLAG_LATERAL_MAJOR, b
// fastest, then c, then the slab's planes.
uint slab_index(uvec3 v) {
    uvec3 l = v & 15u;
    uvec3 e = uvec3(16u);
    uint a = pc.axis_sign & 3u;
    l[a] -= pc.slab & 255u;
    if ((pc.flags & FLAG_LATERAL_MAJOR) != 0u) {
        return l[pc.lateral & 3u] + 16u * (l[(pc.lateral >> 2) & 3u] + 16u * l[a]);
    }
    e[a] = (pc.slab >> 8) & 255u;
    return l.x + e.x * (l.y + e.y * l.z);
}

// Segment functions: keep in sync with src/solver/segment.rs.
// E1(x) = (1 − e^{−x})/x, E2(x) = (x − 1 + e^{−x})/x², series below x = 1 (no cancellation).
float seg_e1(float x) {
    if (x < 1.0) {
        float r = 1.0 / 39916800.0;                  // 1/11!
        r = 1.0 / 3628800.0 - x * r;
        r = 1.0 / 362880.0 - x * r;
        r = 1.0 / 40320.0 - x * r;
        r = 1.0 / 5040.0 - x * r;
        r = 1.0 / 720.0 - x * r;
        r = 1.0 / 120.0 - x * r;
        r = 1.0 / 24.0 - x * r;
        r = 1.0 / 6.0 - x * r;
        r = 0.5 - x * r;
        return 1.0 - x * r;
    }
    return (1.0 - exp(-x)) / x;
}
float seg_e2(float x) {
    if (x < 1.0) {
        float r = 1.0 / 479001600.0;                 // 1/12!
        r = 1.0 / 39916800.0 - x * r;
        r = 1.0 / 3628800.0 - x * r;
        r = 1.0 / 362880.0 - x * r;
        r = 1.0 / 40320.0 - x * r;
        r = 1.0 / 5040.0 - x * r;
        r = 1.0 / 720.0 - x * r;
        r = 1.0 / 120.0 - x * r;
        r = 1.0 / 24.0 - x * r;
        r = 1.0 / 6.0 - x * r;
        return 0.5 - x * r;
    }
    return (1.0 - seg_e1(x)) / x;
}
