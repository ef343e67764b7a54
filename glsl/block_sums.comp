#version 450
// block_sums.comp: per block of 4096 values of a resident field (one component of one brick), the
// sum of |v| in f64, value after value in index order, and the largest |v| (NaN left out): the
// device-resident commit's share of the host's `combine` (the order's scattered power per block)
// and `max_abs` (the next order's f16 scale), bit for bit (exact.glsl). One invocation per block:
// the sum's order is the host's. Host side: src/solver/gpu/end_of_order.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) readonly buffer Field { uint words[]; };

// `BlockSum` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
struct BlockSum {
    double abs_sum;
    uint max_abs_bits;
    uint pad;
};
layout(std430, binding = 1) writeonly buffer Sums { BlockSum sums[]; };

// `EndPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // blocks (block_sums), values (commit, to_half) or units (remaining)
    uint groups_x;  // workgroups along x of the dispatch (more go along y)
    uint mode;
    int param;
    double factor[3];
    double dark_floor;
} pc;

void main() {
    uint block = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (block >= pc.count) return;
    precise double sum = 0.0;
    uint largest = 0u;
    uint base = block * 4096u;
    for (uint i = 0u; i < 4096u; i++) {
        uint a = words[base + i] & 0x7fffffffu;
        sum += f64_of_f32_bits(a);
        if (a <= 0x7f800000u) largest = max(largest, a);
    }
    sums[block].abs_sum = sum;
    sums[block].max_abs_bits = largest;
    sums[block].pad = 0u;
}
