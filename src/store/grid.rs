//! Brick arithmetic: how a volume of arbitrary dims is tiled into 16³ bricks.

/// Voxels along each edge of a brick.
pub const BRICK_EDGE: u32 = 16;
/// Voxels in one brick (16³).
pub const BRICK_VOXELS: usize = 4096;

/// The tiling of a `dims` volume into bricks. Bricks are numbered x fastest, then y, then z; the
/// last brick along an axis is partial when `dims` is not a multiple of 16 (its voxels beyond `dims`
/// exist in storage and are always zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BrickGrid {
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
    /// Bricks along x, y, z (`ceil(dims / 16)`).
    pub bricks: [u32; 3],
}

impl BrickGrid {
    pub fn new(dims: [u32; 3]) -> Self {
        let bricks = dims.map(|d| d.div_ceil(BRICK_EDGE));
        BrickGrid { dims, bricks }
    }

    pub fn brick_count(&self) -> usize {
        self.bricks.iter().map(|&b| b as usize).product()
    }

    /// Linear index of brick `b` (x fastest).
    pub fn brick_index(&self, b: [u32; 3]) -> usize {
        let [bx, by, _] = self.bricks.map(|n| n as usize);
        b[0] as usize + bx * (b[1] as usize + by * b[2] as usize)
    }

    /// Inverse of [`BrickGrid::brick_index`].
    pub fn brick_coords(&self, i: usize) -> [u32; 3] {
        let [bx, by, _] = self.bricks.map(|n| n as usize);
        [(i % bx) as u32, ((i / bx) % by) as u32, (i / (bx * by)) as u32]
    }

    pub fn voxel_count(&self) -> u64 {
        self.dims.iter().map(|&d| d as u64).product()
    }

    /// True when voxel `v` lies inside `dims`.
    pub fn contains(&self, v: [u32; 3]) -> bool {
        v[0] < self.dims[0] && v[1] < self.dims[1] && v[2] < self.dims[2]
    }

    /// (brick index, local index `x%16 + 16·(y%16) + 256·(z%16)`) of voxel `v`.
    pub fn locate(&self, v: [u32; 3]) -> (usize, usize) {
        let b = v.map(|c| c / BRICK_EDGE);
        let l = v.map(|c| (c % BRICK_EDGE) as usize);
        (self.brick_index(b), local_index(l))
    }

    /// The first voxel of brick `b` (its corner with the smallest coordinates).
    pub fn brick_origin(&self, b: [u32; 3]) -> [u32; 3] {
        b.map(|c| c * BRICK_EDGE)
    }

    /// How many voxels of brick `b` lie inside `dims` along each axis (16 except at the far edges).
    pub fn brick_extent(&self, b: [u32; 3]) -> [u32; 3] {
        let mut e = [0; 3];
        for a in 0..3 {
            e[a] = (self.dims[a] - b[a] * BRICK_EDGE).min(BRICK_EDGE);
        }
        e
    }
}

/// Local index of voxel (x, y, z) inside its brick, each coordinate in 0..16.
pub fn local_index(l: [usize; 3]) -> usize {
    l[0] + 16 * (l[1] + 16 * l[2])
}

/// The volume coordinates of voxel `local` (x fastest, [`local_index`]'s order) of the brick whose
/// low corner is `origin`.
pub fn brick_voxel(origin: [u32; 3], local: usize) -> [u32; 3] {
    let edge = BRICK_EDGE as usize;
    [
        origin[0] + (local % edge) as u32,
        origin[1] + (local / edge % edge) as u32,
        origin[2] + (local / (edge * edge)) as u32,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_and_coords_round_trip() {
        let g = BrickGrid::new([37, 20, 53]);
        assert_eq!(g.bricks, [3, 2, 4]);
        assert_eq!(g.brick_count(), 24);
        for i in 0..g.brick_count() {
            assert_eq!(g.brick_index(g.brick_coords(i)), i);
        }
        assert_eq!(g.brick_extent([2, 1, 3]), [5, 4, 5]);
        assert_eq!(g.locate([36, 19, 52]), (g.brick_index([2, 1, 3]), 4 + 16 * 3 + 256 * 4));
    }
}
