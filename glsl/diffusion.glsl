// diffusion.glsl: what the diffusion acceleration's two kernels share (diffusion_moments.comp,
// diffusion_prolong.comp): their push constants and the test of which voxels the diffusion grid
// holds. The host's twin of both is src/solver/acceleration.rs; the host side of the kernels is
// src/solver/gpu/accelerate.rs.

// `DiffusionPush` in src/solver/gpu/kernels.rs (checked by tests/it/shader_interface.rs).
layout(push_constant) uniform Push {
    uint count;     // unknowns (moments) or voxels (prolong)
    uint groups_x;  // workgroups along x of the dispatch (more go along y)
    uint unknowns;  // of the grid: the stride between channels of the moments and the change
    uint comps;     // source components per voxel (storage directions × channels)
    uint channels;
    uint edge;      // voxels per cell edge (a power of two)
    uint cells[3];  // cells of the grid along x, y, z
    uint first;         // moments: the round's first voxel of each cell's sequence
    uint round_voxels;  // moments: voxels per round
    uint albedo_grid;   // prolong: 1 when the scene has a per-voxel albedo factor
    double extinction[3];  // σt per unit density, per channel
    double scatter[3];     // σs per unit density, per channel
    double voxel_size;
    double four_pi;        // Σ Ω over the storage directions, summed on the host
} pc;

const uint BRICK_EDGE = 16u;
const uint BRICK_VOXELS = 4096u;
const uint NONE = 0xffffffffu;

// Whether a voxel of density `rho` is in the diffusion grid (`acceleration::in_grid`): it holds
// medium and no channel makes it thicker than MAX_VOXEL_DEPTH mean free paths. Products in the
// host's order, not fused.
bool in_grid(double rho) {
    if (!(rho > 0.0)) return false;
    for (uint ch = 0u; ch < pc.channels; ch++) {
        precise double depth = rho * pc.extinction[ch] * pc.voxel_size;
        if (depth > 2.0) return false;  // MAX_VOXEL_DEPTH
    }
    return true;
}
