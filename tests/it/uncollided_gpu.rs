//! The traced emission's uncollided light on the device (`glsl/uncollided_trace.comp`,
//! `lpm::solver::uncollided::gpu`) against its CPU twin (`Clusters::receive` with the exact DDA):
//! a compact emitter beside a mirror (its images in the unfolded frame) in a heterogeneous medium
//! with a density step (emitters on a face of the medium), three channels, clusters taken whole;
//! every voxel's fluence and flux, clustered and with every pair exact; the device's trace is
//! bitwise the same run to run; and the kernel's constants are the host's.

use crate::common::validated;
use lpm::solver::gpu::kernels::{TraceTarget, UNCOLLIDED_NODE_COST, UNCOLLIDED_SEGMENT_COST, UNCOLLIDED_STACK};
use lpm::solver::uncollided::clusters::{Clusters, Emitter, Received, Work};
use lpm::solver::uncollided::gpu::{self, DeviceTrace, Inputs};
use lpm::solver::uncollided::kernel::NearTable;
use lpm::solver::uncollided::Unfolded;
use lpm::store::BRICK_VOXELS;
use lpm::vk::Context;
use std::time::Instant;

const DIMS: [u32; 3] = [20, 14, 12];
/// σt·h at density 1, per channel.
const EXTINCTION: [f64; 3] = [0.08, 0.05, 0.03];
const H: f64 = 0.5;
/// Device against twin, per voxel, where both walks took the same pairs: f32 rounding (measured
/// 7.8e-7 with every pair exact; see the module docs of `uncollided::gpu`).
const SAME_WALKS: f64 = 1e-5;
/// … and where an acceptance test sat on its threshold and the walks parted: the clustering's own
/// error (`clusters::tests`: within 0.5 % of every pair exact).
const PARTED_WALKS: f64 = 5e-3;

/// A smooth medium with a denser slab from z = 7 on (its face: a step of σt·h 0.04).
fn density(v: [u32; 3]) -> f32 {
    let [x, y, z] = v.map(|c| c as f32);
    1.0 + 0.3 * (0.5 * x).sin() * (0.4 * y).cos() + 0.2 * (0.3 * z).sin() + if v[2] >= 7 { 0.5 } else { 0.0 }
}

/// A 4×4×5 block of uneven emitters against the mirror at x = 0, across the slab's face, with
/// their images beyond the mirror; a face neighbour's σt·h differing by more than 0.02 makes an
/// emitter an edge one.
fn emitters(frame: &Unfolded) -> Vec<Emitter> {
    let largest = EXTINCTION.iter().cloned().fold(0.0, f64::max);
    let mut out = Vec::new();
    for z in 4..9u32 {
        for y in 5..9u32 {
            for x in 0..4u32 {
                let v = [x, y, z];
                let rho = density(v) as f64;
                let s = 1.0 + ((x * 7 + y * 3 + z * 5) % 11) as f64;
                let j = [s, 0.5 * s, 2.0 + s];
                let sigma = EXTINCTION.map(|e| e * rho);
                let edge = (0..3).any(|a| {
                    [-1i64, 1].iter().any(|&step| {
                        let mut c = v.map(|x| x as i64);
                        c[a] += step;
                        let inside = c[a] >= frame.lo[a] && c[a] < frame.hi[a];
                        let other = if inside { density(frame.source(c)) as f64 } else { 0.0 };
                        largest * (other - rho).abs() > 0.02
                    })
                });
                for cell in frame.images(v) {
                    out.push(Emitter { cell, j, sigma, edge });
                }
            }
        }
    }
    out
}

fn dense() -> Vec<f32> {
    let mut out = Vec::new();
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                out.push(density([x, y, z]));
            }
        }
    }
    out
}

/// The volume's bricks (16 voxels a side) as targets.
fn bricks() -> Vec<TraceTarget> {
    let mut out = Vec::new();
    for bz in 0..DIMS[2].div_ceil(16) {
        for by in 0..DIMS[1].div_ceil(16) {
            for bx in 0..DIMS[0].div_ceil(16) {
                let origin = [bx * 16, by * 16, bz * 16];
                let extent = std::array::from_fn(|a| (DIMS[a] - origin[a]).min(16));
                out.push(TraceTarget { origin, extent });
            }
        }
    }
    out
}

/// The voxel of brick `t` at local index `l`, when inside the volume.
fn cell_of(t: &TraceTarget, l: usize) -> Option<[i64; 3]> {
    let local = [l % 16, (l / 16) % 16, l / 256].map(|v| v as u32);
    (0..3).all(|a| local[a] < t.extent[a]).then(|| std::array::from_fn(|a| (t.origin[a] + local[a]) as i64))
}

/// Every brick's values on the device, brick by brick (each its own dispatch), with each voxel's
/// walk.
fn on_device(trace: &mut DeviceTrace, targets: &[TraceTarget]) -> Vec<(Received, Work)> {
    let mut out = Vec::new();
    for b in 0..targets.len() {
        let (values, _) = trace.receive(b, 1).expect("device trace");
        let walks = trace.walks(1).expect("walks");
        out.extend(values.into_iter().zip(walks));
    }
    out
}

/// Fluence and flux per voxel, device against twin: the worst relative differences (fluence per
/// channel; flux as |Δflux| over the channel-summed fluence) where the two walks took the same
/// pairs, and where they parted (an acceptance test on its threshold).
struct Compared {
    same: (f64, f64),
    parted: (f64, f64),
    parted_voxels: usize,
    voxels: usize,
    clusters: u64,
}

fn compare(device: &[(Received, Work)], inputs: &Inputs, targets: &[TraceTarget]) -> Compared {
    let mut c = Compared { same: (0.0, 0.0), parted: (0.0, 0.0), parted_voxels: 0, voxels: 0, clusters: 0 };
    for (b, t) in targets.iter().enumerate() {
        for l in 0..BRICK_VOXELS {
            let (got, walk) = &device[b * BRICK_VOXELS + l];
            let Some(cell) = cell_of(t, l) else {
                assert!(
                    got.fluence == [0.0; 3] && walk.near + walk.far + walk.clusters == 0,
                    "{b}/{l}: beyond the brick"
                );
                continue;
            };
            let mut w = Work::default();
            let want = gpu::receive_on_host(inputs, cell, &mut w);
            let fluence = (0..3)
                .map(|ch| {
                    assert!(want.fluence[ch] > 0.0, "{cell:?}: no light");
                    (got.fluence[ch] / want.fluence[ch] - 1.0).abs()
                })
                .fold(0.0, f64::max);
            let total: f64 = want.fluence.iter().sum();
            let flux = (got.flux - want.flux).length() / total;
            let same = w.clusters == walk.clusters && w.near == walk.near && w.far == walk.far;
            let slot = if same { &mut c.same } else { &mut c.parted };
            slot.0 = slot.0.max(fluence);
            slot.1 = slot.1.max(flux);
            c.parted_voxels += !same as usize;
            c.voxels += 1;
            c.clusters += w.clusters;
        }
    }
    c
}

#[test]
fn the_device_trace_is_its_cpu_twin_within_f32_and_repeats_bitwise() {
    let frame = Unfolded::new(DIMS, [[true, false], [false; 2], [false; 2]]).expect("one mirror");
    let tree = Clusters::new(emitters(&frame));
    let table = NearTable::new();
    let dense = dense();
    let targets = bricks();
    assert_eq!(targets.len(), 2);
    let ctx = Context::new(validated()).expect("Vulkan");
    for exact in [false, true] {
        let inputs = Inputs {
            tree: &tree,
            table: &table,
            frame,
            density: &dense,
            extinction: EXTINCTION,
            channels: 3,
            h: H,
            exact,
        };
        let t = Instant::now();
        let mut trace = DeviceTrace::new(&ctx, &inputs, &targets).expect("Vulkan").expect("the device takes it");
        let device = on_device(&mut trace, &targets);
        let device_seconds = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let c = compare(&device, &inputs, &targets);
        let host_seconds = t.elapsed().as_secs_f64();
        eprintln!(
            "exact {exact}: {} voxels, {} emitters, stack {}: same walks worst fluence {:.2e} flux {:.2e}; {} voxels' walks \
             parted, worst fluence {:.2e} flux {:.2e}; {} clusters taken whole (twin); device {device_seconds:.2} s, \
             twin {host_seconds:.2} s",
            c.voxels,
            tree.len(),
            gpu::stack_need(&tree),
            c.same.0,
            c.same.1,
            c.parted_voxels,
            c.parted.0,
            c.parted.1,
            c.clusters
        );
        assert!(c.same.0 < SAME_WALKS && c.same.1 < SAME_WALKS, "exact {exact}: {:?}", c.same);
        assert!(c.parted.0 < PARTED_WALKS && c.parted.1 < PARTED_WALKS, "exact {exact}: {:?}", c.parted);
        if exact {
            assert_eq!((c.clusters, c.parted_voxels), (0, 0));
        } else {
            assert!(c.clusters > 0, "no cluster taken whole");
        }
        // Run to run: the same bits.
        drop(trace);
        let mut again = DeviceTrace::new(&ctx, &inputs, &targets).expect("Vulkan").expect("the device takes it");
        let repeat = on_device(&mut again, &targets);
        let bits = |v: &[(Received, Work)]| -> Vec<u64> {
            v.iter().flat_map(|(r, _)| r.fluence.into_iter().chain(r.flux.to_array()).map(f64::to_bits)).collect()
        };
        assert!(bits(&repeat) == bits(&device), "exact {exact}: a second run differs");
    }
    let messages = ctx.validation_messages();
    assert!(messages.is_empty(), "validation errors:\n{}", messages.join("\n"));
}

/// The kernel's stack and loop charges are the host's constants.
#[test]
fn the_trace_kernel_constants_are_the_hosts() {
    let glsl = include_str!("../../glsl/uncollided_trace.comp");
    let constant = |name: &str| -> u32 {
        let line = glsl
            .lines()
            .find_map(|l| l.trim().strip_prefix(&format!("const uint {name} = ")))
            .unwrap_or_else(|| panic!("const uint {name} in glsl/uncollided_trace.comp"));
        line.trim_end_matches(';').trim_end_matches('u').parse().expect("a decimal value")
    };
    assert_eq!(constant("STACK"), UNCOLLIDED_STACK);
    assert_eq!(constant("NODE_COST"), UNCOLLIDED_NODE_COST);
    assert_eq!(constant("SEGMENT_COST"), UNCOLLIDED_SEGMENT_COST);
}
