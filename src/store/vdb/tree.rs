//! The 5-4-3 tree: a root table of 4096³ tiles and 32³ internal nodes, 16³ internal nodes below
//! them, 8³ leaves at the bottom, with a constant tile in any slot that has no child, at every level.
//! [`read_topology`] reads the structure and the tile values (`Tree::readTopology`);
//! [`read_buffers`] then reads the leaves' values (`Tree::readBuffers`), leaf by leaf, in the order
//! the topology listed them. The tree is kept sparse: memory grows with the nodes in the file, never
//! with the volume's bounding box.

use super::error::R;
use super::stream::Stream;
use super::values::{read_values, Encoding};
use std::collections::HashMap;
use std::io::{Read, Seek};

const NONE: u32 = u32::MAX;
/// log2 of the edge of each level's node in child units, and in voxels.
const L5: u32 = 5;
const L4: u32 = 4;
const L3: u32 = 3;
/// Voxels along the edge of a root child (4096), of a 16³ node (128) and of a leaf (8).
const SPAN5: i32 = 1 << (L5 + L4 + L3);
const SPAN4: i32 = 1 << (L4 + L3);
const SPAN3: i32 = 1 << L3;

enum RootEntry {
    Tile { value: f32 },
    Node(u32),
}

struct Internal {
    /// Child index (into the next level's nodes) per slot, or NONE for a tile.
    children: Vec<u32>,
    /// Tile values (meaningful where there is no child).
    values: Vec<f32>,
}

/// A grid's tree with its values as f32.
pub struct Tree {
    pub background: f32,
    root: HashMap<[i32; 3], RootEntry>,
    node5: Vec<Internal>,
    node4: Vec<Internal>,
    leaf_masks: Vec<[u64; 8]>,
    leaf_values: Vec<[f32; 512]>,
    /// Inclusive index bounding box of the active voxels and tiles, if any is active.
    bbox: Option<[[i64; 3]; 2]>,
}

/// Slot of coordinate `c` inside a node of `log2` children of `child_log2` voxels each (x slowest).
fn slot(c: [i32; 3], log2: u32, child_log2: u32) -> usize {
    let m = (1 << log2) - 1;
    let i = c.map(|v| ((v >> child_log2) & m) as usize);
    (i[0] << (2 * log2)) | (i[1] << log2) | i[2]
}

/// The origin offset (in voxels) of slot `n` of a node of `log2` children of `child_log2` voxels.
fn slot_offset(n: usize, log2: u32, child_log2: u32) -> [i64; 3] {
    let m = (1usize << log2) - 1;
    [n >> (2 * log2), (n >> log2) & m, n & m].map(|v| (v as i64) << child_log2)
}

fn bit(mask: &[u64], n: usize) -> bool {
    mask[n >> 6] >> (n & 63) & 1 == 1
}

impl Tree {
    fn grow(&mut self, lo: [i64; 3], hi: [i64; 3]) {
        self.bbox = Some(match self.bbox {
            None => [lo, hi],
            Some([a, b]) => [std::array::from_fn(|i| a[i].min(lo[i])), std::array::from_fn(|i| b[i].max(hi[i]))],
        });
    }

    /// Inclusive index bounding box of the active voxels (leaf voxels and tiles), or `None` when
    /// nothing is active.
    pub fn active_bbox(&self) -> Option<[[i64; 3]; 2]> {
        self.bbox
    }

    pub fn leaf_count(&self) -> usize {
        self.leaf_masks.len()
    }

    /// The value at index coordinate `c` (OpenVDB's `tree.getValue`: active or not).
    pub fn value(&self, c: [i32; 3]) -> f32 {
        match self.lookup(c) {
            Ok((leaf, i)) => self.leaf_values.get(leaf).map_or(self.background, |l| l[i]),
            Err(v) => v,
        }
    }

    /// Where `c`'s value is: `Ok((leaf, index))` inside a leaf, or `Err(value)` for a tile or the
    /// background (constant over the whole leaf-sized block around `c`).
    pub fn lookup(&self, c: [i32; 3]) -> Result<(usize, usize), f32> {
        let key = c.map(|v| v & !(SPAN5 - 1));
        let n5 = match self.root.get(&key) {
            None => return Err(self.background),
            Some(RootEntry::Tile { value }) => return Err(*value),
            Some(RootEntry::Node(n)) => &self.node5[*n as usize],
        };
        let s5 = slot(c, L5, L4 + L3);
        let n4 = match n5.children[s5] {
            NONE => return Err(n5.values[s5]),
            n => &self.node4[n as usize],
        };
        let s4 = slot(c, L4, L3);
        match n4.children[s4] {
            NONE => Err(n4.values[s4]),
            leaf => Ok((leaf as usize, slot(c, L3, 0))),
        }
    }

    /// The value of the whole inclusive box `[lo, hi]` when one tile or the background covers it
    /// (so a brick in empty space costs one lookup, not 4096); `None` when it may vary.
    pub fn constant_over(&self, lo: [i32; 3], hi: [i32; 3]) -> Option<f32> {
        let same = |shift: u32| (0..3).all(|i| lo[i] >> shift == hi[i] >> shift);
        if !same(L5 + L4 + L3) {
            return None;
        }
        let n5 = match self.root.get(&lo.map(|v| v & !(SPAN5 - 1))) {
            None => return Some(self.background),
            Some(RootEntry::Tile { value }) => return Some(*value),
            Some(RootEntry::Node(n)) => &self.node5[*n as usize],
        };
        if !same(L4 + L3) {
            return None;
        }
        let s5 = slot(lo, L5, L4 + L3);
        let n4 = match n5.children[s5] {
            NONE => return Some(n5.values[s5]),
            n => &self.node4[n as usize],
        };
        if !same(L3) {
            return None;
        }
        let s4 = slot(lo, L4, L3);
        match n4.children[s4] {
            NONE => Some(n4.values[s4]),
            _ => None,
        }
    }

    /// The values of leaf `leaf` (x slowest, z fastest), if they were read.
    pub fn leaf(&self, leaf: usize) -> Option<&[f32; 512]> {
        self.leaf_values.get(leaf)
    }
}

/// Reads the tree's topology (`Tree::readTopology`): everything but the leaf values.
pub(crate) fn read_topology<S: Read + Seek>(s: &mut Stream<S>, enc: &mut Encoding) -> R<Tree> {
    let what = "the tree topology";
    let at = s.pos();
    let buffers = s.i32(what)?;
    if buffers != 1 {
        return Err(s.malformed(what, at, format!("{buffers} buffers per leaf; OpenVDB writes 1")));
    }
    enc.background = enc.value_type.read(s, "the background value")?;
    let at = s.pos();
    let (tiles, children) = (s.u32(what)?, s.u32(what)?);
    let entry_size = 12 + enc.value_type.size() as u64;
    if u64::from(tiles) * entry_size + u64::from(children) * 12 > s.remaining() {
        return Err(s.truncated("the root table", at));
    }
    let mut tree = Tree::with_background(enc.background);
    let check_origin = |s: &Stream<S>, at: u64, o: [i32; 3]| {
        if o.iter().any(|v| v & (SPAN5 - 1) != 0) {
            Err(s.malformed("the root table", at, format!("root entry origin {o:?} is not a multiple of {SPAN5}")))
        } else {
            Ok(())
        }
    };
    for _ in 0..tiles {
        let at = s.pos();
        let origin = s.coord("a root tile")?;
        let value = enc.value_type.read(s, "a root tile")?;
        let active = s.u8("a root tile")? != 0;
        check_origin(s, at, origin)?;
        if tree.root.insert(origin, RootEntry::Tile { value }).is_some() {
            return Err(s.malformed("the root table", at, format!("two entries at {origin:?}")));
        }
        if active {
            let lo = origin.map(i64::from);
            tree.grow(lo, lo.map(|v| v + i64::from(SPAN5) - 1));
        }
    }
    for _ in 0..children {
        let at = s.pos();
        let origin = s.coord("a root child's origin")?;
        check_origin(s, at, origin)?;
        let n = read_internal5(s, enc, &mut tree, origin.map(i64::from))?;
        if tree.root.insert(origin, RootEntry::Node(n)).is_some() {
            return Err(s.malformed("the root table", at, format!("two entries at {origin:?}")));
        }
    }
    Ok(tree)
}

/// Reads a node's masks and tile values; returns (child mask, tile values).
fn read_node<S: Read + Seek>(s: &mut Stream<S>, enc: &Encoding, log2: u32) -> R<(Vec<u64>, Vec<u64>, Vec<f32>)> {
    let words = 1usize << (3 * log2 - 6);
    let child_mask = s.mask(words, "an internal node's child mask")?;
    let value_mask = s.mask(words, "an internal node's value mask")?;
    let mut values = vec![0.0f32; 1 << (3 * log2)];
    read_values(s, enc, &value_mask, &mut values)?;
    Ok((child_mask, value_mask, values))
}

fn read_internal5<S: Read + Seek>(s: &mut Stream<S>, enc: &Encoding, tree: &mut Tree, origin: [i64; 3]) -> R<u32> {
    let (child_mask, value_mask, values) = read_node(s, enc, L5)?;
    let mut children = vec![NONE; values.len()];
    for (n, child) in children.iter_mut().enumerate() {
        let o = slot_offset(n, L5, L4 + L3);
        let o = std::array::from_fn(|i| origin[i] + o[i]);
        if bit(&child_mask, n) {
            *child = read_internal4(s, enc, tree, o)?;
        } else if bit(&value_mask, n) {
            tree.grow(o, o.map(|v| v + i64::from(SPAN4) - 1));
        }
    }
    tree.node5.push(Internal { children, values });
    Ok((tree.node5.len() - 1) as u32)
}

fn read_internal4<S: Read + Seek>(s: &mut Stream<S>, enc: &Encoding, tree: &mut Tree, origin: [i64; 3]) -> R<u32> {
    let (child_mask, value_mask, values) = read_node(s, enc, L4)?;
    let mut children = vec![NONE; values.len()];
    for (n, child) in children.iter_mut().enumerate() {
        let o = slot_offset(n, L4, L3);
        let o: [i64; 3] = std::array::from_fn(|i| origin[i] + o[i]);
        if bit(&child_mask, n) {
            let words = s.mask(8, "a leaf's value mask")?;
            let mask: [u64; 8] = std::array::from_fn(|i| words[i]);
            for v in 0..512usize {
                if bit(&mask, v) {
                    let p = [o[0] + (v >> 6) as i64, o[1] + ((v >> 3) & 7) as i64, o[2] + (v & 7) as i64];
                    tree.grow(p, p);
                }
            }
            *child = tree.leaf_masks.len() as u32;
            tree.leaf_masks.push(mask);
        } else if bit(&value_mask, n) {
            tree.grow(o, o.map(|v| v + i64::from(SPAN3) - 1));
        }
    }
    tree.node4.push(Internal { children, values });
    Ok((tree.node4.len() - 1) as u32)
}

/// Reads every leaf's values (`Tree::readBuffers`), in topology order.
pub(crate) fn read_buffers<S: Read + Seek>(s: &mut Stream<S>, enc: &Encoding, tree: &mut Tree) -> R<()> {
    tree.leaf_values.reserve_exact(tree.leaf_masks.len());
    for mask in &tree.leaf_masks {
        // The leaf repeats its value mask; the topology's copy is the one OpenVDB uses.
        s.skip(64, "a leaf's value mask")?;
        let mut values = [0.0f32; 512];
        read_values(s, enc, mask, &mut values)?;
        tree.leaf_values.push(values);
    }
    Ok(())
}

/// Building a [`Tree`] node by node from another sparse format (NanoVDB, see
/// [`crate::store::nanovdb`]): the same structure and the same rules as reading OpenVDB's topology,
/// so everything downstream (placement, brick filling) is shared. Origins are index coordinates of
/// the node's first voxel; slots are OpenVDB's (x slowest).
impl Tree {
    pub(crate) fn with_background(background: f32) -> Tree {
        Tree {
            background,
            root: HashMap::new(),
            node5: Vec::new(),
            node4: Vec::new(),
            leaf_masks: Vec::new(),
            leaf_values: Vec::new(),
            bbox: None,
        }
    }

    /// A 4096³ tile of the root; `false` when the root already has an entry there.
    pub(crate) fn add_root_tile(&mut self, origin: [i32; 3], value: f32, active: bool) -> bool {
        if self.root.contains_key(&origin) {
            return false;
        }
        self.root.insert(origin, RootEntry::Tile { value });
        if active {
            let lo = origin.map(i64::from);
            self.grow(lo, lo.map(|v| v + i64::from(SPAN5) - 1));
        }
        true
    }

    /// A 32³ node under the root (all its slots tiles of `fill` until set); `None` when the root
    /// already has an entry there.
    pub(crate) fn add_node5(&mut self, origin: [i32; 3], fill: f32) -> Option<u32> {
        if self.root.contains_key(&origin) {
            return None;
        }
        let n = self.node5.len() as u32;
        self.node5.push(Internal { children: vec![NONE; 1 << (3 * L5)], values: vec![fill; 1 << (3 * L5)] });
        self.root.insert(origin, RootEntry::Node(n));
        Some(n)
    }

    /// Slot `slot` of 32³ node `n5` (whose first voxel is `origin`) as a 128³ tile.
    pub(crate) fn set_node5_tile(&mut self, n5: u32, origin: [i32; 3], slot: usize, value: f32, active: bool) {
        self.node5[n5 as usize].values[slot] = value;
        if active {
            let o = slot_offset(slot, L5, L4 + L3);
            let lo: [i64; 3] = std::array::from_fn(|i| i64::from(origin[i]) + o[i]);
            self.grow(lo, lo.map(|v| v + i64::from(SPAN4) - 1));
        }
    }

    /// A 16³ node in slot `slot` of 32³ node `n5`.
    pub(crate) fn add_node4(&mut self, n5: u32, slot: usize, fill: f32) -> u32 {
        let n = self.node4.len() as u32;
        self.node4.push(Internal { children: vec![NONE; 1 << (3 * L4)], values: vec![fill; 1 << (3 * L4)] });
        self.node5[n5 as usize].children[slot] = n;
        n
    }

    /// Slot `slot` of 16³ node `n4` (whose first voxel is `origin`) as an 8³ tile.
    pub(crate) fn set_node4_tile(&mut self, n4: u32, origin: [i32; 3], slot: usize, value: f32, active: bool) {
        self.node4[n4 as usize].values[slot] = value;
        if active {
            let o = slot_offset(slot, L4, L3);
            let lo: [i64; 3] = std::array::from_fn(|i| i64::from(origin[i]) + o[i]);
            self.grow(lo, lo.map(|v| v + i64::from(SPAN3) - 1));
        }
    }

    /// A leaf (its active mask and 512 values, x slowest) in slot `slot` of 16³ node `n4`; its first
    /// voxel is `origin`.
    pub(crate) fn add_leaf(&mut self, n4: u32, slot: usize, origin: [i32; 3], mask: [u64; 8], values: [f32; 512]) {
        for v in 0..512usize {
            if bit(&mask, v) {
                let p = [
                    i64::from(origin[0]) + (v >> 6) as i64,
                    i64::from(origin[1]) + ((v >> 3) & 7) as i64,
                    i64::from(origin[2]) + (v & 7) as i64,
                ];
                self.grow(p, p);
            }
        }
        self.node4[n4 as usize].children[slot] = self.leaf_masks.len() as u32;
        self.leaf_masks.push(mask);
        self.leaf_values.push(values);
    }
}
