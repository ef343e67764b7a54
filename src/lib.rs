//! # lpm — Light Propagation Maps, streamed out of core, on Vulkan
//!
//! lpm solves the radiative transfer equation in a voxel volume of absorbing, scattering and emitting
//! medium lit by a sky and a sun, and renders images from the solution. The method is Fattal's Light
//! Propagation Maps (a discrete-ordinates method) in the parallel, streamed form of Gruson et al. 2012:
//! the volume is tiled into 16³ bricks kept in memory-mapped files, and each of the six cube faces is
//! swept slice of bricks by slice of bricks, the ray state travelling with the sweep on the device.
//! Only occupied bricks are stored, streamed and solved (empty space is crossed by the rays but holds
//! no medium, source or fluence); a slice that does not fit the device budget is streamed as
//! sub-slices of fewer planes; and every pass over the memory-mapped files hands its pages back, so
//! neither device nor host memory grows with the volume (see [`solver::gpu`] and [`store::Field`]).
//!
//! ## Layout (each layer only uses the ones above it)
//!
//! | module | what it owns |
//! |---|---|
//! | [`scene`] | the TOML job description, validated into typed values and typed errors |
//! | [`store`] | the 16³ brick store: memory-mapped field files, empty-brick table, importers |
//! | [`output`] | atomic writes (temporary name, then rename) and the exported raw/json/nhdr layout |
//! | [`quadrature`] | propagation directions and their solid angles, storage directions, phase tables |
//! | [`vk`] | the thin Vulkan layer: instance, device, queues, buffers, pipelines, timeline sync |
//! | [`solver`] | the plan (what a scene needs), the discretisation shared by both backends, the CPU twin (f64), the GPU driver, the order loop |
//! | [`render`] | the camera ray-march over the solved source, EXR and PNG writers |
//! | [`reference`](mod@reference) | the independent Monte-Carlo reference (shares only the scene with the solver) |
//! | [`compare`] | accuracy figures of one output directory against another (e.g. a solve against a reference) |
//! | [`job`] | a whole `lpm solve`: scene → store → solve → exported fields, image, report; checkpoints and resume |
//! | [`bench`](mod@bench) | `lpm bench`: the profiled stream (JSON) and the time-against-error study |
//! | [`plot`] | small dependency-free plots (log/linear axes, series, legend) written as SVG and PNG, with an embedded bitmap font |
//!
//! The binary (`src/main.rs`) is a thin CLI over [`job`], [`reference::job`], [`compare`], [`bench`](mod@bench)
//! and the output readers.
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
//! "direction" swept along its exact direction, so its uncollided light shows no ray effects.

pub mod bench;
pub mod compare;
pub mod job;
pub mod output;
pub mod plot;
pub mod quadrature;
pub mod reference;
pub mod render;
pub mod scene;
pub mod solver;
pub mod store;
pub mod vk;
