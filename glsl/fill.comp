#version 450
// fill.comp: data[i] = value for every i < count. A smoke-test kernel for the Vulkan layer.
//
// Bindings: set 0, binding 0: the storage buffer to fill.
// Push constants (must match the host's 8-byte block): { uint count; uint value; }.

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, set = 0, binding = 0) writeonly buffer Data {
    uint data[];
};

layout(push_constant) uniform Push {
    uint count;
    uint value;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    // The last workgroup overhangs `count` (and the buffer may be larger than count).
    if (i >= pc.count) {
        return;
    }
    data[i] = pc.value;
}
