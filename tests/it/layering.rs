//! The GPU driver's files form layers (issue 33): no file of `src/solver/gpu` uses, directly or
//! through others, a file that uses it back. The layer list is in the module docs of
//! `src/solver/gpu/mod.rs`; this test keeps it true. A file's uses are the `super::name` and
//! `crate::solver::gpu::name` paths in its code (comments, doc links included, do not count).
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

fn uses_of(code: &str, files: &BTreeSet<String>) -> BTreeSet<String> {
    let mut uses = BTreeSet::new();
    for line in code.lines() {
        let code = line.split("//").next().unwrap_or("");
        for prefix in ["crate::solver::gpu::", "super::"] {
            let mut rest = code;
            while let Some(at) = rest.find(prefix) {
                rest = &rest[at + prefix.len()..];
                let name: String = rest.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                if files.contains(&name) {
                    uses.insert(name);
                }
            }
        }
        // `use super::{a, b::C}` lists: the first segment of each item.
        if let Some(list) = code.split("super::{").nth(1) {
            for item in list.split(['}', ',']) {
                let name = item.trim().split("::").next().unwrap_or("").trim().to_string();
                if files.contains(&name) {
                    uses.insert(name);
                }
            }
        }
    }
    uses
}

/// The files that can reach `from` again through `uses`, if any: one cycle, in order.
fn cycle_through(from: &str, uses: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    let mut path = vec![from.to_string()];
    let mut seen = BTreeSet::new();
    fn walk(
        at: &str,
        from: &str,
        uses: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        seen: &mut BTreeSet<String>,
    ) -> bool {
        for next in &uses[at] {
            if next == from {
                return true;
            }
            if seen.insert(next.clone()) {
                path.push(next.clone());
                if walk(next, from, uses, path, seen) {
                    return true;
                }
                path.pop();
            }
        }
        false
    }
    walk(from, from, uses, &mut path, &mut seen).then_some(path)
}

#[test]
fn the_gpu_driver_has_no_import_cycle() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/solver/gpu");
    let mut sources = BTreeMap::new();
    for entry in std::fs::read_dir(&dir).expect("src/solver/gpu") {
        let path = entry.expect("entry").path();
        let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("").to_string();
        // mod.rs is the driver on top: its children's `super::` means it, not a sibling.
        if path.extension().is_some_and(|e| e == "rs") && name != "mod" {
            sources.insert(name, std::fs::read_to_string(&path).expect("source"));
        }
    }
    assert!(sources.len() > 10, "found only {} files in {}", sources.len(), dir.display());
    let files: BTreeSet<String> = sources.keys().cloned().collect();
    let uses: BTreeMap<String, BTreeSet<String>> =
        sources.iter().map(|(name, code)| (name.clone(), uses_of(code, &files))).collect();
    // The parser finds what it should: two uses the layer list names.
    assert!(uses["resources"].contains("buffers") && uses["budget"].contains("sizes"), "{uses:?}");
    let cycles: Vec<String> = files.iter().filter_map(|f| cycle_through(f, &uses)).map(|c| c.join(" → ")).collect();
    assert!(cycles.is_empty(), "import cycles among src/solver/gpu's files:\n{}", cycles.join("\n"));
}
