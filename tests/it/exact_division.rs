//! The end-of-order kernels' f64 division (`div_rn` in glsl/exact.glsl) gives the host's correctly
//! rounded quotient bit for bit, whatever the device's own f64 division does: Vulkan does not
//! promise a correctly rounded one, and the resident mode's answer is bitwise the streamed mode's
//! only if it is. Started from the device's quotient and from quotients spoiled on purpose (up to
//! a relative 2^-20 off, as a loose division would give), every result must equal the host's.

use lpm::solver::gpu::kernels::{DivisionTestPush, DIVISION_TEST};
use lpm::vk::{vk, BufferRange, Context, ContextOptions, MemoryLocation, Recorder};

/// splitmix64: a fixed sequence, so a failure is reproducible.
struct Sequence(u64);

impl Sequence {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// A positive or negative f64 with a random significand and an exponent in [-lo, lo).
    fn value(&mut self, lo: i32) -> f64 {
        let bits = self.next();
        let significand = 1.0 + (bits >> 12) as f64 / (1u64 << 52) as f64;
        let exponent = (bits % (2 * lo as u64)) as i32 - lo;
        let sign = if bits & (1 << 11) != 0 { -1.0 } else { 1.0 };
        sign * significand * 2f64.powi(exponent)
    }
}

#[test]
fn the_kernels_division_is_the_hosts_to_the_bit() {
    let ctx = Context::new(ContextOptions { validation: true, ..ContextOptions::default() }).expect("Vulkan");
    if !ctx.limits().float64 {
        eprintln!("the device has no f64 shaders: its end-of-order passes run on the host; nothing to check");
        return;
    }
    let mut seq = Sequence(33);
    // (a, b, q0): quotients of every size, started exact, a few ulps off, and far off.
    let spoil = [0.0, 1e-16, -3e-16, 2f64.powi(-30), -(2f64.powi(-30)), 2f64.powi(-20), -(2f64.powi(-20))];
    let mut cases: Vec<[f64; 3]> = Vec::new();
    for i in 0..4096 {
        let (a, b) = (seq.value(60), seq.value(60));
        cases.push([a, b, a / b * (1.0 + spoil[i % spoil.len()])]);
    }
    // Shapes the kernels divide: e = add / (t + add), (growth / gain − 1) / boost, m / ρ.
    for _ in 0..1024 {
        let (t, add) = (seq.value(10).abs(), seq.value(20).abs());
        cases.push([add, t + add, add / (t + add) * (1.0 + 2f64.powi(-25))]);
        let m = seq.value(4).abs();
        cases.push([m, 3.0, m / 3.0 * (1.0 - 2f64.powi(-21))]);
    }
    // Exact quotients (a multiple of b), and ones just off them.
    for k in 1..=256 {
        let b = seq.value(8);
        let a = b * k as f64;
        cases.push([a, b, a / b * (1.0 + 2f64.powi(-22))]);
        let a_next = f64::from_bits(a.to_bits() + 1);
        cases.push([a_next, b, a_next / b * (1.0 - 2f64.powi(-22))]);
    }
    let n = cases.len();
    let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let mut input = ctx.create_host_buffer("division cases", 24 * n as u64, usage, MemoryLocation::CpuToGpu).unwrap();
    input.bytes_mut().copy_from_slice(bytemuck::cast_slice(&cases));
    let output = ctx.create_host_buffer("quotients", 8 * n as u64, usage, MemoryLocation::GpuToCpu).unwrap();
    let k = DIVISION_TEST;
    let pipeline = ctx.create_compute_pipeline(k.name, k.spirv, k.layout_bindings, k.push.size as u32).unwrap();
    let timeline = ctx.create_timeline("division test", 0).unwrap();
    for own in [0u32, 1] {
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "division test").unwrap();
        let buffers = [BufferRange::from(&*input), BufferRange::from(&*output)];
        let push = DivisionTestPush { count: n as u32, own };
        rec.dispatch(&pipeline, &buffers, bytemuck::bytes_of(&push), [k.groups_for(n as u32), 1, 1]).unwrap();
        rec.compute_to_host();
        let value = u64::from(own) + 1;
        rec.submit(ctx.compute_queue(), &[], (&timeline, value)).unwrap();
        timeline.wait(&ctx, value, 60_000_000_000).unwrap();
        let got: &[f64] = bytemuck::cast_slice(output.bytes());
        let wrong: Vec<String> = cases
            .iter()
            .zip(got)
            .filter(|([a, b, _], q)| (a / b).to_bits() != q.to_bits())
            .take(5)
            .map(|([a, b, q0], q)| format!("{a:e} / {b:e}: host {:e}, kernel {q:e} (from {q0:e})", a / b))
            .collect();
        let from = if own == 1 { "the device's own quotient" } else { "the spoiled quotients" };
        assert!(
            wrong.is_empty(),
            "started from {from}, the kernel's division differs from the host's:\n{}",
            wrong.join("\n")
        );
    }
    // SAFETY: the timeline waits above: the submissions using them have completed.
    unsafe {
        ctx.destroy_timeline(timeline);
        ctx.destroy_pipeline(pipeline);
        ctx.destroy_host_buffer(input);
        ctx.destroy_host_buffer(output);
    }
    let messages = ctx.validation_messages();
    assert!(messages.is_empty(), "validation errors:\n{}", messages.join("\n"));
}
