#version 450
// to_half.comp: the next order's previous source at f16, from the new source at f32: each value
// times 2^exponent rounded to the nearest f16, two to a word (the lower index in the low half), as
// the host's copy workers round it on the way up (exact.glsl). Host side:
// src/solver/gpu/end_of_order.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) writeonly buffer Half { uint halves[]; };
layout(std430, binding = 1) readonly buffer Full { uint values[]; };

// `EndPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // words of the f16 field (pairs of values)
    uint groups_x;
    uint mode;
    int param;     // the f16 scale's exponent
    double factor[3];
    double dark_floor;
} pc;

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    uint lo = f16_bits_scaled(values[2u * i], pc.param);
    uint hi = f16_bits_scaled(values[2u * i + 1u], pc.param);
    halves[i] = lo | (hi << 16);
}
