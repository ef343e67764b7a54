//! `lpm::compare` on synthetic output directories written with the exporter itself.
use crate::common::temp_dir;
use lpm::compare::{compare_dirs, write_comparison_json, CompareError, CompareOptions};
use lpm::output::{export_dense, FieldMeta};
use lpm::render::{write_exr, Image};
use std::path::{Path, PathBuf};

fn meta(components: usize) -> FieldMeta {
    FieldMeta {
        quantity: "fluence".into(),
        units: "test".into(),
        components: (0..components).map(|c| format!("c{c}")).collect(),
        description: "synthetic".into(),
        origin: [0.0; 3],
    }
}

/// A directory holding `fluence.*` (and `fluence_stderr.*` when given).
fn dir(root: &Path, name: &str, dims: [u32; 3], c: usize, fluence: &[f32], stderr: Option<&[f32]>) -> PathBuf {
    let d = root.join(name);
    std::fs::create_dir_all(&d).unwrap();
    export_dense(fluence, dims, 0.5, &d, "fluence", &meta(c)).unwrap();
    if let Some(se) = stderr {
        export_dense(se, dims, 0.5, &d, "fluence_stderr", &meta(c)).unwrap();
    }
    d
}

fn field(n: usize) -> Vec<f32> {
    (0..n).map(|i| 1.0 + (i % 7) as f32 * 0.25).collect()
}

#[test]
fn identical_directories_give_zero_errors() {
    let root = temp_dir("compare-identical");
    let dims = [4, 3, 2];
    let values = field(24 * 3);
    let a = dir(&root, "a", dims, 3, &values, None);
    let b = dir(&root, "b", dims, 3, &values, None);
    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    let m = &c.fluence.metrics;
    assert_eq!((c.fluence.voxels_total, c.fluence.voxels_used, c.fluence.voxels_excluded), (24, 24, 0));
    assert_eq!(m.values, 72);
    assert_eq!(
        (m.relative_l2, m.rmse, m.max_relative_error, m.mean_bias),
        (Some(0.0), Some(0.0), Some(0.0), Some(0.0))
    );
    assert_eq!(c.fluence.max_relative_stderr, None);
    assert!(c.image.is_none() && c.notes.is_empty(), "{c:?}");
    let text = c.to_string();
    assert!(text.contains("24 of 24 voxels") && text.contains("rel. L2"), "{text}");
}

#[test]
fn a_scaled_candidate_has_the_scale_as_error_and_bias() {
    let root = temp_dir("compare-scaled");
    let dims = [5, 4, 3];
    let b_values = field(60);
    let a_values: Vec<f32> = b_values.iter().map(|v| v * 1.1).collect();
    let a = dir(&root, "a", dims, 1, &a_values, None);
    let b = dir(&root, "b", dims, 1, &b_values, None);
    // Images too: the same scaling.
    let img = Image { width: 6, height: 4, rgb: (0..72).map(|i| 0.5 + i as f32 * 0.01).collect(), alpha: None };
    let scaled = Image { rgb: img.rgb.iter().map(|v| v * 1.1).collect(), ..img.clone() };
    write_exr(&a.join("image.exr"), &scaled).unwrap();
    write_exr(&b.join("image.exr"), &img).unwrap();

    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    let close = |x: Option<f64>, y: f64| (x.unwrap() - y).abs() < 1e-6;
    let m = &c.fluence.metrics;
    assert!(close(m.relative_l2, 0.1) && close(m.mean_bias, 0.1) && close(m.max_relative_error, 0.1), "{m:?}");
    let rms_b = (b_values.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / 60.0).sqrt();
    assert!(close(m.rmse, 0.1 * rms_b), "{m:?}");
    let img_c = c.image.as_ref().expect("images compared");
    assert_eq!((img_c.width, img_c.height, img_c.metrics.values), (6, 4, 72));
    assert!(close(img_c.metrics.relative_l2, 0.1) && close(img_c.metrics.mean_bias, 0.1), "{img_c:?}");
    assert!(c.to_string().contains("6×4 px"));

    // JSON, written atomically.
    let json_path = root.join("cmp.json");
    write_comparison_json(&json_path, &c).unwrap();
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    assert!((json["fluence"]["metrics"]["relative_l2"].as_f64().unwrap() - 0.1).abs() < 1e-6);
    assert_eq!(json["fluence"]["voxels_used"], 60);
    assert!((json["image"]["metrics"]["mean_bias"].as_f64().unwrap() - 0.1).abs() < 1e-6);

    // Images of different sizes are skipped with a note.
    write_exr(&a.join("image.exr"), &Image { width: 3, height: 4, rgb: vec![1.0; 36], alpha: None }).unwrap();
    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    assert!(c.image.is_none());
    assert!(c.notes.iter().any(|n| n.contains("3×4") && n.contains("6×4")), "{:?}", c.notes);
    // Only one image: a note, no error.
    std::fs::remove_file(a.join("image.exr")).unwrap();
    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    assert!(c.image.is_none() && c.notes.iter().any(|n| n.contains("image.exr")), "{:?}", c.notes);
}

#[test]
fn mismatched_fields_are_errors_naming_both_files() {
    let root = temp_dir("compare-mismatch");
    let a = dir(&root, "a", [4, 3, 2], 1, &field(24), None);
    let b = dir(&root, "b", [4, 2, 3], 1, &field(24), None);
    let err = compare_dirs(&a, &b, &CompareOptions::default()).unwrap_err();
    assert!(matches!(err, CompareError::Mismatch { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(&a.join("fluence.json").display().to_string()), "{msg}");
    assert!(msg.contains(&b.join("fluence.json").display().to_string()), "{msg}");
    assert!(msg.contains("[4, 3, 2]") && msg.contains("[4, 2, 3]"), "{msg}");

    let c3 = dir(&root, "c3", [4, 3, 2], 3, &field(72), None);
    let msg = compare_dirs(&a, &c3, &CompareOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("components") && msg.contains("c3"), "{msg}");

    // A missing directory names the file it could not read.
    let msg = compare_dirs(&a, &root.join("nowhere"), &CompareOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("nowhere") && msg.contains("fluence.json"), "{msg}");
    // A bad threshold is rejected.
    let bad = CompareOptions { max_relative_stderr: f64::NAN, ..Default::default() };
    assert!(matches!(compare_dirs(&a, &a, &bad), Err(CompareError::BadThreshold(_))));
}

#[test]
fn the_reference_standard_error_masks_noisy_and_dark_voxels() {
    let root = temp_dir("compare-mask");
    let dims = [4, 4, 1];
    let mut b_values = vec![2.0f32; 16 * 2];
    let mut se = vec![0.02f32; 16 * 2]; // 1 % relative: kept
    se[3 * 2 + 1] = 0.2; // voxel 3, channel 1: 10 % relative, excluded
    se[5 * 2] = f32::NAN; // voxel 5: excluded
    b_values[7 * 2 + 1] = 0.0; // voxel 7: dark, excluded
    se[7 * 2 + 1] = 0.0;
    // The candidate is exact on kept voxels and far off on excluded ones.
    let mut a_values = b_values.clone();
    for v in [3usize, 5, 7] {
        a_values[v * 2] = 100.0;
        a_values[v * 2 + 1] = 100.0;
    }
    let a = dir(&root, "a", dims, 2, &a_values, None);
    let b = dir(&root, "b", dims, 2, &b_values, Some(&se));
    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    assert_eq!((c.fluence.voxels_used, c.fluence.voxels_excluded), (13, 3));
    assert_eq!(c.fluence.max_relative_stderr, Some(0.05));
    assert_eq!(c.fluence.metrics.values, 26);
    assert_eq!(c.fluence.metrics.relative_l2, Some(0.0));
    assert!(c.to_string().contains("3 excluded"), "{c}");

    // A looser threshold lets voxel 3 in (and its error shows).
    let c = compare_dirs(&a, &b, &CompareOptions { max_relative_stderr: 0.2, ..Default::default() }).unwrap();
    assert_eq!(c.fluence.voxels_used, 14);
    assert!(c.fluence.metrics.relative_l2.unwrap() > 1.0);

    // Standard errors of another shape than the reference's fluence are an error.
    export_dense(&field(15), [5, 3, 1], 0.5, &b, "fluence_stderr", &meta(1)).unwrap();
    let msg = compare_dirs(&a, &b, &CompareOptions::default()).unwrap_err().to_string();
    assert!(msg.contains("fluence_stderr.json"), "{msg}");
}

/// A directory whose fluence has the given component names (and standard errors when given).
fn named_dir(
    root: &Path,
    name: &str,
    dims: [u32; 3],
    names: &[&str],
    fluence: &[f32],
    stderr: Option<&[f32]>,
) -> PathBuf {
    let d = root.join(name);
    std::fs::create_dir_all(&d).unwrap();
    let meta = FieldMeta { components: names.iter().map(|s| s.to_string()).collect(), ..meta(0) };
    export_dense(fluence, dims, 0.5, &d, "fluence", &meta).unwrap();
    if let Some(se) = stderr {
        export_dense(se, dims, 0.5, &d, "fluence_stderr", &meta).unwrap();
    }
    d
}

#[test]
fn a_grey_reference_is_compared_with_each_channel_of_an_rgb_candidate() {
    // A grey scene solved with `solver.plan = "full"` has r, g, b channels; its reference has one.
    let root = temp_dir("compare-grey-rgb");
    let dims = [3, 2, 2];
    let grey = field(12);
    let se: Vec<f32> = grey.iter().map(|v| v * 0.01).collect();
    let b = named_dir(&root, "b", dims, &["grey"], &grey, Some(&se));
    let rgb: Vec<f32> = grey.iter().flat_map(|&v| [v, v * 1.1, v]).collect();
    let a = named_dir(&root, "a", dims, &["r", "g", "b"], &rgb, None);
    let c = compare_dirs(&a, &b, &CompareOptions::default()).unwrap();
    assert_eq!((c.fluence.components, c.fluence.voxels_used, c.fluence.metrics.values), (3, 12, 36));
    // Only g is off, by 10 %: ‖a − b‖/‖b‖ = 0.1/√3 over the three channels.
    let l2 = c.fluence.metrics.relative_l2.unwrap();
    assert!((l2 - 0.1 / 3f64.sqrt()).abs() < 1e-6, "{l2}");
    // The reference's noise counts once per channel compared: 1 % relative, as for one channel.
    assert!((c.fluence.reference_noise_relative_l2.unwrap() - 0.01).abs() < 1e-6, "{c:?}");
    assert!(c.notes.iter().any(|n| n.contains("reference is grey")), "{:?}", c.notes);

    // Only "grey" against "r", "g", "b": other names with other counts are still a mismatch.
    let other = named_dir(&root, "other", dims, &["c0", "c1", "c2"], &rgb, None);
    assert!(matches!(compare_dirs(&other, &b, &CompareOptions::default()), Err(CompareError::Mismatch { .. })));
}

#[test]
fn the_dense_core_is_compared_on_its_own() {
    // 4×4×1 voxels, densities 0 (one empty voxel) then 1..15; the candidate is exact except in the
    // two densest voxels, where it is 20 % high.
    let root = temp_dir("compare-core");
    let dims = [4, 4, 1];
    let density: Vec<f32> = (0..16).map(|i| i as f32).collect();
    let b_values = vec![1.0f32; 16];
    let mut a_values = b_values.clone();
    a_values[14] = 1.2;
    a_values[15] = 1.2;
    let a = dir(&root, "a", dims, 1, &a_values, None);
    let b = dir(&root, "b", dims, 1, &b_values, None);
    // The 0.9 quantile of the 15 non-zero densities 1..15 is 13.6 → the lower value 13: voxels 13-15.
    let core = Some(lpm::compare::CoreMask { density: density.clone(), quantile: 0.9 });
    let c = compare_dirs(&a, &b, &CompareOptions { core, ..Default::default() }).unwrap();
    let k = c.fluence.core.as_ref().expect("core comparison");
    assert_eq!((k.voxels_used, k.density_threshold), (3, 13.0));
    assert!((k.metrics.mean_bias.unwrap() - 0.4 / 3.0).abs() < 1e-6, "{:?}", k.metrics);
    // The whole medium dilutes it: 0.4 over 16 voxels.
    assert!((c.fluence.metrics.mean_bias.unwrap() - 0.4 / 16.0).abs() < 1e-6);
    assert!(c.to_string().contains("core"), "{c}");
    // A quantile outside [0, 1) and a density of another size are errors.
    let bad = Some(lpm::compare::CoreMask { density: density.clone(), quantile: 1.0 });
    assert!(matches!(
        compare_dirs(&a, &b, &CompareOptions { core: bad, ..Default::default() }),
        Err(CompareError::BadQuantile(_))
    ));
    let short = Some(lpm::compare::CoreMask { density: density[..15].to_vec(), quantile: 0.5 });
    assert!(compare_dirs(&a, &b, &CompareOptions { core: short, ..Default::default() }).is_err());
}
