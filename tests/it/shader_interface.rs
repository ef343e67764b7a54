//! The interface between the host and every kernel, checked against the committed SPIR-V instead
//! of "keep in sync" comments. `lpm::solver::gpu::kernels::ALL` is the one table of kernels; for
//! each: it is a `glsl/*.comp` (and every one of those is in the table), its push-constant
//! block's members sit at the Rust struct's `offset_of!` under the same names, the structs it
//! shares through buffers likewise, it declares its storage buffers in set 0 at exactly the
//! bindings the table gives (the names the host binds buffers by, `Kernel::set`), and its
//! workgroup size is the one the host dispatches with. The two sweep kernels share one set
//! (`SWEEP_BINDINGS`, every binding used by one of them), and the `FLAG_*` bits of
//! glsl/common.glsl are the Rust ones. A small test kernel (glsl/segment_test.comp) evaluates the
//! GLSL segment functions against src/solver/segment.rs over optical depths 1e-8 … 1e4.

use lpm::solver::gpu::buffers::SWEEP_BINDING_COUNT;
use lpm::solver::gpu::encoder::LOCAL_SIZE;
use lpm::solver::gpu::kernels::{self, Kernel, ALL, SWEEP_BINDINGS};
use lpm::solver::gpu::layout::{self, SweepPush};
use lpm::vk::{vk, BufferRange, Context, ContextOptions, MemoryLocation, Recorder};
use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{Decoration, ExecutionMode, Op, StorageClass};
use std::collections::{BTreeSet, HashMap};

const COMMON_GLSL: &str = include_str!("../../glsl/common.glsl");

fn load(spirv: &[u8]) -> Module {
    rspirv::dr::load_bytes(spirv).expect("parsing SPIR-V")
}

fn id(op: &Operand) -> u32 {
    match op {
        Operand::IdRef(i) => *i,
        other => panic!("expected an id, got {other:?}"),
    }
}

fn literal(op: &Operand) -> u32 {
    match op {
        Operand::LiteralBit32(v) => *v,
        other => panic!("expected a literal, got {other:?}"),
    }
}

fn global(module: &Module, result: u32) -> &Instruction {
    module.types_global_values.iter().find(|i| i.result_id == Some(result)).expect("a type or global of that id")
}

/// The size in bytes of a scalar, vector or array type (an array's by its stride).
fn type_size(module: &Module, ty: u32) -> u32 {
    let t = global(module, ty);
    match t.class.opcode {
        Op::TypeInt | Op::TypeFloat => literal(&t.operands[0]) / 8,
        Op::TypeVector => type_size(module, id(&t.operands[0])) * literal(&t.operands[1]),
        Op::TypeArray => {
            let length = literal(&global(module, id(&t.operands[1])).operands[0]);
            let stride = decorations(module, ty)
                .get(&Decoration::ArrayStride)
                .copied()
                .flatten()
                .unwrap_or_else(|| type_size(module, id(&t.operands[0])));
            stride * length
        }
        other => panic!("unexpected member type {other:?}"),
    }
}

/// The members of struct type `ty` as (name, offset), in offset order, and the struct's size
/// (last member's offset + its size).
fn struct_members(module: &Module, ty: u32) -> (Vec<(String, u32)>, u32) {
    let mut names = HashMap::new();
    for n in &module.debug_names {
        if n.class.opcode == Op::MemberName && id(&n.operands[0]) == ty {
            if let Operand::LiteralString(s) = &n.operands[2] {
                names.insert(literal(&n.operands[1]), s.clone());
            }
        }
    }
    let mut members = Vec::new();
    for a in &module.annotations {
        if a.class.opcode == Op::MemberDecorate
            && id(&a.operands[0]) == ty
            && a.operands[2] == Operand::Decoration(Decoration::Offset)
        {
            let m = literal(&a.operands[1]);
            members.push((m, names.get(&m).cloned().unwrap_or_default(), literal(&a.operands[3])));
        }
    }
    members.sort_by_key(|&(_, _, offset)| offset);
    let st = global(module, ty);
    let size = members.last().map_or(0, |&(m, _, offset)| offset + type_size(module, id(&st.operands[m as usize])));
    (members.into_iter().map(|(_, n, o)| (n, o)).collect(), size)
}

/// The pointee of pointer type `ptr`.
fn pointee(module: &Module, ptr: u32) -> u32 {
    id(&global(module, ptr).operands[1])
}

fn decorations(module: &Module, target: u32) -> HashMap<Decoration, Option<u32>> {
    let mut d = HashMap::new();
    for a in &module.annotations {
        if a.class.opcode == Op::Decorate && id(&a.operands[0]) == target {
            if let Operand::Decoration(dec) = a.operands[1] {
                d.insert(dec, a.operands.get(2).map(literal));
            }
        }
    }
    d
}

fn variables(module: &Module, class: StorageClass) -> Vec<&Instruction> {
    module
        .types_global_values
        .iter()
        .filter(|i| i.class.opcode == Op::Variable && i.operands.first() == Some(&Operand::StorageClass(class)))
        .collect()
}

/// The push-constant block's members and size.
fn push_block(module: &Module) -> (Vec<(String, u32)>, u32) {
    let vars = variables(module, StorageClass::PushConstant);
    assert_eq!(vars.len(), 1, "one push-constant block");
    let ty = pointee(module, vars[0].result_type.expect("a typed variable"));
    struct_members(module, ty)
}

/// The name glslang gives `target` (a block's type name: `Directions`, `Deposit`, ...).
fn name_of(module: &Module, target: u32) -> String {
    module
        .debug_names
        .iter()
        .find(|n| n.class.opcode == Op::Name && id(&n.operands[0]) == target)
        .and_then(|n| match &n.operands[1] {
            Operand::LiteralString(s) => Some(s.clone()),
            _ => None,
        })
        .unwrap_or_default()
}

/// The storage-buffer bindings as (set, binding, block name), sorted.
fn storage_bindings(module: &Module) -> Vec<(u32, u32, String)> {
    let mut b: Vec<(u32, u32, String)> = variables(module, StorageClass::StorageBuffer)
        .iter()
        .map(|v| {
            let d = decorations(module, v.result_id.expect("a variable id"));
            let block = name_of(module, pointee(module, v.result_type.expect("a typed variable")));
            (d[&Decoration::DescriptorSet].expect("a set"), d[&Decoration::Binding].expect("a binding"), block)
        })
        .collect();
    b.sort_unstable();
    b
}

fn local_size(module: &Module) -> [u32; 3] {
    let mode = module
        .execution_modes
        .iter()
        .find(|m| m.operands[1] == Operand::ExecutionMode(ExecutionMode::LocalSize))
        .expect("a LocalSize execution mode");
    [literal(&mode.operands[2]), literal(&mode.operands[3]), literal(&mode.operands[4])]
}

/// Every uniform descriptor the kernels declare (anything but storage buffers and push constants).
fn other_descriptors(module: &Module) -> usize {
    [StorageClass::Uniform, StorageClass::UniformConstant].iter().map(|&c| variables(module, c).len()).sum()
}

fn load_kernel(k: &Kernel) -> Module {
    load(k.spirv)
}

/// The table's members in offset order.
fn table_members(m: &kernels::Members) -> Vec<(String, u32)> {
    let mut v: Vec<(String, u32)> = m.fields.iter().map(|&(n, o)| (n.to_string(), o as u32)).collect();
    v.sort_by_key(|(_, o)| *o);
    v
}

#[test]
fn every_kernel_in_glsl_is_in_the_table_once() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("glsl");
    let mut in_glsl: Vec<String> = std::fs::read_dir(&dir)
        .expect("glsl/")
        .filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".comp").map(str::to_string))
        .collect();
    in_glsl.sort();
    let mut in_table: Vec<String> = ALL.iter().map(|k| k.name.to_string()).collect();
    in_table.sort();
    assert_eq!(in_table, in_glsl, "kernels::ALL against glsl/*.comp");
    for k in ALL {
        let committed = std::fs::read(dir.join(format!("../spirv/{}.spv", k.name))).expect("spirv/<name>.spv");
        assert!(committed == k.spirv, "{}: the table's SPIR-V is not spirv/{}.spv", k.name, k.name);
    }
}

#[test]
fn push_constants_sit_where_the_rust_struct_puts_them() {
    for k in ALL {
        let (members, size) = push_block(&load_kernel(k));
        assert_eq!(members, table_members(&k.push), "{}: push-constant members (name, offset), GLSL vs Rust", k.name);
        assert_eq!(size as usize, k.push.size, "{}: push-constant block size", k.name);
    }
}

#[test]
fn structs_in_buffers_match_the_rust_ones() {
    for k in ALL {
        let module = load_kernel(k);
        for (glsl, rust) in k.structs {
            // glslang emits a struct twice: laid out (std430, with offsets) for the buffer, and plain.
            let (members, size) = module
                .debug_names
                .iter()
                .filter(|n| n.class.opcode == Op::Name && n.operands[1] == Operand::LiteralString((*glsl).into()))
                .map(|n| struct_members(&module, id(&n.operands[0])))
                .find(|(members, _)| !members.is_empty())
                .unwrap_or_else(|| panic!("{}: no struct `{glsl}` with offsets", k.name));
            assert_eq!(members, table_members(rust), "{}: `{glsl}` members (name, offset), GLSL vs Rust", k.name);
            assert_eq!(size as usize, rust.size, "{}: `{glsl}` size", k.name);
        }
    }
}

#[test]
fn every_kernel_binds_set_0_as_the_host_writes_it() {
    let mut sweep_used = BTreeSet::new();
    for k in ALL {
        let module = load_kernel(k);
        let bindings = storage_bindings(&module);
        let declared: Vec<(u32, String)> = bindings
            .iter()
            .map(|(set, binding, block)| {
                assert_eq!(*set, 0, "{}: {block} is not in set 0", k.name);
                (*binding, block.clone())
            })
            .collect();
        let table: Vec<(u32, String)> = k.bindings.iter().map(|&(b, n)| (b, n.to_string())).collect();
        assert_eq!(declared, table, "{}: storage buffers (binding, block), GLSL vs the table", k.name);
        assert!(k.bindings.iter().all(|&(b, _)| b < k.layout_bindings), "{}: a binding outside its layout", k.name);
        assert_eq!(other_descriptors(&module), 0, "{}: the host binds storage buffers only", k.name);
        if k.layout_bindings == SWEEP_BINDING_COUNT && ["propagate", "collect"].contains(&k.name) {
            for &(b, name) in k.bindings {
                assert_eq!(SWEEP_BINDINGS[b as usize], name, "{}: binding {b} of the shared sweep set", k.name);
                sweep_used.insert(b);
            }
        }
    }
    // Every binding of the shared sweep set is used by one of its kernels.
    assert_eq!(sweep_used, (0..SWEEP_BINDING_COUNT).collect::<BTreeSet<_>>());
}

#[test]
fn the_workgroup_size_is_the_one_the_host_dispatches_with() {
    for k in ALL {
        assert_eq!(local_size(&load_kernel(k)), k.local_size, "{}: local_size", k.name);
    }
    // The sweep's dispatch grid divides by this.
    assert_eq!([LOCAL_SIZE[0], LOCAL_SIZE[1], 1], kernels::PROPAGATE.local_size);
}

#[test]
fn flag_bits_are_the_rust_ones() {
    let mut glsl = HashMap::new();
    for line in COMMON_GLSL.lines() {
        let Some(rest) = line.trim().strip_prefix("const uint FLAG_") else { continue };
        let (name, value) = rest.split_once('=').expect("const uint FLAG_X = Nu;");
        let value = value.split(';').next().unwrap_or("").trim().trim_end_matches('u');
        glsl.insert(format!("FLAG_{}", name.trim()), value.parse::<u32>().expect("a decimal flag value"));
    }
    let rust = HashMap::from([
        ("FLAG_BOUNDARY".to_string(), layout::FLAG_BOUNDARY),
        ("FLAG_GAIN".to_string(), layout::FLAG_GAIN),
        ("FLAG_EMIT".to_string(), layout::FLAG_EMIT),
        ("FLAG_EXITS".to_string(), layout::FLAG_EXITS),
        ("FLAG_VACUUM".to_string(), layout::FLAG_VACUUM),
        ("FLAG_HALF_SOURCE".to_string(), layout::FLAG_HALF_SOURCE),
        ("FLAG_CARRY".to_string(), layout::FLAG_CARRY),
        ("FLAG_LATERAL_MAJOR".to_string(), layout::FLAG_LATERAL_MAJOR),
    ]);
    assert_eq!(glsl, rust, "FLAG_* in glsl/common.glsl vs src/solver/gpu/layout.rs");
    // The f16 scale exponent lives above every flag bit.
    assert!(rust.values().all(|&f| f < 1 << layout::HALF_SCALE_SHIFT));
}

#[test]
fn glsl_segment_functions_match_the_rust_ones() {
    use lpm::solver::segment::{e1, e2};
    let ctx = Context::new(ContextOptions { validation: true, ..ContextOptions::default() }).expect("Vulkan");
    // Log-spaced optical depths over [1e-8, 1e4], and both sides of the series switch at x = 1.
    let n = 2048usize;
    let mut xs: Vec<f32> = (0..n - 2).map(|i| (1e-8f64 * 1e12f64.powf(i as f64 / (n - 3) as f64)) as f32).collect();
    xs.extend([1.0f32 - f32::EPSILON, 1.0]);
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let mut input = ctx.create_host_buffer("depths", 4 * n as u64, usage, MemoryLocation::CpuToGpu).unwrap();
    input.bytes_mut().copy_from_slice(bytemuck::cast_slice(&xs));
    let output = ctx.create_host_buffer("values", 8 * n as u64, usage, MemoryLocation::GpuToCpu).unwrap();
    let k = kernels::SEGMENT_TEST;
    let pipeline = ctx.create_compute_pipeline(k.name, k.spirv, k.layout_bindings, k.push.size as u32).unwrap();
    let timeline = ctx.create_timeline("segment test", 0).unwrap();
    let push = SweepPush { na: n as u32, ..SweepPush::default() };
    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "segment test").unwrap();
    let buffers = [BufferRange::from(&*input), BufferRange::from(&*output)];
    rec.dispatch(&pipeline, &buffers, bytemuck::bytes_of(&push), [(n as u32).div_ceil(64), 1, 1]).unwrap();
    rec.compute_to_host();
    rec.submit(ctx.compute_queue(), &[], (&timeline, 1)).unwrap();
    timeline.wait(&ctx, 1, 60_000_000_000).unwrap();
    let values: &[f32] = bytemuck::cast_slice(output.bytes());
    let mut worst = (0.0f64, 0.0f32);
    for (i, &x) in xs.iter().enumerate() {
        let (g1, g2) = (values[2 * i] as f64, values[2 * i + 1] as f64);
        let (r1, r2) = (e1(x as f64), e2(x as f64));
        for (g, r) in [(g1, r1), (g2, r2)] {
            let rel = (g - r).abs() / r.abs();
            if rel > worst.0 {
                worst = (rel, x);
            }
        }
    }
    // f32 arithmetic: a few ulps (2^-23 ≈ 1.2e-7) of the f64 values.
    assert!(worst.0 < 2e-6, "largest relative difference {:e} at x = {:e}", worst.0, worst.1);
    // SAFETY: the timeline wait above: the only submission using them has completed.
    unsafe {
        ctx.destroy_timeline(timeline);
        ctx.destroy_pipeline(pipeline);
        ctx.destroy_host_buffer(input);
        ctx.destroy_host_buffer(output);
    }
    let messages = ctx.validation_messages();
    assert!(messages.is_empty(), "validation errors:\n{}", messages.join("\n"));
}
