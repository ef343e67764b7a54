//! Scene files (TOML): parsing and validation into [`Scene`].
//!
//! # Two stages
//!
//! Loading is split in two on purpose:
//!
//! 1. **Raw** (`raw`, private): serde deserialises the text into structs that mirror the file
//!    exactly — every key optional where the file may omit it, integers as `i64`, "number or
//!    `[r, g, b]`" kept in the form written, lights as a flat struct with a `kind` string. Every
//!    struct has `#[serde(deny_unknown_fields)]`, so a misspelt key is an error rather than a
//!    silently ignored setting. Syntax errors, type errors and unknown or missing keys surface
//!    here as [`SceneError::Parse`], with the line, column and (recovered from the position) key.
//! 2. **Validated** (`types`, public): [`validate`] checks ranges and consistency (finite
//!    numbers, albedo in [0, 1], exactly one volume source, the raw file's size, a usable camera
//!    basis, …), applies defaults and normalises (the sun direction), producing [`Scene`] and its
//!    parts. Failures are [`SceneError::Invalid`] (or the raw-file variants) naming the exact
//!    dotted key, e.g. `medium.albedo[1]` or `lights[2].direction`.
//!
//! Why not deserialise straight into the typed values? serde's derive can only say "wrong type";
//! it cannot express "finite and ≥ 0", "not parallel to the view direction" or "both `procedural`
//! and `raw`", and custom `Deserialize` impls that do would scatter validation over many impls and
//! lose the key in the message. Keeping serde's job to shape and the validator's job to meaning
//! gives one place for every rule, messages that name the key, and typed values the solver can
//! trust without re-checking (see `types`). The raw structs never leave this module, so the file
//! format can grow (new keys, aliases) without touching the solver's types.
//!
//! Densities of procedural volumes come from [`procedural`]; the values of raw density files are
//! checked later by the brick importer (here only the file's existence and size are checked).

pub mod blackbody;
pub mod environment;
mod error;
mod locate;
pub mod procedural;
mod raw;
mod types;
pub mod validate;

pub use error::SceneError;
pub use types::*;

/// The `[volume]` keys that name a file (relative to the scene file). Whatever moves or confines a
/// scene's files uses this list: the job server confines each to its data root
/// (`serve/prepare.rs`), a sweep task makes each absolute (`sweep`). A new key that names a file
/// goes here.
pub const VOLUME_FILE_KEYS: [&str; 7] = ["raw", "vdb", "nvdb", "nrrd", "emission_raw", "temperature_raw", "albedo_raw"];

/// Makes every file a scene table names — the volume's [`VOLUME_FILE_KEYS`] (all but those in
/// `except`) and an environment light's `map` — absolute, resolved against `base` (the scene
/// file's directory) as the loader would, so that a copy of the scene written elsewhere reads the
/// same files.
pub fn make_file_paths_absolute(scene: &mut toml::Table, base: &Path, except: &[&str]) {
    let absolute = |named: &str| {
        let joined = base.join(named);
        std::path::absolute(&joined).unwrap_or(joined).to_string_lossy().into_owned()
    };
    if let Some(toml::Value::Array(lights)) = scene.get_mut("lights") {
        for light in lights.iter_mut().filter_map(toml::Value::as_table_mut) {
            if let Some(toml::Value::String(map)) = light.get_mut("map") {
                *map = absolute(map);
            }
        }
    }
    if let Some(toml::Value::Table(volume)) = scene.get_mut("volume") {
        for key in VOLUME_FILE_KEYS.into_iter().filter(|k| !except.contains(k)) {
            if let Some(toml::Value::String(named)) = volume.get_mut(key) {
                *named = absolute(named);
            }
        }
    }
}
pub use validate::{
    camera_from_keys, default_camera, display_from_keys, fitted_default_camera, CameraKeys, ExposureKey, VolumeFrame,
};

use std::path::Path;

impl Scene {
    /// Reads and validates the scene file at `path`. Relative `volume.raw` paths are resolved
    /// against the scene file's directory.
    /// Only a regular file of at most [`validate::MAX_SCENE_BYTES`] is read: a FIFO would block
    /// forever and `/dev/zero` would be read until memory ran out.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let bad = |problem: String| SceneError::BadFile { path: path.to_path_buf(), problem };
        // Through the input checks: a FIFO would block in open(), a device never end.
        let bytes =
            crate::input::read_capped(path, validate::MAX_SCENE_BYTES, "a scene file").map_err(|e| match e {
                crate::input::InputError::Io { source, .. } => SceneError::Read { path: path.to_path_buf(), source },
                e => bad(e.words()),
            })?;
        let text = String::from_utf8(bytes).map_err(|_| bad("not UTF-8 text".to_string()))?;
        Scene::from_toml_str(&text, path)
    }

    /// Parses and validates scene `text`. `path` is the file it (nominally) came from: it is used in
    /// messages and to resolve a relative `volume.raw` against its directory; it is not read.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Scene, SceneError> {
        let raw: raw::RawScene = toml::from_str(text).map_err(|e| parse_error(path, text, &e))?;
        let scene = validate::Validator { path }.scene(raw)?;
        tracing::debug!(path = %path.display(), dims = ?scene.volume.dims, lights = scene.lights.len(), "scene loaded");
        Ok(scene)
    }
}

/// Converts a TOML/serde error into [`SceneError::Parse`], recovering line, column and key from
/// the reported span.
fn parse_error(path: &Path, text: &str, e: &toml::de::Error) -> SceneError {
    // toml's messages may span lines ("invalid table header\nexpected `.`, `]`"): keep one line.
    let message = e.message().trim_end().lines().map(str::trim).collect::<Vec<_>>().join("; ");
    let (mut line, mut column, mut key) = match e.span() {
        Some(span) => {
            let (l, c) = locate::line_column(text, span.start);
            (Some(l), Some(c), locate::key_at(text, span.start))
        }
        None => (None, None, None),
    };
    // "missing field `x`" points at the table that lacks it: name the missing key itself. The
    // top-level tables are required by name, and their span is the whole document.
    if let Some(field) = message.strip_prefix("missing field `").and_then(|r| r.split('`').next()) {
        if TOP_LEVEL_REQUIRED.contains(&field) {
            key = Some(field.to_string());
            line = None;
            column = None;
        } else {
            key = Some(match key {
                Some(table) if !table.ends_with(&format!(".{field}")) => format!("{table}.{field}"),
                Some(k) => k,
                None => field.to_string(),
            });
        }
    }
    SceneError::Parse { path: path.to_path_buf(), line, column, key, message }
}

/// Top-level tables that every scene must have.
const TOP_LEVEL_REQUIRED: [&str; 2] = ["volume", "medium"];
