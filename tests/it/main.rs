//! Every integration test in one test crate (`[[test]] name = "it"` in Cargo.toml): one binary to
//! compile and link instead of one per file, with `tests/common` compiled once. Each file is a
//! module named after what it tests; run one with `cargo test --test it budget::`.

#[path = "../common/mod.rs"]
mod common;

mod acceleration;
mod budget;
mod cli;
mod compare;
mod cpu_physics;
mod gpu_solver;
mod hard_cases;
mod out_of_core;
mod plan_full;
mod plot;
mod precision;
mod reference_closed_forms;
mod reference_job;
mod render;
mod resume;
mod scene_files;
mod shader_interface;
mod spirv_current;
mod store_and_outputs;
mod vk_smoke;
