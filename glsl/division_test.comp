#version 450
// division_test.comp: exact.glsl's `div_rn_from` over a table of (a, b, q0) cases, q0 the starting
// quotient (the device's own a / b, or one spoiled on purpose, as a device with a loose f64
// division would give), so the test (tests/it/exact_division.rs) can check the result is the
// host's correctly rounded a / b bit for bit whatever the device's division does.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) readonly buffer Cases { double cases[]; };
layout(std430, binding = 1) writeonly buffer Quotients { double quotients[]; };

layout(push_constant) uniform Push {
    uint count;   // cases
    uint own;     // 1: start from the device's a / b instead of the case's q0
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    double a = cases[3u * i];
    double b = cases[3u * i + 1u];
    double q0 = pc.own != 0u ? a / b : cases[3u * i + 2u];
    quotients[i] = div_rn_from(a, b, q0);
}
