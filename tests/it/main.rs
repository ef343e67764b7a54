//! Every integration test in one test crate (`[[test]] name = "it"` in Cargo.toml): one binary to
//! compile and link instead of one per file, with `tests/common` compiled once. Each file is a
//! module named after what it tests; run one with `cargo test --test it budget::`. The kill test
//! (`resume::`) needs lpm's test hook, compiled in only with `--features test-hooks` (tools/test.sh
//! passes it); without it that test fails and says so.

#[path = "../common/mod.rs"]
mod common;

mod acceleration;
mod albedo_grid;
mod backends_agree;
mod bench_refine;
mod boundary_faces;
mod budget;
mod cli;
mod compare;
mod cpu_physics;
mod cpu_threads;
mod diffusion_correction;
mod emission;
mod emission_uncollided;
mod environment;
mod exact_division;
mod exitance;
mod forward_peak;
mod gpu_solver;
mod hard_cases;
mod hostile_inputs;
mod i3rc;
mod image_views;
mod kobayashi;
mod layering;
mod nanovdb_input;
mod out_of_core;
mod periodic;
mod plan_full;
mod plot;
mod point_light;
mod precision;
mod property_solve;
mod reference_closed_forms;
mod reference_job;
mod reflective;
mod reliability;
mod render;
mod render_blend;
mod resident;
mod resume;
mod scene_files;
mod serve;
mod shader_interface;
mod single_scatter;
mod sky_directions;
mod slurm;
mod spatial_accuracy;
mod spirv_current;
mod stop_rule;
mod store_and_outputs;
mod synthetic_acceleration;
mod temperature;
mod uncollided_gpu;
mod vdb_input;
mod vdb_nrrd;
mod vdb_output;
mod vdb_sparse;
mod vk_smoke;
mod warm_start;
