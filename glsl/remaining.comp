#version 450
// remaining.comp: the stop rule's tally (src/solver/remaining.rs) over the resident fields, one
// invocation per brick (unit) walking its channels and voxels in the host's order. Mode 0: the
// brightest committed fluence among the brick's medium voxels. Mode 1: with the dark floor (1e-12
// of the brightest over all bricks) and the tail factor per channel, the largest remaining error
// e_v, the sum of e_v² (f64, in walk order) and the count of voxels counted. The host adds the
// bricks up in slot order, as its own pass does. Host side: src/solver/gpu/end_of_order.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) readonly buffer Density { uint density[]; };
layout(std430, binding = 1) readonly buffer Total { uint total[]; };
layout(std430, binding = 2) readonly buffer Newest { uint newest[]; };

// `GpuUnitTally` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
struct UnitTally {
    double brightest;
    double sum_sq;
    uint max_e_bits;
    uint count;
    uint pad0;
    uint pad1;
};
layout(std430, binding = 3) buffer Tallies { UnitTally tallies[]; };

// `EndPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // bricks
    uint groups_x;
    uint mode;      // 0: brightest; 1: the tally
    int param;      // the channels
    double factor[3];
    double dark_floor;
} pc;

void main() {
    uint unit = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (unit >= pc.count) return;
    double brightest = 0.0;
    precise double sum_sq = 0.0;
    uint max_e = 0u;
    uint n = 0u;
    uint c = uint(pc.param);
    for (uint ch = 0u; ch < c; ch++) {
        uint base = (unit * c + ch) * 4096u;
        for (uint v = 0u; v < 4096u; v++) {
            uint rho = density[unit * 4096u + v];
            // ρ > 0 (denormals too, NaN not) from the bits.
            if (rho == 0u || rho > 0x7f800000u) continue;
            // By its magnitude (src/solver/remaining.rs: a warm start's total can be negative).
            double t = abs(f64_of_f32_bits(total[base + v]));
            if (!(t > 0.0) || isinf(t)) continue;
            if (pc.mode == 0u) {
                brightest = max(brightest, t);
                continue;
            }
            if (t < pc.dark_floor) continue;
            uint e_bits;
            double f = pc.factor[ch];
            if (isinf(f)) {
                e_bits = 0x7f800000u;
            } else {
                precise double add = f * abs(f64_of_f32_bits(newest[base + v]));
                precise double e = div_rn(add, t + add);
                e_bits = f32_bits_of(e);
            }
            precise double e = f64_of_f32_bits(e_bits);
            sum_sq += e * e;
            if (e_bits <= 0x7f800000u) max_e = max(max_e, e_bits);
            n += 1u;
        }
    }
    if (pc.mode == 0u) {
        tallies[unit].brightest = brightest;
    } else {
        tallies[unit].sum_sq = sum_sq;
        tallies[unit].max_e_bits = max_e;
        tallies[unit].count = n;
    }
}
