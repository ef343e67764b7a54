#version 450
// sharpen.comp: the diffusion correction of the device-resident mode (solver::antidiffusion's
// `sharpen_increment`, bit for bit): per voxel of the occupied bricks and per source component,
// the change C(T + S) − C(T) that this order's raw source S makes to the sharpened committed
// total T, C being the capped anti-diffusive fluxes between partner voxels two apart, each flux's
// κ thinned out in optically thick voxels (`Sharpening::stable_share`, with the host's portable
// e^−x, `exp_neg`). Every step is one IEEE f64 operation in the host's order, not contracted
// (`precise`); f32 values are read from their bits and rounded back from them (exact.glsl).
// One invocation per voxel. Host side: src/solver/gpu/sharpen.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) readonly buffer Density { uint density[]; };
layout(std430, binding = 1) readonly buffer Total { uint total[]; };
layout(std430, binding = 2) readonly buffer Raw { uint raw[]; };
layout(std430, binding = 3) writeonly buffer Sharpened { uint sharpened[]; };
// Per brick of the volume (x fastest), its slot, or EMPTY.
layout(std430, binding = 4) readonly buffer BrickSlots { uint brick_slot[]; };
layout(std430, binding = 5) readonly buffer Origins { uvec4 origin[]; };
// The albedo factor per voxel (bound to the density, unread, without an albedo grid: flag bit 9).
layout(std430, binding = 7) readonly buffer Albedo { uint albedo[]; };
// `SharpenConstants` in src/solver/gpu/kernels.rs, checked by tests/it/shader_interface.rs (computed on the host, so no
// f64 literal is parsed here).
layout(std430, binding = 6) readonly buffer Constants {
    double kappa_w[3];     // PARTNER_WEIGHT · κ per axis
    double thickness[3];   // σt·h per channel at density 1
    double albedo[3];      // per channel
    double two_thirds;     // 2/3
    double boost;          // Σκ
    double one_plus_boost; // 1 + Σκ
    double growth;         // LARGEST_VOXEL_PATTERN_GROWTH
    double small;          // SMALL_THICKNESS
    double flux_share;     // LARGEST_FLUX_SHARE
    double log2_e;
    double ln2_hi;         // ln 2 in two parts (antidiffusion::LN2_HI, LN2_LO)
    double ln2_lo;
    double exp_limit;      // 700
} c;

// `SharpenPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // voxels of the occupied bricks
    uint groups_x;  // workgroups along x of the dispatch (more go along y)
    uint comps;
    uint channels;
    uint dims[3];
    uint flags;     // bit a: axis a periodic; bit 3 + 2a + side: that face of axis a a mirror;
                    // bit 9: a per-voxel albedo factor
    uint bricks[2]; // bricks of the volume along x and y
} pc;

const uint BRICK_EDGE = 16u;
const uint BRICK_VOXELS = 4096u;
const uint EMPTY = 0xffffffffu;

// `antidiffusion::exp_neg`, step for step.
double exp_neg(double x) {
    if (!(x < c.exp_limit)) return 0.0;
    precise double scaled = x * c.log2_e + 0.5;
    int k = int(scaled);
    precise double y = (double(k) * c.ln2_hi - x) + double(k) * c.ln2_lo;
    precise double p = 1.0;
    for (int n = 13; n >= 1; n--) {
        precise double yp = y * p;
        p = 1.0 + div_rn(yp, double(n));
    }
    precise double out_value = p * uint64BitsToDouble(uint64_t(1023 - k) << 52);
    return out_value;
}

// `Sharpening::stable_share`.
double stable_share(double rho, double factor, uint ch) {
    precise double x = c.two_thirds * c.thickness[ch] * rho;
    precise double quick = c.albedo[ch] * factor * 0.5 * x * c.one_plus_boost;
    if (quick <= c.growth) return 1.0;
    precise double returned;
    if (x < c.small) {
        returned = 0.5 * x;
    } else {
        precise double less = exp_neg(x) - 1.0;
        returned = 1.0 + div_rn(less, x);
    }
    precise double loop_gain = c.albedo[ch] * factor * returned;
    precise double gained = loop_gain * c.one_plus_boost;
    if (gained <= c.growth || c.boost <= 0.0) return 1.0;
    precise double over = div_rn(c.growth, loop_gain) - 1.0;
    precise double share = div_rn(over, c.boost);
    // f64::clamp(0, 1), as the host clamps.
    if (share < 0.0) share = 0.0;
    if (share > 1.0) share = 1.0;
    return share;
}

// The slot and voxel of volume voxel `v`, or EMPTY.
uvec2 locate(uvec3 v) {
    uvec3 b = v / BRICK_EDGE;
    uint slot = brick_slot[b.x + pc.bricks[0] * (b.y + pc.bricks[1] * b.z)];
    uvec3 l = v % BRICK_EDGE;
    return uvec2(slot, l.x + BRICK_EDGE * (l.y + BRICK_EDGE * l.z));
}

// The scattering weight of a located voxel, density × albedo factor (`scattering_at`); 0 where
// no brick holds it.
double weight(uvec2 at) {
    if (at.x == EMPTY) return 0.0;
    uint v = at.x * BRICK_VOXELS + at.y;
    double a = (pc.flags & (1u << 9)) != 0u ? f64_of_f32_bits(albedo[v]) : 1.0;
    precise double m = f64_of_f32_bits(density[v]) * a;
    return m;
}

// One flux of the host's `flux` closure: s hands over to its partner, capped by the smaller value.
double flux(double kappa, double m, double mn, double s, double other) {
    precise double limit = c.flux_share * max(min(s, other), 0.0);
    precise double numerator = kappa * 2.0 * (m * other - mn * s);
    precise double f = div_rn(numerator, m + mn);
    // f64::clamp(−limit, limit), as the host clamps.
    if (f < -limit) f = -limit;
    if (f > limit) f = limit;
    return f;
}

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    uint slot = i / BRICK_VOXELS;
    uint local = i % BRICK_VOXELS;
    double rho = f64_of_f32_bits(density[i]);
    double m = weight(uvec2(slot, local));
    if (!(m > 0.0)) {
        for (uint k = 0u; k < pc.comps; k++) {
            uint at = (slot * pc.comps + k) * BRICK_VOXELS + local;
            sharpened[at] = raw[at];
        }
        return;
    }
    precise double factor = rho > 0.0 ? div_rn(m, rho) : 0.0;
    double share[3];
    for (uint ch = 0u; ch < pc.channels; ch++) share[ch] = stable_share(rho, factor, ch);
    // The partners (−x, +x, −y, +y, −z, +z) that scatter, with a voxel between that scatters too.
    uvec3 v = origin[slot].xyz + uvec3(local % BRICK_EDGE, (local / BRICK_EDGE) % BRICK_EDGE, local / (BRICK_EDGE * BRICK_EDGE));
    uint dims[3] = pc.dims;
    uvec2 partner[6];
    double partner_m[6];
    double partner_share[6][3];
    bool valid[6];
    for (uint n = 0u; n < 6u; n++) {
        valid[n] = false;
        uint axis = n / 2u;
        uint side = n % 2u;
        int d = int(dims[axis]);
        int step = side == 0u ? -1 : 1;
        int mid = int(v[axis]) + step;
        int far = int(v[axis]) + 2 * step;
        bool inside = mid >= 0 && mid < d && far >= 0 && far < d;
        if (!inside) {
            if ((pc.flags & (1u << axis)) != 0u) {
                mid = ((mid % d) + d) % d;
                far = ((far % d) + d) % d;
            } else if ((pc.flags & (1u << (3u + 2u * axis + side))) != 0u) {
                // Across a mirror the volume goes on as its image.
                int image_far = far < 0 ? -1 - far : (far >= d ? 2 * d - 1 - far : far);
                if (image_far < 0 || image_far >= d) continue;
                mid = mid < 0 ? -1 - mid : (mid >= d ? 2 * d - 1 - mid : mid);
                far = image_far;
            } else {
                continue;
            }
        }
        uvec3 between = v;
        between[axis] = uint(mid);
        if (!(weight(locate(between)) > 0.0)) continue;
        uvec3 w = v;
        w[axis] = uint(far);
        uvec2 at = locate(w);
        double mn = weight(at);
        if (!(mn > 0.0)) continue;
        valid[n] = true;
        partner[n] = at;
        partner_m[n] = mn;
        double rho_n = f64_of_f32_bits(density[at.x * BRICK_VOXELS + at.y]);
        precise double factor_n = rho_n > 0.0 ? div_rn(mn, rho_n) : 0.0;
        for (uint ch = 0u; ch < pc.channels; ch++) partner_share[n][ch] = stable_share(rho_n, factor_n, ch);
    }
    for (uint k = 0u; k < pc.comps; k++) {
        uint ch = k % pc.channels;
        uint at = (slot * pc.comps + k) * BRICK_VOXELS + local;
        double t = f64_of_f32_bits(total[at]);
        precise double x = t + f64_of_f32_bits(raw[at]);
        precise double change_before = 0.0;
        precise double change_after = 0.0;
        for (uint n = 0u; n < 6u; n++) {
            if (!valid[n]) continue;
            uint p = (partner[n].x * pc.comps + k) * BRICK_VOXELS + partner[n].y;
            double t_other = f64_of_f32_bits(total[p]);
            precise double x_other = t_other + f64_of_f32_bits(raw[p]);
            precise double kappa = c.kappa_w[n / 2u] * min(share[ch], partner_share[n][ch]);
            change_before -= flux(kappa, m, partner_m[n], t, t_other);
            change_after -= flux(kappa, m, partner_m[n], x, x_other);
        }
        precise double value = (x - t) + (change_after - change_before);
        sharpened[at] = f32_bits_of(value);
    }
}
