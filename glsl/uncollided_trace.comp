#version 450
// uncollided_trace.comp: the traced emission's uncollided light at every voxel of a batch of
// target bricks, on the device: the port, in f32, of `Clusters::receive`
// (src/solver/uncollided/clusters.rs), its CPU twin. One invocation per voxel of the batch walks
// the emitters' octree (Nodes, Children, Emitters) with a stack of its own, as the twin does:
// a node is taken whole when the target lies at least kappa radii away, its optical radius is at
// most tau, no member is on a face of the medium and the transmittance does not bend across it
// (the children's mean optical depth within `spread` of the centroid's); a leaf takes the near
// table (every |offset| <= near_reach) or its 2^3 Gauss points. Optical depths are the exact 3-D
// DDA of `point::optical_path_in` through the density of the frame unfolded by the mirrors
// (`Unfolded::source`). Output per voxel: the fluence per channel, the flux vector, and the pairs
// taken (clusters, near, far). Host side: src/solver/uncollided/gpu.rs.
//
// Rounds: llvmpipe (lavapipe) leaves every loop once a shader call has run 65535 loop iterations
// in all (one counter over all loops of its SIMD lanes), so on a CPU implementation each
// invocation spends at most `budget` iterations per dispatch (the host gives each lane its share)
// and keeps its stack and sums in Received and Stacks for the next round; `budget` 0 is one
// round without a limit (a GPU).

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

// The traversal stack's capacity (the host's `STACK_CAPACITY`; it refuses a deeper tree).
const uint STACK = 128u;
const uint BRICK_EDGE = 16u;
const uint BRICK_VOXELS = 4096u;
// Loop iterations charged per node besides its segments' DDA steps (its loops over children,
// Gauss points, channels and covariances, were none of them unrolled), and per segment besides
// its steps (the DDA's set-up over the axes): the host's `NODE_COST` and `SEGMENT_COST`.
const uint NODE_COST = 128u;
const uint SEGMENT_COST = 8u;
const float BIG = 3.0e38;

struct TraceNode {
    float centre[3];
    float radius;
    float j[3];
    float weight;
    float cov[6];  // xx, yy, zz, xy, xz, yz
    float sigma[3];  // the members' source-weighted σt·h per channel
    float sigma_max;
    uint flags;  // bit 0: a member is on a face of the medium; bit 1: a leaf
    uint first;  // a leaf: its emitter; else its first child in Children
    uint count;  // children
};

struct TraceEmitter {
    int cell[3];
    float j[3];
    float sigma[3];
};

struct TraceTarget {
    uint origin[3];
    uint extent[3];
};

struct TraceReceived {
    float fluence[3];
    float flux[3];
    uint clusters;
    uint near_pairs;
    uint far_pairs;
    uint depth;  // entries left on the stack: 0 when done
};

layout(std430, binding = 0) readonly buffer Nodes { TraceNode nodes[]; };
layout(std430, binding = 1) readonly buffer Children { uint children[]; };
layout(std430, binding = 2) readonly buffer Emitters { TraceEmitter emitters[]; };
// ln K by offset class and σ node (`NearTable`).
layout(std430, binding = 3) readonly buffer NearLn { float near_ln[]; };
// The volume's density, x fastest.
layout(std430, binding = 4) readonly buffer Density { float density[]; };
layout(std430, binding = 5) readonly buffer Targets { TraceTarget targets[]; };
layout(std430, binding = 6) buffer Received { TraceReceived received[]; };
// Each invocation's saved stack between rounds (stack_stride entries each).
layout(std430, binding = 7) buffer Stacks { uint stacks[]; };

layout(push_constant) uniform Push {
    int lo[3];  // the unfolded frame: cells lo .. hi per axis
    uint count;  // invocations: 4096 per target brick of the batch
    int hi[3];
    uint groups_x;
    uint dims[3];  // the volume's
    uint channels;
    float extinction[3];  // σt·h at density 1
    float h;  // the voxel edge
    float kappa;
    float tau;
    float spread;
    uint root;
    uint exact;  // 1: every pair exact (tests)
    uint first;  // the batch's first target brick
    uint sigma_nodes;
    float table_sigma_max;
    float node_scale;  // (sigma_nodes − 1) / ln(table_sigma_max + 1)
    int near_reach;
    uint max_steps;  // a DDA's steps at most (the frame's extents summed, and some)
    uint round_index;
    uint budget;  // loop iterations per invocation and round; 0: no limit
    uint stack_stride;
} pc;

// The density of the volume's cell that cell c of the unfolded frame images (`Unfolded::source`;
// no loop: every loop iteration counts against llvmpipe's limit).
float density_at(ivec3 c) {
    ivec3 n = ivec3(pc.dims[0], pc.dims[1], pc.dims[2]);
    ivec3 s = mix(c, -1 - c, lessThan(c, ivec3(0)));
    s = mix(s, 2 * n - 1 - c, greaterThanEqual(c, n));
    return density[uint(s.x) + pc.dims[0] * (uint(s.y) + pc.dims[1] * uint(s.z))];
}

// ∫ρ ds (voxel units) from a to b through the frame, by the 3-D DDA of `optical_path_in`; `steps`
// counts its iterations.
float optical_path(vec3 a, vec3 b, inout uint steps) {
    vec3 d = b - a;
    float len = length(d);
    if (!(len > 0.0)) return 0.0;
    vec3 dir = d / len;
    float t0 = 0.0;
    float t1 = len;
    for (int axis = 0; axis < 3; axis++) {
        float low = float(pc.lo[axis]);
        float size = float(pc.hi[axis]);
        if (dir[axis] == 0.0) {
            if (a[axis] < low || a[axis] > size) return 0.0;
        } else {
            float ta = (low - a[axis]) / dir[axis];
            float tb = (size - a[axis]) / dir[axis];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    if (!(t0 < t1)) return 0.0;
    vec3 start = a + dir * t0;
    ivec3 cell;
    vec3 t_max = vec3(BIG);
    vec3 t_delta = vec3(BIG);
    ivec3 stride = ivec3(0);
    for (int axis = 0; axis < 3; axis++) {
        float c = floor(start[axis]);
        // On a boundary and travelling down: the segment lies in the cell below.
        if (dir[axis] < 0.0 && c == start[axis]) c -= 1.0;
        cell[axis] = clamp(int(c), pc.lo[axis], pc.hi[axis] - 1);
        if (dir[axis] > 0.0) {
            stride[axis] = 1;
            t_max[axis] = (float(cell[axis]) + 1.0 - a[axis]) / dir[axis];
            t_delta[axis] = 1.0 / dir[axis];
        } else if (dir[axis] < 0.0) {
            stride[axis] = -1;
            t_max[axis] = (float(cell[axis]) - a[axis]) / dir[axis];
            t_delta[axis] = -1.0 / dir[axis];
        }
    }
    float t = t0;
    float sum = 0.0;
    for (uint s = 0u; s < pc.max_steps; s++) {
        steps++;
        int axis = (t_max.x <= t_max.y && t_max.x <= t_max.z) ? 0 : (t_max.y <= t_max.z ? 1 : 2);
        float t_next = min(t_max[axis], t1);
        if (t_next > t) {
            sum += density_at(cell) * (t_next - t);
            t = t_next;
        }
        if (t >= t1) break;
        cell[axis] += stride[axis];
        if (cell[axis] < pc.lo[axis] || cell[axis] >= pc.hi[axis]) break;
        t_max[axis] += t_delta[axis];
    }
    return sum;
}

// sinh(x)/x (the series where the difference of exponentials would cancel in f32).
float sinhc(float x) {
    if (abs(x) < 0.1) {
        float x2 = x * x;
        return 1.0 + x2 * (1.0 / 6.0 + x2 / 120.0);
    }
    return (exp(x) - exp(-x)) / (2.0 * x);
}

// The target voxel's mean over its cube of a source's T/r² as a factor on the centre value
// (`clusters::target_end`).
float target_end(vec3 u, float r, float sigma_v, float sigma_mean) {
    float ends = sinhc(0.5 * sigma_v * u.x) * sinhc(0.5 * sigma_v * u.y) * sinhc(0.5 * sigma_v * u.z);
    return ends * (1.0 + ((4.0 * sigma_v - 2.0 * sigma_mean) / r + 2.0 / (r * r)) / 24.0);
}

// K(c, σ) from the near table (`NearTable::kernel`): quadratic in ln K through the three nodes
// nearest σ's.
float near_kernel(ivec3 c, float sigma) {
    ivec3 m = abs(c);
    // Sorted ascending: the offset's class.
    if (m.x > m.y) m.xy = m.yx;
    if (m.y > m.z) m.yz = m.zy;
    if (m.x > m.y) m.xy = m.yx;
    uint n = uint(pc.near_reach) + 1u;
    uint base = ((uint(m.x) * n + uint(m.y)) * n + uint(m.z)) * pc.sigma_nodes;
    sigma = max(sigma, 0.0);
    uint last = pc.sigma_nodes - 1u;
    if (sigma >= pc.table_sigma_max) {
        float r = sqrt(float(c.x * c.x + c.y * c.y + c.z * c.z));
        return exp(near_ln[base + last] - (sigma - pc.table_sigma_max) * r);
    }
    float x = log(sigma + 1.0) * pc.node_scale;
    // Rounded half away from zero, as Rust's `round` (x ≥ 0).
    uint j = uint(clamp(int(floor(x + 0.5)), 1, int(last) - 1));
    float t = x - float(j);
    float lm = near_ln[base + j - 1u];
    float l0 = near_ln[base + j];
    float lp = near_ln[base + j + 1u];
    return exp(l0 + 0.5 * t * (lp - lm) + 0.5 * t * t * (lp - 2.0 * l0 + lm));
}

// u·C·u, the spread along the unit vector u of a covariance C (xx, yy, zz, xy, xz, yz): `along`.
float along(vec3 u, float c[6]) {
    return u.x * u.x * c[0] + u.y * u.y * c[1] + u.z * u.z * c[2]
        + 2.0 * (u.x * u.y * c[3] + u.x * u.z * c[4] + u.y * u.z * c[5]);
}

vec3 centre_of(uint n) {
    return vec3(nodes[n].centre[0], nodes[n].centre[1], nodes[n].centre[2]);
}

void main() {
    uint i = (gl_WorkGroupID.y * pc.groups_x + gl_WorkGroupID.x) * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    uint brick = pc.first + i / BRICK_VOXELS;
    uint local = i % BRICK_VOXELS;
    uvec3 l = uvec3(local % BRICK_EDGE, (local / BRICK_EDGE) % BRICK_EDGE, local / (BRICK_EDGE * BRICK_EDGE));
    TraceTarget target = targets[brick];
    bool inside = l.x < target.extent[0] && l.y < target.extent[1] && l.z < target.extent[2];
    ivec3 cell = ivec3(target.origin[0] + l.x, target.origin[1] + l.y, target.origin[2] + l.z);

    uint stack[STACK];
    uint sp = 0u;
    float fluence[3] = float[3](0.0, 0.0, 0.0);
    vec3 flux = vec3(0.0);
    uint clusters = 0u;
    uint near_pairs = 0u;
    uint far_pairs = 0u;
    if (pc.round_index == 0u) {
        if (inside) {
            stack[0] = pc.root;
            sp = 1u;
        }
    } else {
        TraceReceived s = received[i];
        if (s.depth == 0u) return;
        fluence = s.fluence;
        flux = vec3(s.flux[0], s.flux[1], s.flux[2]);
        clusters = s.clusters;
        near_pairs = s.near_pairs;
        far_pairs = s.far_pairs;
        sp = s.depth;
        for (uint k = 0u; k < sp; k++) {
            stack[k] = stacks[i * pc.stack_stride + k];
        }
    }
    // Iterations spent (the restore above) and kept for saving the stack at the end.
    uint used = sp + NODE_COST;
    uint reserve = pc.stack_stride + NODE_COST;

    vec3 x = vec3(cell) + 0.5;
    float rho = inside ? density_at(cell) : 0.0;
    float sigma_v[3];
    float largest = 0.0;
    for (uint ch = 0u; ch < 3u; ch++) {
        sigma_v[ch] = pc.extinction[ch] * rho;
        if (ch < pc.channels) largest = max(largest, pc.extinction[ch]);
    }
    // The 2³ Gauss–Legendre points of a unit cube about its centre: ±1/(2√3).
    float ga = 0.5 / sqrt(3.0);

    while (sp > 0u) {
        uint n = stack[sp - 1u];
        TraceNode node = nodes[n];
        vec3 middle = vec3(node.centre[0], node.centre[1], node.centre[2]);
        vec3 d = x - middle;
        float r = length(d);
        if (pc.budget != 0u) {
            // At most 9 segments (8 children and the centroid, or 8 Gauss points), each within
            // the node's radius of its centroid: a DDA of at most √3·(r + R) + 7 steps.
            uint steps_bound = min(uint(ceil(1.7321 * (r + node.radius))) + 10u, pc.max_steps);
            uint cost = NODE_COST + 9u * (steps_bound + SEGMENT_COST);
            if (used + cost + reserve > pc.budget) break;
        }
        sp--;
        uint steps = 0u;
        uint segments = 0u;
        if ((node.flags & 2u) != 0u) {
            TraceEmitter e = emitters[node.first];
            ivec3 ec = ivec3(e.cell[0], e.cell[1], e.cell[2]);
            ivec3 c = cell - ec;
            vec3 centre = vec3(ec) + 0.5;
            vec3 de = x - centre;
            float re = length(de);
            float g[3];
            if (all(lessThanEqual(abs(c), ivec3(pc.near_reach)))) {
                near_pairs++;
                float tau = 0.0;
                if (re > 0.0) {
                    tau = optical_path(centre, x, steps);
                    segments++;
                }
                for (uint ch = 0u; ch < 3u; ch++) {
                    float s = re > 0.0 ? pc.extinction[ch] * tau / re : e.sigma[ch];
                    g[ch] = near_kernel(c, s);
                }
            } else {
                // The source voxel by 2³ Gauss points, each its own segment.
                far_pairs++;
                float sum[3] = float[3](0.0, 0.0, 0.0);
                float tau_sum = 0.0;
                for (uint q = 0u; q < 8u; q++) {
                    vec3 offset = vec3((q & 1u) != 0u ? ga : -ga, (q & 2u) != 0u ? ga : -ga, (q & 4u) != 0u ? ga : -ga);
                    vec3 y = centre + offset;
                    vec3 dq = x - y;
                    float r2 = dot(dq, dq);
                    float tau = optical_path(y, x, steps);
                    segments++;
                    tau_sum += tau;
                    for (uint ch = 0u; ch < 3u; ch++) {
                        sum[ch] += 0.125 * exp(-pc.extinction[ch] * tau) / r2;
                    }
                }
                vec3 u = de / re;
                for (uint ch = 0u; ch < 3u; ch++) {
                    g[ch] = sum[ch] * target_end(u, re, sigma_v[ch], pc.extinction[ch] * tau_sum / 8.0 / re);
                }
            }
            float total = 0.0;
            for (uint ch = 0u; ch < 3u; ch++) {
                if (ch < pc.channels) {
                    float phi = pc.h * e.j[ch] * g[ch];
                    fluence[ch] += phi;
                    total += phi;
                }
            }
            if (re > 0.0) flux += de / re * total;
        } else {
            bool open = pc.exact != 0u || (node.flags & 1u) != 0u || r < pc.kappa * node.radius
                || node.sigma_max * node.radius > pc.tau;
            float taus[8];
            if (!open) {
                // The transmittance's bend across the cluster: the children's weighted mean
                // depth against the centroid's.
                float mean = 0.0;
                for (uint k = 0u; k < node.count; k++) {
                    uint child = children[node.first + k];
                    taus[k] = optical_path(centre_of(child), x, steps);
                    segments++;
                    mean += nodes[child].weight / node.weight * taus[k];
                }
                float at_centroid = optical_path(middle, x, steps);
                segments++;
                open = largest * abs(mean - at_centroid) > pc.spread;
            }
            if (open) {
                if (sp + node.count > STACK) {
                    // Deeper than the host measured: never (it refuses such a tree); say so.
                    received[i].depth = 0xFFFFFFFFu;
                    return;
                }
                // Children pushed last first: they come off the stack in their order.
                for (uint k = node.count; k > 0u; k--) {
                    stack[sp] = children[node.first + k - 1u];
                    sp++;
                }
            } else {
                clusters++;
                vec3 u = d / r;
                float t[3] = float[3](0.0, 0.0, 0.0);
                float inner[6] = float[6](0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                float tau_mean = 0.0;
                for (uint k = 0u; k < node.count; k++) {
                    uint child = children[node.first + k];
                    float w = nodes[child].weight / node.weight;
                    vec3 dk = x - centre_of(child);
                    float rk2 = dot(dk, dk);
                    float rk = sqrt(rk2);
                    tau_mean += w * taus[k];
                    // The child's members deeper or shallower in its own medium (`receive`).
                    float spread_k = along(u, nodes[child].cov) + 1.0 / 12.0;
                    for (uint ch = 0u; ch < 3u; ch++) {
                        float s = nodes[child].sigma[ch];
                        float deeper = 1.0 + spread_k * s * (0.5 * s + 2.0 / rk);
                        t[ch] += nodes[child].j[ch] * exp(-pc.extinction[ch] * taus[k]) / rk2 * deeper;
                    }
                    for (uint m = 0u; m < 6u; m++) {
                        inner[m] += w * nodes[child].cov[m];
                    }
                }
                float spread_along = along(u, inner) + 1.0 / 12.0;
                float trace = inner[0] + inner[1] + inner[2] + 0.25;
                float spread_factor = 1.0 + (4.0 * spread_along - trace) / (r * r);
                float total = 0.0;
                for (uint ch = 0u; ch < 3u; ch++) {
                    if (ch < pc.channels) {
                        float g = t[ch] * spread_factor * target_end(u, r, sigma_v[ch], pc.extinction[ch] * tau_mean / r);
                        float phi = pc.h * g;
                        fluence[ch] += phi;
                        total += phi;
                    }
                }
                flux += u * total;
            }
        }
        used += NODE_COST + steps + SEGMENT_COST * segments;
    }

    TraceReceived out_value;
    out_value.fluence = fluence;
    out_value.flux = float[3](flux.x, flux.y, flux.z);
    out_value.clusters = clusters;
    out_value.near_pairs = near_pairs;
    out_value.far_pairs = far_pairs;
    out_value.depth = sp;
    received[i] = out_value;
    for (uint k = 0u; k < sp; k++) {
        stacks[i * pc.stack_stride + k] = stack[k];
    }
}
