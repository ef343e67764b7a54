#version 450
// tally_sums.comp: after a pass, the sums of what the rays carried out, so that only these sums
// (and, on a periodic sweep axis, the far face's exits) come home instead of all three ray
// buffers. The three buffers hold, per direction and channel, one value per ray: what left
// through the far face, through a side of lateral axis b, of axis c. Each invocation sums one
// chunk of `chunk` consecutive rays of one (buffer, direction·channel) segment in f64, value after
// value in index order (f32 read from its bits, exact.glsl, so a device that flushes denormals
// sums what the host would); the host adds a segment's chunks in chunk order. Chunks keep each
// invocation's loop well under llvmpipe's 65535-iteration limit and spread the work over the
// device; the result is the same on every device. Host side: src/solver/gpu/tally_sums.rs.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "exact.glsl"

layout(std430, binding = 0) readonly buffer Far { uint far_words[]; };
layout(std430, binding = 1) readonly buffer SideB { uint side_b_words[]; };
layout(std430, binding = 2) readonly buffer SideC { uint side_c_words[]; };
layout(std430, binding = 3) writeonly buffer Sums { double sums[]; };

layout(push_constant) uniform Push {
    uint segments;  // directions × channels of the pass
    uint rays;      // values per segment
    uint chunks;    // chunks per segment: ceil(rays / chunk)
    uint chunk;     // rays to a chunk (4096: well under llvmpipe's loop limit)
    uint groups_x;  // workgroups along x of the dispatch (more go along y)
} pc;

void main() {
    uint id = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    uint per_buffer = pc.segments * pc.chunks;
    if (id >= 3u * per_buffer) return;
    uint buffer_index = id / per_buffer;
    uint rest = id % per_buffer;
    uint segment = rest / pc.chunks;
    uint chunk = rest % pc.chunks;
    uint first = chunk * pc.chunk;
    uint count = min(pc.chunk, pc.rays - first);
    uint base = segment * pc.rays + first;
    precise double sum = 0.0;
    for (uint i = 0u; i < count; i++) {
        uint bits;
        if (buffer_index == 0u) {
            bits = far_words[base + i];
        } else if (buffer_index == 1u) {
            bits = side_b_words[base + i];
        } else {
            bits = side_c_words[base + i];
        }
        sum += f64_of_f32_bits(bits);
    }
    sums[id] = sum;
}
