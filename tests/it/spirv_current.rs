//! The committed SPIR-V in `spirv/` must be exactly what `tools/compile_shaders.sh` makes from
//! `glsl/`: shaders are never compiled at run time, so a stale `.spv` would silently run old code.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Files in `dir` with extension `ext`, sorted, as stems.
fn stems(dir: &Path, ext: &str) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == ext))
        .filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    v.sort();
    v
}

#[test]
fn committed_spirv_matches_glsl() {
    let root = repo();
    let sources = stems(&root.join("glsl"), "comp");
    assert!(!sources.is_empty(), "no glsl/*.comp found");

    // Never skip: a missing compiler must not turn into a silently passing test.
    let version = Command::new("glslangValidator").arg("--version").current_dir(&root).output();
    match version {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!("glslangValidator --version failed ({}); install the Debian package glslang-tools", o.status),
        Err(e) => {
            panic!("glslangValidator not found ({e}); install the Debian package glslang-tools")
        }
    }

    let tmp = std::env::temp_dir().join(format!("lpm-spirv-current-{}", std::process::id()));
    fs::create_dir_all(&tmp).expect("creating a temporary directory");
    let mut stale = Vec::new();
    for name in &sources {
        let out = tmp.join(format!("{name}.spv"));
        // Same arguments as tools/compile_shaders.sh, same working directory.
        let result = Command::new("glslangValidator")
            .args(["-V", "--target-env", "vulkan1.2", "-Iglsl", "-o"])
            .arg(&out)
            .arg(format!("glsl/{name}.comp"))
            .current_dir(&root)
            .output()
            .expect("running glslangValidator");
        assert!(
            result.status.success(),
            "glsl/{name}.comp does not compile:\n{}{}",
            String::from_utf8_lossy(&result.stdout),
            String::from_utf8_lossy(&result.stderr)
        );
        let fresh = fs::read(&out).expect("reading freshly compiled SPIR-V");
        match fs::read(root.join("spirv").join(format!("{name}.spv"))) {
            Ok(committed) if committed == fresh => {}
            Ok(_) => stale.push(format!("spirv/{name}.spv differs from glsl/{name}.comp")),
            Err(_) => stale.push(format!("spirv/{name}.spv is missing")),
        }
    }
    let _ = fs::remove_dir_all(&tmp);
    for spv in stems(&root.join("spirv"), "spv") {
        if !sources.contains(&spv) {
            stale.push(format!("spirv/{spv}.spv has no source glsl/{spv}.comp"));
        }
    }
    assert!(stale.is_empty(), "{}\nrun tools/compile_shaders.sh (and delete orphaned .spv files)", stale.join("\n"));
}
