#version 450
// albedo_scale.comp: source[i] *= a(v), the per-voxel albedo factor of the voxel value i belongs
// to, in f32 as the host's `scale_by_albedo` multiplies (bit for bit, denormals included: the
// product of two f32 values is exact in f64, then rounded once, exact.glsl). The device-resident
// mode's first pass after an order's sweeps when the scene has an albedo grid (the sweeps scatter
// with the medium's albedo). Host side: src/solver/gpu/end_of_order.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) buffer Source { uint source[]; };
layout(std430, binding = 1) readonly buffer Albedo { uint albedo[]; };

// `EndPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // values of the source
    uint groups_x;  // workgroups along x of the dispatch (more go along y)
    uint mode;      // source components per voxel
    int param;
    double factor[3];
    double dark_floor;
} pc;

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    // Brick after brick, component after component, 4096 voxels each.
    uint slot = i / (pc.mode * 4096u);
    uint local = i % 4096u;
    precise double product = f64_of_f32_bits(source[i]) * f64_of_f32_bits(albedo[slot * 4096u + local]);
    source[i] = f32_bits_of(product);
}
