#version 450
// Transpose: reorders every brick block of one resident field, in place, between the brick's own
// order (x fastest: x + 16y + 256z) and the x sweeps' lateral-major order (y fastest:
// y + 16z + 256x, FLAG_LATERAL_MAJOR in common.glsl). One workgroup per block of 4096 values: it
// reads the block into shared memory, then writes it back permuted. A pure permutation of bits
// (f16 pairs are split and re-paired as bits, never converted), so a round trip is the identity.
// Host side: src/solver/gpu/transpose.rs.

layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) buffer Field { uint words[]; };

// `TransposePush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint blocks;        // blocks of 4096 values in the buffer
    uint half_values;   // 1: the values are f16, two to a word (lower address in the low half)
    uint to_lateral;    // 1: brick order → lateral-major; 0: back
    uint groups_x;      // workgroups along x of the dispatch (blocks beyond it go along y)
} pc;

const uint VALUES = 4096u;
shared uint tile[VALUES];

// Where word k of the block sits in the tile: its low four bits XORed with bits 4-7 and 8-11, a
// bijection inside each run of 16 words. The permuted reads step through the tile by 16 or 256
// words (8 or 128 for f16 pairs); unswizzled, 32 neighbouring invocations would hit one or two of
// the 32 banks of shared memory (16-way conflicts on a GPU); swizzled they spread over 16 to 32.
// Without padding, so the tile stays at 16 KiB, the least every device has.
uint slot(uint k) {
    return k ^ (((k >> 4u) ^ (k >> 8u)) & 15u);
}

// Where the value that lands at index j comes from, inside its block.
uint source_of(uint j) {
    // Lateral-major j = y + 16z + 256x comes from x + 16y + 256z = x + 16(y + 16z); brick-order
    // j = x + 16y + 256z comes from y + 16z + 256x = (y + 16z) + 256x.
    return pc.to_lateral != 0u ? (j >> 8) + 16u * (j & 255u) : (j >> 4) + 256u * (j & 15u);
}

uint half_at(uint value) {
    return (tile[slot(value >> 1)] >> (16u * (value & 1u))) & 0xffffu;
}

void main() {
    uint block = gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x;
    // The same for every invocation of the workgroup: no barrier is skipped by some of them only.
    if (block >= pc.blocks) return;
    uint n = pc.half_values != 0u ? VALUES / 2u : VALUES;
    uint base = block * n;
    for (uint i = gl_LocalInvocationID.x; i < n; i += 256u) tile[slot(i)] = words[base + i];
    barrier();
    for (uint i = gl_LocalInvocationID.x; i < n; i += 256u) {
        if (pc.half_values != 0u) {
            words[base + i] = half_at(source_of(2u * i)) | (half_at(source_of(2u * i + 1u)) << 16);
        } else {
            words[base + i] = tile[slot(source_of(i))];
        }
    }
}
