//! The device memory budget: any cut of the sweeps (slices in flight, directions per pass, sub-slices
//! of fewer planes, directions and planes per dispatch) gives bitwise the same fluence and source,
//! and a budget below the smallest unit is a clear error. (Resident against streamed: `resident.rs`.)
use crate::common::*;
use lpm::scene::{Scene, Shape};
use lpm::solver::BackendKind::Gpu;
use lpm::solver::SolveError;

fn cloud() -> Scene {
    cloud_of([34, 30, 38])
}

/// The cloud on 2×2×2 bricks, 6 of them occupied: still two occupied slices along every axis,
/// for the tests that solve it many times over.
fn small_cloud() -> Scene {
    cloud_of([24, 22, 26])
}

fn cloud_of(dims: [u32; 3]) -> Scene {
    let mut s =
        scene(Shape::Cloud, dims, [0.9, 0.7, 0.5], [0.9, 0.8, 0.7], vec![sky(0.5), sun([0.4, -0.3, 1.0], [2.0; 3])]);
    s.medium.g = 0.5;
    s.solver.directions_per_face = 3;
    s.solver.storage_directions_per_face = Some(2);
    s.solver.max_orders = 3;
    s
}

fn bits(solved: &Solved) -> (Vec<u32>, Vec<u32>) {
    (
        solved.fields.fluence_total.as_slice().iter().map(|v| v.to_bits()).collect(),
        solved.fields.source_total.as_slice().iter().map(|v| v.to_bits()).collect(),
    )
}

#[test]
fn any_budget_gives_bitwise_the_same_fluence_and_source() {
    let mut base = small_cloud();
    let resident = solve("budget-resident", &base, Gpu);
    assert!(resident.run.memory.expect("memory plan").is_resident());
    // The cuts below are the streamed mode's.
    base.solver.device_residency = lpm::scene::DeviceResidency::Streamed;
    let reference = solve("budget-large", &base, Gpu);
    assert!(bits(&reference) == bits(&resident), "resident and streamed differ");
    let full = reference.run.memory.expect("memory plan");
    assert!(!full.is_resident());
    assert_eq!(full.directions_per_pass, 9, "{full:?}");
    assert_eq!(full.planes_per_dispatch, 16, "{full:?}");
    assert_eq!(full.planes_per_slice, 16, "{full:?}");

    let needed = smallest_unit(&base);
    let mut cuts = Vec::new();
    // The smallest unit, a budget that still holds every direction but not a whole slice in each
    // of two slots (sub-slices), and one between those two.
    let sub_slices = full.planned_bytes - full.slice_bytes / 2;
    for budget in [needed, sub_slices, (needed + sub_slices) / 2] {
        let mut s = base.clone();
        s.solver.device_memory_budget = Some(budget);
        let solved = solve(&format!("budget-{budget}"), &s, Gpu);
        let m = solved.run.memory.expect("memory plan");
        assert!(m.planned_bytes <= budget, "{m:?}");
        assert!(solved.run.peak_device_bytes <= budget, "peak {} over budget {budget}", solved.run.peak_device_bytes);
        assert!(bits(&solved) == bits(&reference), "budget {budget} ({m:?}) changed the result");
        // The power through each face, summed pass by pass (so in another order of f64 sums).
        let (e, r) = (&solved.run.outcome.energy, &reference.run.outcome.energy);
        for (f, g) in e.faces.iter().zip(&r.faces) {
            for (a, b) in [(f.power_in[0], g.power_in[0]), (f.power_out[0], g.power_out[0])] {
                assert!((a - b).abs() <= 1e-9 * r.boundary_in[0], "{}: {a} vs {b} (budget {budget})", f.face);
            }
        }
        eprintln!("budget {budget}: {m:?}");
        cuts.push((
            m.slices_in_flight,
            m.directions_per_pass,
            m.planes_per_slice,
            m.directions_per_dispatch,
            m.planes_per_dispatch,
        ));
    }
    // The smallest budget: one slice at a time, one direction per pass, sub-slices of one plane.
    assert_eq!(full.slices_in_flight, 2);
    assert_eq!(cuts[0], (1, 1, 1, 1, 1));
    // Every direction in one pass, but one slot or sub-slices: which, the cost model decides by
    // the device's figures (a CPU device keeps two slots of sub-slices, a GPU one whole slice).
    assert!(cuts[1].1 == 9 && (cuts[1].0 < 2 || cuts[1].2 < 16), "{:?}", cuts[1]);
    assert_ne!(cuts[2], (2, 9, 16, 9, 16), "the middle budget should cut the sweeps too");
}

#[test]
fn pipelined_and_serial_schedules_agree_bitwise() {
    // Two slices in flight: transfers are a second submission stream (a dedicated transfer queue
    // where the device has one, else the compute queue), ordered only by timeline semaphores.
    // One slice in flight: each slice completes before the next. Same answer, bit for bit.
    let scene = small_cloud();
    let dir = temp_dir("schedule");
    let store = lpm::solver::build_store(&scene, &dir.join("store")).unwrap();
    let run = |slots: u32| {
        let options = lpm::solver::gpu::GpuOptions { max_slices_in_flight: slots, ..Default::default() };
        let (run, fields) =
            lpm::solver::solve_with(&scene, &store, Gpu, validated(), options, false, |_, _| {}).unwrap();
        assert_eq!(run.memory.unwrap().slices_in_flight, slots);
        (fields.fluence_total.as_slice().to_vec(), fields.source_total.as_slice().to_vec())
    };
    let (pipelined, serial) = (run(2), run(1));
    assert!(pipelined.0.iter().zip(&serial.0).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(pipelined.1.iter().zip(&serial.1).all(|(a, b)| a.to_bits() == b.to_bits()));
}

#[test]
fn a_budget_below_the_smallest_unit_says_how_much_is_needed() {
    let scene = cloud();
    let needed = smallest_unit(&scene);
    let err = SolveError::BudgetTooSmall { budget: 1000, needed };
    let text = err.to_string();
    assert!(text.contains(&needed.to_string()) && text.contains("--device-memory-budget"), "{text}");
    assert!(needed > 4096);
}

/// The planner's figure is what the driver allocates: every buffer the backend makes (and the
/// largest staging its tables came through) adds up to `planned_bytes`, for plans cut every way
/// (two slots and one, all directions per pass and fewer, whole slices and sub-slices, f32 and
/// f16 sources).
#[test]
fn the_planned_bytes_are_the_bytes_allocated() {
    use lpm::solver::fields::StoreFields;
    use lpm::solver::gpu::{GpuBackend, GpuOptions};
    use lpm::solver::plan::{Plan, Precision};
    let mut half = cloud();
    half.solver.storage_precision = lpm::scene::StoragePrecision::F16;
    let ctx = lpm::vk::Context::new(validated()).unwrap();
    for (name, scene) in [("f32", cloud()), ("f16", half)] {
        let dir = temp_dir(&format!("budget-bytes-{name}"));
        let store = lpm::solver::build_store(&scene, &dir.join("store")).unwrap();
        let total = store.grid().brick_count();
        let plan = Plan::new(&scene, total, total - store.occupied_count());
        let precision = if name == "f16" { Precision::F16 } else { Precision::F32 };
        assert_eq!(plan.source_precision, precision);
        let needed = smallest_unit(&scene);
        let mut plans = Vec::new();
        for (budget, slots) in
            [(None, 2), (None, 1), (Some(needed), 2), (Some(needed * 3 / 2), 2), (Some(needed * 4), 1)]
        {
            let mut fields = StoreFields::create(&store, &plan).unwrap();
            let options = GpuOptions { budget, max_slices_in_flight: slots, ..GpuOptions::default() };
            let gpu = GpuBackend::new(ctx.clone(), &plan, &store, &mut fields, options).unwrap();
            let memory = gpu.memory_plan();
            assert_eq!(gpu.buffer_bytes(), memory.planned_bytes, "{name}: {memory:?}");
            plans.push((memory.slices_in_flight, memory.directions_per_pass, memory.planes_per_slice));
        }
        // The cases cover different cuts.
        plans.sort();
        plans.dedup();
        assert!(plans.len() >= 3, "{name}: {plans:?}");
    }
}

/// The host memory budget only decides whether the store's pages stay resident between passes
/// (`store::resident`): a store kept resident and one whose pages are handed back after every pass
/// give the same bits, and the run says which it did.
#[test]
fn keeping_the_store_resident_or_not_gives_the_same_bits() {
    let mut kept = small_cloud();
    kept.solver.host_memory_budget = Some(1 << 40);
    let mut released = small_cloud();
    released.solver.host_memory_budget = Some(1);
    let (a, b) = (solve("host-kept", &kept, Gpu), solve("host-released", &released, Gpu));
    assert!(a.run.residency.kept_resident && a.run.residency.budget_origin == "solver.host_memory_budget");
    assert!(!b.run.residency.kept_resident);
    assert!(a.run.residency.store_bytes > 0 && a.run.residency.store_bytes == b.run.residency.store_bytes);
    assert!(bits(&a) == bits(&b), "resident and released stores solved differently");
}

/// A face swept in several passes through two slots: each later pass's first slice is gathered
/// while the pass before ends (the stream counts them), and the answer is bitwise the one-pass
/// answer.
#[test]
fn later_passes_start_from_a_slice_gathered_while_the_pass_before_ended() {
    use lpm::solver::fields::StoreFields;
    use lpm::solver::gpu::cost::{self, Cut, DeviceFigures};
    use lpm::solver::gpu::{budget, GpuBackend, GpuOptions};
    use lpm::solver::orders::Backend;
    use lpm::solver::plan::Plan;
    // The full cloud: on `small_cloud` the first budget that splits a face's directions also cuts
    // sub-slices of 2 planes (measured), which this count of whole slices does not cover.
    let mut scene = cloud();
    scene.solver.device_residency = lpm::scene::DeviceResidency::Streamed;
    // Directions enough that the ray state, not the slots, is what a smaller budget cuts first.
    scene.solver.directions_per_face = 6;
    scene.solver.max_orders = 2;
    let dir = temp_dir("pregather");
    let store = lpm::solver::build_store(&scene, &dir.join("store")).unwrap();
    let total = store.grid().brick_count();
    let plan = Plan::new(&scene, total, total - store.occupied_count());
    let ctx = lpm::vk::Context::new(validated()).unwrap();
    // A device whose bus takes half as long as its kernels for one pass of every direction, with
    // no overheads: a second slot hides the bus, and a second pass hides behind the kernels too.
    let per_face = plan.propagation.per_face() as u32;
    let whole = Cut { resident: false, slots: 1, pass: per_face, slab: 16, group: per_face, planes: 16 };
    let only = |bus, device| DeviceFigures {
        bus_bytes_per_second: bus,
        device_bytes_per_second: device,
        submission_seconds: 0.0,
        dispatch_seconds: 0.0,
        cache_bytes: 0.0,
        cache_bytes_per_second: 1.0,
    };
    let bus_bytes = cost::order_seconds(&plan, store.occupied_count() as u64, whole, &only(1.0, 1e30));
    let kernel_bytes = cost::order_seconds(&plan, store.occupied_count() as u64, whole, &only(1e30, 1.0));
    let figures = only(2e6 * bus_bytes / kernel_bytes, 1e6);
    // The largest budget whose plan has fewer directions per pass than a face has.
    let extent = budget::slice_extent(&plan, &store);
    let plan_for = |bytes| budget::plan_memory(&plan, extent, &ctx.limits(), bytes, 2, false, &figures);
    let mut bytes = plan_for(u64::MAX / 4).unwrap().planned_bytes;
    let memory = loop {
        bytes -= bytes / 50;
        let m = plan_for(bytes).expect("a plan on the way down");
        if m.directions_per_pass < per_face {
            break m;
        }
    };
    let cut = |m: budget::MemoryPlan| (m.slices_in_flight, m.directions_per_pass, m.planes_per_slice);
    assert_eq!(memory.slices_in_flight, 2, "{memory:?}");
    let options =
        GpuOptions { budget: Some(bytes), resident: false, cost_figures: Some(figures), ..GpuOptions::default() };
    let mut fields = StoreFields::create(&store, &plan).unwrap();
    let mut gpu =
        GpuBackend::new(ctx.clone(), &plan, &store, &mut fields, GpuOptions { profile: true, ..options }).unwrap();
    assert_eq!(cut(gpu.memory_plan()), cut(memory));
    gpu.propagate_order(0).unwrap();
    let stats = gpu.stream_stats().unwrap();
    // Every face's later passes (its first slice is no longer in flight when a pass ends).
    let passes = per_face.div_ceil(memory.directions_per_pass) as u64;
    assert_eq!(stats.pregathered_slices, 6 * (passes - 1), "{memory:?}");
    drop(gpu);

    let solve_with = |options| {
        let (run, fields) =
            lpm::solver::solve_with(&scene, &store, Gpu, validated(), options, false, |_, _| {}).unwrap();
        (run.memory.unwrap(), fields.fluence_total.as_slice().to_vec(), fields.source_total.as_slice().to_vec())
    };
    let (in_passes, whole) = (solve_with(options), solve_with(GpuOptions { resident: false, ..GpuOptions::default() }));
    assert_eq!(cut(in_passes.0), cut(memory));
    assert!(whole.0.directions_per_pass == per_face);
    let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    assert!(same(&in_passes.1, &whole.1) && same(&in_passes.2, &whole.2), "pregathered passes changed the answer");
}

/// The memory planner keeps, of the cuts that fit, the quickest by the cost model: as the budget
/// shrinks its estimate never falls (the cuts that fit only get fewer), the plan never exceeds the
/// budget, and the first cut below the whole plan keeps two slots, every direction in one pass and
/// whole slices, and takes fewer directions or planes per dispatch instead. Where the device's
/// cache can hold a dispatch's deposit, the dispatches are sized to fit it.
/// In a streamed pass of whole slices, every occupied slice after the pass's first is gathered on
/// the copy workers while the slices before it compute, not on the submitting thread at its
/// turn, with one slot or two; the bits are those of the resident solve
/// (`any_budget_gives_bitwise_the_same_fluence_and_source`, `pipelined_and_serial_schedules_agree_bitwise`
/// run the same schedule).
#[test]
fn streamed_slices_are_gathered_while_the_slices_before_them_compute() {
    use lpm::solver::fields::StoreFields;
    use lpm::solver::gpu::{GpuBackend, GpuOptions};
    use lpm::solver::orders::Backend;
    use lpm::solver::plan::Plan;
    let mut scene = cloud();
    scene.solver.device_residency = lpm::scene::DeviceResidency::Streamed;
    // The sky alone: a sun adds its beam's sweep to order 0, one more pass to count.
    scene.lights.truncate(1);
    let dir = temp_dir("gather-ahead");
    let store = lpm::solver::build_store(&scene, &dir.join("store")).unwrap();
    let total = store.grid().brick_count();
    let plan = Plan::new(&scene, total, total - store.occupied_count());
    let ctx = lpm::vk::Context::new(validated()).unwrap();
    // Slices along each axis that hold an occupied brick.
    let grid = *store.grid();
    let occupied_slices = |axis: usize| {
        (0..grid.bricks[axis])
            .filter(|&k| (0..total).any(|b| grid.brick_coords(b)[axis] == k && store.slot(b).is_some()))
            .count() as u64
    };
    for slots in [1, 2] {
        let options =
            GpuOptions { resident: false, profile: true, max_slices_in_flight: slots, ..GpuOptions::default() };
        let mut fields = StoreFields::create(&store, &plan).unwrap();
        let mut gpu = GpuBackend::new(ctx.clone(), &plan, &store, &mut fields, options).unwrap();
        let memory = gpu.memory_plan();
        assert_eq!((memory.slices_in_flight, memory.planes_per_slice), (slots, 16), "{memory:?}");
        gpu.propagate_order(0).unwrap();
        let stats = gpu.stream_stats().unwrap();
        let passes = (plan.propagation.per_face() as u32).div_ceil(memory.directions_per_pass) as u64;
        let expected: u64 = (0..3).map(|axis| 2 * passes * (occupied_slices(axis) - 1)).sum();
        assert!(expected > 0);
        assert_eq!(stats.gathered_ahead_slices, expected, "{slots} slot(s): {memory:?}");
    }
}

#[test]
fn the_planner_keeps_the_quickest_cut_that_fits() {
    use lpm::solver::gpu::budget;
    use lpm::solver::gpu::cost::{self, Cut, DeviceFigures};
    use lpm::solver::plan::Plan;
    let mut scene = cloud();
    scene.solver.directions_per_face = 5;
    let dir = temp_dir("planner-cost");
    let store = lpm::solver::build_store(&scene, &dir.join("store")).unwrap();
    let total = store.grid().brick_count();
    let plan = Plan::new(&scene, total, total - store.occupied_count());
    let ctx = lpm::vk::Context::new(validated()).unwrap();
    let extent = budget::slice_extent(&plan, &store);
    let per_face = plan.propagation.per_face() as u32;
    for cpu in [true, false] {
        // The typical figures of a CPU device and of a GPU.
        let mut limits = ctx.limits();
        limits.is_cpu = cpu;
        let figures = DeviceFigures::for_device(&limits);
        let plan_for = |bytes| budget::plan_memory(&plan, extent, &limits, bytes, 2, false, &figures);
        let whole = plan_for(u64::MAX / 4).unwrap();
        let full_cut = (2, per_face, 16, per_face, 16);
        let cut = |m: &budget::MemoryPlan| {
            (
                m.slices_in_flight,
                m.directions_per_pass,
                m.planes_per_slice,
                m.directions_per_dispatch,
                m.planes_per_dispatch,
            )
        };
        assert_eq!(cut(&whole), full_cut);
        let mut bytes = whole.planned_bytes;
        let mut last = whole;
        let mut first_cut = None;
        let mut cuts = 0;
        while let Ok(m) = plan_for(bytes) {
            assert!(m.planned_bytes <= bytes, "{m:?}");
            assert!(m.estimated_order_seconds >= last.estimated_order_seconds, "{m:?} after {last:?}");
            if cut(&m) != cut(&last) {
                cuts += 1;
                first_cut.get_or_insert(cut(&m));
            }
            last = m;
            bytes -= bytes / 50;
        }
        assert_eq!(cut(&last), (1, 1, 1, 1, 1), "the smallest budget's plan");
        let (slots, pass, slab, group, planes) = first_cut.unwrap();
        assert!(
            (slots, pass, slab) == (2, per_face, 16) && (group < per_face || planes < 16),
            "cpu {cpu}: the first cut below the whole plan: {:?}",
            first_cut
        );
        assert!(cuts >= 10, "cpu {cpu}: {cuts} different cuts");
    }
    // A device whose kernels are the cost, whose cache holds half of a whole face's deposit and
    // whose dispatches cost nothing of their own: with every byte to spare, the plan sizes its
    // dispatches so that the deposit stays in the cache between the two kernels.
    let mut limits = ctx.limits();
    limits.is_cpu = false;
    let typical = DeviceFigures::for_device(&limits);
    let whole = budget::plan_memory(&plan, extent, &limits, u64::MAX / 4, 2, false, &typical).unwrap();
    let cached = DeviceFigures {
        cache_bytes: whole.deposit_bytes as f64,
        device_bytes_per_second: 1e9,
        cache_bytes_per_second: 1e11,
        submission_seconds: 0.0,
        dispatch_seconds: 0.0,
        ..typical
    };
    let m = budget::plan_memory(&plan, extent, &limits, u64::MAX / 4, 2, false, &cached).unwrap();
    assert!(m.deposit_bytes * 2 <= whole.deposit_bytes, "{m:?}");
    assert!((m.slices_in_flight, m.directions_per_pass, m.planes_per_slice) == (2, per_face, 16), "{m:?}");
    let full = Cut { resident: false, slots: 2, pass: per_face, slab: 16, group: per_face, planes: 16 };
    let occupied = store.occupied_count() as u64;
    assert!(m.estimated_order_seconds < cost::order_seconds(&plan, occupied, full, &cached), "{m:?}");
}
