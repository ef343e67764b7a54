//! # lpm — Light Propagation Maps, streamed out of core, on Vulkan
//!
//! lpm solves the radiative transfer equation in a voxel volume of absorbing, scattering and emitting
//! medium lit by a sky, an HDR environment map, suns and point lights, and renders images from the
//! solution. The
//! method is Fattal's Light Propagation Maps (a discrete-ordinates method) in the parallel, streamed
//! form of Gruson et al. 2012:
//! the volume is tiled into 16³ bricks kept in memory-mapped files, and each of the six cube faces is
//! swept slice of bricks by slice of bricks, the ray state travelling with the sweep on the device.
//! Only occupied bricks are stored, streamed and solved (empty space is crossed by the rays but holds
//! no medium, source or fluence); a slice that does not fit the device budget is streamed as
//! sub-slices of fewer planes; and a store larger than the host memory budget has every pass over
//! its memory-mapped files hand the pages back, so neither device nor host memory grows with the
//! volume (see [`solver::gpu`], [`store::Field`] and [`store::resident`]: a store that fits keeps its
//! pages, so no pass faults the volume in again). When the occupied bricks' medium and fields fit
//! the device budget instead, they stay on the device for the whole solve (the resident mode of
//! [`solver::gpu`]): the passes only compute, and the fields cross the bus once per order, or only
//! at checkpoints and at the end where the passes between orders run on the device too
//! (`solver::gpu::end_of_order`).
//!
//! ## Layout (each layer only uses the ones above it)
//!
//! | module | what it owns |
//! |---|---|
//! | [`input`] | opening every file a user names: regular files only, size caps for small inputs, and a solve's confinement to the server's data root, checked on the open file |
//! | [`threads`] | how many worker threads a user may ask for (`--threads`): up to a few per core, a clear error beyond |
//! | [`progress`] | the stages of a solve as its layers report them, and the one estimator of the fraction done and the seconds left (CLI, `progress.json`, the job server) |
//! | [`scene`] | the TOML job description, validated into typed values and typed errors; the physics every layer shares from it (procedural densities, the blackbody colour of a temperature) |
//! | [`store`] | the 16³ brick store: memory-mapped field files, empty-brick table, importers (raw, OpenVDB `.vdb`, NanoVDB `.nvdb`, NRRD), the per-voxel emission field (grey, or r, g, b from a temperature grid) and albedo factor field |
//! | [`output`] | atomic writes (temporary name, then rename), outputs published as a set, the exported raw/json/nhdr layout, the sparse OpenVDB export (our own writer) and the per-face exitance maps' files (`faces/`) |
//! | [`quadrature`] | propagation directions and their solid angles, storage directions, phase tables |
//! | [`vk`] | the thin Vulkan layer: instance, device, queues, buffers, pipelines, timeline sync |
//! | [`solver`] | the plan (what a scene needs), the discretisation shared by both backends, the CPU twin (f64), the GPU driver, the order loop |
//! | [`render`] | the camera ray-march over the solved source (RGBA: alpha = 1 − transmittance), EXR and PNG writers, the render data a solve keeps for `lpm render` |
//! | [`reference`](mod@reference) | the independent Monte-Carlo reference (shares only the scene with the solver) |
//! | [`compare`] | accuracy figures of one output directory against another (e.g. a solve against a reference) |
//! | [`job`] | a whole `lpm solve`: scene → store → solve → exported fields, image, report; checkpoints and resume |
//! | [`bench`](mod@bench) | `lpm bench`: the profiled stream (JSON), the time-against-error study and the grid-refinement study (the same medium at h, h/2, h/4: error against h and the observed order) |
//! | `serve` | `lpm serve`: the HTTP job server, its durable SQLite queue and the `submit`/`status`/`fetch` client (cargo feature `service`, on by default) |
//! | [`sweep`](mod@sweep) | `lpm sweep`: frames and parameter sweeps as numbered tasks, one task per run, Slurm array scripts |
//! | [`plot`] | small dependency-free plots (log/linear axes, series, legend) written as SVG |
//!
//! The binary (`src/main.rs`) is a thin CLI over [`job`], [`reference::job`], [`compare`], [`bench`](mod@bench)
//! and the output readers.
//!
//! ## Architecture
//!
//! ### The data's way through the layers
//!
//! 1. **Scene** — `lpm solve scene.toml` ([`job`]) loads the TOML into raw serde structs and
//!    validates them into a typed [`scene::Scene`]: every later layer trusts it.
//! 2. **Store** — [`solver::build_store`] fills the [`store::BrickStore`]: the density of every
//!    occupied 16³ brick in a memory-mapped file, plus the empty-brick table. The solver's fields
//!    ([`solver::fields::StoreFields`]) are more files of the same bricks.
//! 3. **Plan** — [`solver::plan::Plan`] decides what the scene needs (channels, directions, storage
//!    directions and precision, beams) and derives each direction's offset tables and collect row.
//! 4. **Order loop** — [`solver::orders::run_orders`] has a [`solver::orders::Backend`] propagate
//!    one scattering order at a time into its fields, then runs the host passes itself, written
//!    once in [`solver::passes`] for both kinds of field (the store's f32 files, the twin's f64
//!    memory): commit the order (a per-voxel albedo factor multiplies the source first,
//!    `store::albedo`; at high albedo a diffusion solve estimates the light still to come and
//!    folds it into the order, [`solver::acceleration`]; then, with `solver.diffusion_correction =
//!    "on"`, the default, the next order is given the change the order makes to the sharpened
//!    total, which takes the discretisation's numerical diffusion back out:
//!    [`solver::antidiffusion`], a capped stencil over partners two voxels apart, on either
//!    layout), the stop rule's remaining error, a checkpoint (store only, at the cadence
//!    of `solver.checkpoint_every_*`, written in the background while the next order's sweeps run),
//!    and at the end the energy balance and the geometric tail.
//!    The passes run on every core, with every sum taken in a fixed order (bitwise at any thread
//!    count).
//! 5. **Backend** — either the CPU twin ([`solver::cpu`], f64, in memory, its sweeps plane by plane
//!    on every core: `solver/cpu_sweep.rs`, bitwise the same at any thread count) or the GPU driver
//!    ([`solver::gpu`]): `sizes` → `budget` (the memory plan) → `resources` (everything on the
//!    device, all-or-nothing) → `streamer` (slices through the slots: gather on the copy workers,
//!    upload, compute, download, scatter, against timeline semaphores; resident: compute only,
//!    with a load and an unload per order, or neither where `end_of_order` commits on the device)
//!    → `encoder` (push constants,
//!    one descriptor set per step bound once for both kernels, which share a pipeline layout, and
//!    the dispatches of `glsl/propagate.comp` and `glsl/collect.comp`) → [`vk`].
//! 6. **Outputs** — [`job`] exports the committed fluence and source ([`output`], atomically: raw +
//!    NRRD header, and sparse OpenVDB grids), keeps `render-data/` (density and source in brick
//!    form, linked from the store) and renders the image from it ([`render`]: `lpm render` renders
//!    new views from the same data), and writes `report.json`. Independently,
//!    [`reference`](mod@reference) solves the same scene by Monte Carlo, and [`compare`] holds one
//!    output directory against another.
//!
//! ### Where each kind of change goes
//!
//! | change | where |
//! |---|---|
//! | a scene key | `scene/raw.rs` (the file's shape), `scene/validate.rs` (check and default), `scene/types.rs`, README |
//! | a scene key that names a file | as above, **and** `serve/prepare.rs` (`VOLUME_KEYS`): the server confines every such path to its data root |
//! | the physics of a sweep | `glsl/*.comp` **and** its twin in [`solver::cpu`]; [`solver::segment`] for the segment solution |
//! | a shader interface (push constants, bindings, flags) | `solver/gpu/layout.rs`, `glsl/common.glsl`, the shared set's bindings (`SWEEP_BINDINGS`, `sweep_bindings`) in `solver/gpu/encoder.rs`; `tests/it/shader_interface.rs` fails until both sides agree; `tools/compile_shaders.sh` regenerates `spirv/` |
//! | a device buffer or its size | `solver/gpu/sizes.rs` (the one place sizes are computed), then `resources.rs`; the planner follows |
//! | scheduling of slices, overlap, copies | `solver/gpu/streamer.rs` (and `copier.rs`, `slice.rs`) |
//! | what a per-voxel emission or temperature means | `scene/blackbody.rs` (temperature → colour), `store/emission.rs` (the field the solver, the renderer and the reference read), `solver/emission.rs` (the order-0 source and its power), `solver/uncollided/` (its uncollided light traced instead of swept) |
//! | what a per-voxel albedo means | `store/albedo.rs` (the field), `solver/passes.rs` (the source scaled by it, absorption), `solver/emission.rs` (σa per voxel), `render/march.rs`, `reference/grid.rs` |
//! | how an image reads the source (in space, in direction) | `render/march.rs` (trilinear between voxel centres), `quadrature/blend.rs` (weights between storage directions); `tests/it/render_blend.rs` |
//! | what an image takes from the solve and adds exactly (the suns' single scattering) and sharpens (the chains, the forward lobes) | [`solver::direct`] (the split and each sun's irradiance), `render/keep.rs` (`render-data/`), `render/peak.rs`, `render/march.rs`; `tests/it/single_scatter.rs` |
//! | what the progress bar and the server promise | [`progress`] (the estimator), [`solver::slow_mode`] (its prior from the medium); `tools/eta_table.sh` |
//! | a host pass between orders | `solver/passes.rs` (once, for the store's fields and the twin's); checkpoints in `solver/fields.rs` |
//! | a Vulkan object kind | [`vk`] (destroy functions take the object by value and are `unsafe fn`: the device must be done with it; the driver wraps it in `Owned`) |
//! | an output file | [`output`] (atomic writes) and [`job`]; README's outputs list |
//! | a CLI flag or environment variable | `src/main.rs` only (clap, with `env` for variables) |
//!
//! ### The rules
//!
//! - **No floating-point atomics**, no order-dependent reductions on the device: every voxel
//!   receives each direction's contribution as its own addition, in direction order, so results are
//!   bitwise identical run to run and at any memory budget.
//! - **Every kernel has a twin**: the CPU twin walks the same voxels with the same formulas in f64
//!   and the GPU is tested against it. The host passes between orders are not twinned but shared:
//!   written once ([`solver::passes`]) over both backends' fields.
//! - **Sizes from one place**: the budget planner and the allocations use `solver/gpu/sizes.rs`;
//!   a test holds the planned bytes equal to the bytes allocated.
//! - **The shader interface is checked, not commented**: reflection of the committed SPIR-V.
//! - **All-or-nothing resources**: device objects are owned values freed on drop, after the
//!   streamer has waited for the last submission; no `Option` fields for half-built states.
//! - **Unsafe at the boundary**: a function whose contract the caller must uphold is `unsafe fn`
//!   with a `# Safety` section; every `unsafe` block says why it holds.
//! - **Configuration from the CLI**: the library reads no environment variable (the kill test's
//!   hook, compiled in only with the `test-hooks` cargo feature, is the one exception).
//! - **Errors are typed** (thiserror) and name the file and the field; outputs are written to a
//!   temporary name and renamed when complete.
//!
//! ## The discretisation in one paragraph
//!
//! Directions come from a cube-face parametrisation ([`quadrature`]): each face holds k×k cells with
//! exact solid angles. A ray map on a face has one ray per voxel of the face; a ray advances one voxel
//! plane at a time along the face's axis and occupies, in each plane, the voxel under its mid-plane
//! position. All rays of one direction move by the same integer offset from plane to plane (tables in
//! [`solver::sweep`]), so in every plane the rays of a direction touch distinct voxels: one GPU thread
//! per ray per direction, no atomics, bitwise reproducible. A ray leaving through a side wraps to the
//! opposite side as a new ray. Along its segment in a voxel the exact constant-coefficient solution is
//! used ([`solver::segment`]): what the ray deposits is its segment-average radiance, from which the
//! collect step forms the fluence and the next order's in-scattered source. The sun is one more
//! "direction" swept along its exact direction, so its uncollided light shows no ray effects. An
//! environment map is boundary radiance averaged over each direction's cell, its sun-like peak
//! taken out as one more beam ([`solver::environment`]). A point light's uncollided light is
//! computed exactly from the point on the host (a DDA from the light to every voxel), and its
//! first scattering joins order 0's new source ([`solver::point`]); an emission's is traced the
//! same way from its emitting voxels, far ones clustered, when the plan finds it compact
//! ([`solver::uncollided`]).
//!
//! ## The method by topic
//!
//! Each part of the method is explained, with its derivation and what was measured, in the module
//! that implements it (the README names these pages; the measured studies are in
//! `benches/RESULTS.md`):
//!
//! | topic | where |
//! |---|---|
//! | sweep geometry, the `constant` and `linear` spatial schemes | [`solver::sweep`], [`solver::segment`] |
//! | the plan: channels, storage directions, f16 storage, the sky's own directions, the spatial scheme's choice | [`solver::plan`] |
//! | the stop rule (per-voxel remaining error) | [`solver::remaining`] |
//! | the order loop, the geometric tail (`extrapolate_tail`), divergence checks | [`solver::orders`] |
//! | diffusion synthetic acceleration | [`solver::acceleration`] |
//! | the diffusion correction (numerical diffusion taken back out) | [`solver::antidiffusion`] |
//! | Henyey–Greenstein scattering between direction cells; the forward peak (δ-M with the shape kept) | [`quadrature::phase`] |
//! | point lights, environment maps, emission | [`solver::point`], [`solver::environment`], [`scene::environment`], [`solver::emission`] |
//! | emission's uncollided light traced (a first-collision source), clusters of far emitters | [`solver::uncollided`] |
//! | periodic and mirror faces | [`solver::periodic`], [`solver::mirror`], [`solver::unfold`] |
//! | warm starts | [`solver::warm`] |
//! | the energy books | [`solver::energy`] |
//! | per-voxel albedo, the host passes between orders | [`solver::passes`] |
//! | streaming, the memory plan and its cost model, device residency | [`solver::gpu`], [`solver::gpu::cost`] |
//! | the blackbody colour of a temperature | [`scene::blackbody`] |
//! | the Monte-Carlo reference | [`reference`](mod@reference) |

pub mod bench;
pub mod compare;
pub mod input;
pub mod job;
pub mod output;
pub mod plot;
pub mod progress;
pub mod quadrature;
pub mod reference;
pub mod render;
pub mod scene;
#[cfg(feature = "service")]
pub mod serve;
pub mod solver;
pub mod store;
pub mod sweep;
pub mod threads;
pub mod vk;
