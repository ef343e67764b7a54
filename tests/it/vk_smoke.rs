//! Smoke tests of the Vulkan layer on whatever device the loader offers (lavapipe in CI), always
//! with validation and synchronization validation on, asserting no validation error was reported.

use std::sync::Arc;

use lpm::solver::gpu::kernels;
use lpm::vk::{vk, BufferRange, Context, ContextOptions, MemoryLocation, Recorder, VkError};

const FILL_SPV: &[u8] = kernels::FILL.spirv;
const SECOND: u64 = 1_000_000_000;
/// fill.comp's workgroup.
const FILL_GROUP: u32 = kernels::FILL.local_size[0];

fn context() -> Arc<Context> {
    let _ = tracing_subscriber::fmt().with_test_writer().with_env_filter("lpm=info").try_init();
    let opts = ContextOptions { validation: true, device_index: None, force_single_queue: false };
    match Context::new(opts) {
        Ok(ctx) => {
            eprintln!("device: {} — {}", ctx.device_name(), ctx.driver_description());
            ctx
        }
        Err(e) => panic!("creating the Vulkan context: {e}"),
    }
}

/// fill.comp's push-constant block: { uint count; uint value; }.
fn fill_push(count: u32, value: u32) -> [u8; 8] {
    let mut b = [0u8; 8];
    b[..4].copy_from_slice(&count.to_le_bytes());
    b[4..].copy_from_slice(&value.to_le_bytes());
    b
}

fn assert_clean(ctx: &Context) {
    let msgs = ctx.validation_messages();
    assert!(msgs.is_empty(), "validation errors:\n{}", msgs.join("\n"));
}

#[test]
fn fill_copy_readback() -> Result<(), VkError> {
    let ctx = context();
    let limits = ctx.limits();
    assert!(limits.subgroup_size > 0);
    let pipeline = ctx.create_compute_pipeline("fill", FILL_SPV, 1, 8)?;

    // The buffer is larger than `count` so the shader's bounds guard is exercised: the tail must
    // keep the value the transfer fill put there.
    let count: u32 = 1000;
    let len: u64 = 1024;
    let bytes = len * 4;
    let data = ctx.create_buffer(
        "smoke.data",
        bytes,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuOnly,
    )?;
    assert!(data.mapped().is_none(), "GpuOnly buffers must never be mapped");
    let readback =
        ctx.create_buffer("smoke.readback", bytes, vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu)?;
    assert!(ctx.allocated_bytes() >= 2 * bytes);
    let timeline = ctx.create_timeline("smoke", 0)?;

    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "smoke")?;
    rec.fill_buffer(&data, 0, vk::WHOLE_SIZE, 0xDEAD_BEEF);
    rec.transfer_to_compute();
    rec.dispatch(
        &pipeline,
        &[BufferRange::from(&data)],
        &fill_push(count, 0x00C0_FFEE),
        [count.div_ceil(FILL_GROUP), 1, 1],
    )?;
    rec.compute_to_transfer();
    rec.copy_buffer(&data, &readback, &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: bytes }]);
    rec.transfer_to_host();
    rec.submit(ctx.compute_queue(), &[], (&timeline, 1))?;
    timeline.wait(&ctx, 1, 10 * SECOND)?;
    assert_eq!(timeline.value(&ctx)?, 1);

    let mapped = readback.mapped().expect("GpuToCpu buffers are mapped");
    let words: Vec<u32> = mapped.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    assert_eq!(words.len(), len as usize);
    for (i, &w) in words.iter().enumerate() {
        let want = if i < count as usize { 0x00C0_FFEE } else { 0xDEAD_BEEF };
        assert_eq!(w, want, "word {i}");
    }

    ctx.retire_buffer(data, &timeline, 1);
    ctx.retire_buffer(readback, &timeline, 1);
    ctx.collect_garbage()?;
    assert_eq!(ctx.pending_garbage(), 0, "everything retired on value 1 must be freed once it is reached");
    assert_eq!(ctx.allocated_bytes(), 0);
    assert!(ctx.peak_allocated_bytes() >= 2 * bytes);
    // SAFETY: the wait for value 1 above: the one submission using them has completed.
    unsafe {
        ctx.destroy_pipeline(pipeline);
        ctx.destroy_timeline(timeline);
    }
    assert_clean(&ctx);
    Ok(())
}

#[test]
fn binding_larger_than_max_storage_range_is_refused() -> Result<(), VkError> {
    let ctx = context();
    let limits = ctx.limits();
    let pipeline = ctx.create_compute_pipeline("fill", FILL_SPV, 1, 8)?;
    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "limits")?;

    // A real buffer just over the limit, bound whole (only where that is a modest allocation).
    if limits.max_storage_buffer_range <= 512 << 20 {
        let big = ctx.create_buffer(
            "limits.big",
            limits.max_storage_buffer_range + 4,
            vk::BufferUsageFlags::STORAGE_BUFFER,
            MemoryLocation::GpuOnly,
        )?;
        let r = rec.dispatch(&pipeline, &[BufferRange::from(&big)], &fill_push(1, 1), [1, 1, 1]);
        assert!(matches!(r, Err(VkError::LimitExceeded(_))), "got {r:?}");
        if let Err(e) = r {
            eprintln!("{e}");
        }
        // SAFETY: the dispatch was refused: nothing was recorded or submitted with it.
        unsafe { ctx.destroy_buffer(big) };
    }
    // An explicit range over the limit is refused before the bounds check.
    let small =
        ctx.create_buffer("limits.small", 256, vk::BufferUsageFlags::STORAGE_BUFFER, MemoryLocation::GpuOnly)?;
    let over = BufferRange::new(&small, 0, limits.max_storage_buffer_range + 4);
    let r = rec.dispatch(&pipeline, &[over], &fill_push(1, 1), [1, 1, 1]);
    assert!(matches!(r, Err(VkError::LimitExceeded(_))), "got {r:?}");
    // Too many workgroups.
    let groups = [limits.max_workgroup_count[0].saturating_add(1), 1, 1];
    if groups[0] > limits.max_workgroup_count[0] {
        let r = rec.dispatch(&pipeline, &[BufferRange::from(&small)], &fill_push(1, 1), groups);
        assert!(matches!(r, Err(VkError::LimitExceeded(_))), "got {r:?}");
    }
    // Shape mismatches are plain invalid requests.
    let r = rec.dispatch(&pipeline, &[], &fill_push(1, 1), [1, 1, 1]);
    assert!(matches!(r, Err(VkError::InvalidArgument(_))), "got {r:?}");
    let r = rec.dispatch(&pipeline, &[BufferRange::new(&small, 0, 512)], &fill_push(1, 1), [1, 1, 1]);
    assert!(matches!(r, Err(VkError::InvalidArgument(_))), "got {r:?}");
    let r = ctx.create_compute_pipeline("bad", &FILL_SPV[4..], 1, 8);
    assert!(matches!(r, Err(VkError::InvalidArgument(_))));

    // Never submitted: dropping the recorder frees its pools at once.
    drop(rec);
    // SAFETY: the recorder that used them was never submitted.
    unsafe {
        ctx.destroy_buffer(small);
        ctx.destroy_pipeline(pipeline);
    }
    assert_eq!(ctx.allocated_bytes(), 0);
    assert_clean(&ctx);
    Ok(())
}

/// Submission 1 writes with compute and signals 1; submission 2 waits for 1 (no barrier between
/// them: the semaphore wait is the dependency), copies to a readback buffer and signals 2. Sync
/// validation checks that the wait alone orders the hazard. On devices with a separate transfer
/// queue the second submission goes there.
#[test]
fn two_submissions_ordered_by_timeline() -> Result<(), VkError> {
    let ctx = context();
    let pipeline = ctx.create_compute_pipeline("fill", FILL_SPV, 1, 8)?;
    let count: u32 = 4096;
    let bytes = u64::from(count) * 4;
    let data = ctx.create_buffer(
        "order.data",
        bytes,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC,
        MemoryLocation::GpuOnly,
    )?;
    let readback =
        ctx.create_buffer("order.readback", bytes, vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu)?;
    let timeline = ctx.create_timeline("order", 0)?;

    let compute = ctx.compute_queue();
    let mut first = Recorder::begin(&ctx, compute.family(), "order.write")?;
    first.dispatch(&pipeline, &[BufferRange::from(&data)], &fill_push(count, 7), [count.div_ceil(FILL_GROUP), 1, 1])?;
    first.submit(compute, &[], (&timeline, 1))?;

    let copy_queue = ctx.transfer_queue().unwrap_or(compute);
    let mut second = Recorder::begin(&ctx, copy_queue.family(), "order.copy")?;
    second.copy_buffer(&data, &readback, &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: bytes }]);
    second.transfer_to_host();
    second.submit(copy_queue, &[(&timeline, 1, vk::PipelineStageFlags2::ALL_TRANSFER)], (&timeline, 2))?;

    timeline.wait(&ctx, 2, 10 * SECOND)?;
    let mapped = readback.mapped().expect("mapped");
    assert!(mapped.chunks_exact(4).all(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) == 7));

    ctx.retire_buffer(data, &timeline, 1);
    ctx.retire_buffer(readback, &timeline, 2);
    ctx.collect_garbage()?;
    assert_eq!(ctx.pending_garbage(), 0);
    // SAFETY: the wait for value 2 above: both submissions using them have completed.
    unsafe {
        ctx.destroy_pipeline(pipeline);
        ctx.destroy_timeline(timeline);
    }
    assert_clean(&ctx);
    Ok(())
}

/// GPU work waiting on a value the host signals later (wait-before-signal), and retired resources
/// that are only freed once the value is reached.
#[test]
fn host_signal_releases_gpu_work_and_garbage() -> Result<(), VkError> {
    let ctx = context();
    let timeline = ctx.create_timeline("host", 0)?;
    let buf = ctx.create_buffer("host.buf", 1024, vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu)?;
    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "host.fill")?;
    rec.fill_buffer(&buf, 0, 1024, 0x0101_0101);
    rec.transfer_to_host();
    rec.submit(ctx.compute_queue(), &[(&timeline, 1, vk::PipelineStageFlags2::ALL_TRANSFER)], (&timeline, 2))?;
    ctx.retire_buffer(buf, &timeline, 2);
    ctx.collect_garbage()?;
    // Not reached yet: the recorder's pools and the buffer are still pending.
    assert_eq!(ctx.pending_garbage(), 2);
    assert!(matches!(timeline.wait(&ctx, 2, 1_000_000), Err(VkError::Timeout { .. })));
    timeline.signal(&ctx, 1)?;
    timeline.wait(&ctx, 2, 10 * SECOND)?;
    ctx.collect_garbage()?;
    assert_eq!(ctx.pending_garbage(), 0);
    assert_eq!(ctx.allocated_bytes(), 0);
    // SAFETY: the wait for value 2 above: the one submission waiting on and signalling it is done.
    unsafe { ctx.destroy_timeline(timeline) };
    assert_clean(&ctx);
    Ok(())
}

#[test]
fn timestamps() -> Result<(), VkError> {
    let ctx = context();
    if !ctx.limits().timestamps_supported {
        eprintln!("device has no compute timestamps; nothing to check");
        return Ok(());
    }
    let pool = ctx.create_timestamp_pool("ts", 2)?;
    let pipeline = ctx.create_compute_pipeline("fill", FILL_SPV, 1, 8)?;
    let buf = ctx.create_buffer("ts.buf", 1 << 20, vk::BufferUsageFlags::STORAGE_BUFFER, MemoryLocation::GpuOnly)?;
    let timeline = ctx.create_timeline("ts", 0)?;
    // Twice over the same queries: the pool is reset from the host when made and after each read
    // (no vkCmdResetQueryPool, which a transfer-only queue may not record); the validation layer
    // fails a timestamp written into a query that was not reset since its last use.
    for round in 1..=2u64 {
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "ts")?;
        rec.write_timestamp(&pool, 0, vk::PipelineStageFlags2::TOP_OF_PIPE);
        rec.dispatch(&pipeline, &[BufferRange::from(&buf)], &fill_push(1 << 18, 3), [(1 << 18) / FILL_GROUP, 1, 1])?;
        rec.write_timestamp(&pool, 1, vk::PipelineStageFlags2::COMPUTE_SHADER);
        rec.submit(ctx.compute_queue(), &[], (&timeline, round))?;
        timeline.wait(&ctx, round, 10 * SECOND)?;
        let t = pool.read(&ctx, 0, 2)?;
        assert!(t[1] >= t[0], "timestamps go backwards: {t:?}");
        eprintln!("fill of 1 MiB: {:.3} ms", (t[1] - t[0]) as f64 * f64::from(ctx.limits().timestamp_period_ns) * 1e-6);
        // SAFETY: the submission that wrote them has completed (waited for above).
        unsafe { pool.reset(&ctx, 0, 2) };
    }
    ctx.retire_buffer(buf, &timeline, 2);
    ctx.collect_garbage()?;
    // SAFETY: the wait for value 2 above: the submissions using them have completed.
    unsafe {
        ctx.destroy_timestamp_pool(pool);
        ctx.destroy_pipeline(pipeline);
        ctx.destroy_timeline(timeline);
    }
    assert_clean(&ctx);
    Ok(())
}

#[test]
fn bad_device_index_is_a_clear_error() {
    let opts = ContextOptions { validation: true, device_index: Some(999), force_single_queue: true };
    match Context::new(opts) {
        Err(VkError::NoDevice(msg)) => assert!(msg.contains("LPM_DEVICE=999"), "{msg}"),
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("device 999 should not exist"),
    }
}
