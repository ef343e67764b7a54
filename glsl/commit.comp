#version 450
// commit.comp: total[i] = total[i] + order[i] over a whole resident field, in f32 as the host's
// commit adds (bit for bit, denormals included: exact.glsl). The device-resident mode's commit of
// an order's source and fluence into the committed totals. Host side:
// src/solver/gpu/end_of_order.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) buffer Total { uint total[]; };
layout(std430, binding = 1) readonly buffer Order { uint order_values[]; };

// `EndPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;
    uint groups_x;
    uint mode;
    int param;
    double factor[3];
    double dark_floor;
} pc;

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    total[i] = f32_add_bits(total[i], order_values[i]);
}
