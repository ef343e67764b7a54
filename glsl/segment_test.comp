#version 450
// Test kernel, not used by the solver: evaluates the segment functions of common.glsl (seg_e1,
// seg_e2) at the optical depths of its input, so that tests/it/shader_interface.rs can hold the GLSL
// against src/solver/segment.rs. pc.na is the number of values.
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Depths { float xs[]; };
layout(std430, binding = 1) writeonly buffer Values { vec2 e[]; };    // (E1(x), E2(x))

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.na) return;
    e[i] = vec2(seg_e1(xs[i]), seg_e2(xs[i]));
}
