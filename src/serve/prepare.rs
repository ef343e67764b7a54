//! A scene sent to the server, made safe to solve: validated exactly as the CLI validates it, with
//! every file it names confined to the server's data root (or naming a file uploaded with it) and
//! made absolute.

use super::api::ApiError;
use super::confine::{self, ConfineError};
use crate::scene::Scene;
use std::path::Path;

/// The `[volume]` keys that name a file: each is confined to the data root (or names an upload).
/// A new key that names a file must be added here, or a client could name any file on the host.
const VOLUME_KEYS: [&str; 7] = crate::scene::VOLUME_FILE_KEYS;
/// The `[[lights]]` key that names a file (an environment light's `map`), confined the same way.
const LIGHT_FILE_KEY: &str = "map";

/// Files uploaded with a scene (multipart parts): their directory and names.
pub struct Uploads<'a> {
    pub dir: &'a Path,
    pub names: &'a [String],
}

/// Validates a scene sent by a client as the CLI would (`lpm solve scene.toml`), with its volume
/// path confined to the data root and made absolute. Returns the text the solve will read.
pub fn prepare_scene(data: &Path, text: &str) -> Result<(String, Scene), ApiError> {
    prepare_scene_with(data, text, None)
}

/// [`prepare_scene`], where a volume path that is exactly the name of an uploaded file names that
/// file.
pub fn prepare_scene_with(data: &Path, text: &str, uploads: Option<&Uploads>) -> Result<(String, Scene), ApiError> {
    let mut value: toml::Table = match toml::from_str(text) {
        Ok(v) => v,
        // Let the scene loader word the syntax error, exactly as the CLI does.
        Err(_) => {
            return match validate(text) {
                Err(e) => Err(e),
                Ok(_) => Err(ApiError::BadRequest("scene.toml: not a TOML table".into())),
            }
        }
    };
    let Some(toml::Value::Table(volume)) = value.get_mut("volume") else { return validate(text) };
    for key in VOLUME_KEYS {
        let Some(toml::Value::String(named)) = volume.get(key) else { continue };
        let bad = |m: String| ApiError::BadRequest(format!("scene.toml: volume.{key}: {m}"));
        let uploaded = uploads.filter(|u| u.names.iter().any(|n| n == named));
        let real = match uploaded {
            Some(u) => u.dir.join(named),
            None => confine_named(data, Path::new(named)).map_err(bad)?,
        };
        // A detached NRRD header names its data file: that file must be under the root too.
        if key == "nrrd" {
            if let Ok(header) = crate::store::nrrd_input::nrrd_header(&real) {
                if let crate::store::nrrd_input::header::DataSource::Detached(file) = &header.data {
                    confine_named(data, file).map_err(|m| bad(format!("its data file: {m}")))?;
                }
            }
        }
        let real = real.to_str().ok_or_else(|| bad("the path is not UTF-8".into()))?.to_string();
        volume.insert(key.into(), toml::Value::String(real));
    }
    // An environment light's map is a file too.
    if let Some(toml::Value::Array(lights)) = value.get_mut("lights") {
        for (i, light) in lights.iter_mut().enumerate() {
            let toml::Value::Table(light) = light else { continue };
            let Some(toml::Value::String(named)) = light.get(LIGHT_FILE_KEY) else { continue };
            let bad = |m: String| ApiError::BadRequest(format!("scene.toml: lights[{i}].{LIGHT_FILE_KEY}: {m}"));
            let real = match uploads.filter(|u| u.names.iter().any(|n| n == named)) {
                Some(u) => u.dir.join(named),
                None => confine_named(data, Path::new(named)).map_err(bad)?,
            };
            let real = real.to_str().ok_or_else(|| bad("the path is not UTF-8".into()))?.to_string();
            light.insert(LIGHT_FILE_KEY.into(), toml::Value::String(real));
        }
    }
    // Written anew with the confined absolute path (positions in a later message refer to this text).
    let text = toml::to_string(&value).map_err(|e| ApiError::Internal(format!("cannot write the scene: {e}")))?;
    validate(&text)
}

/// `path` confined to the data root, or why not (in words).
fn confine_named(data: &Path, path: &Path) -> Result<std::path::PathBuf, String> {
    confine::confine(data, path).map_err(|e| match e {
        ConfineError::Unresolvable { path, reason } => format!("{path}: {reason}"),
        e => e.to_string(),
    })
}

/// The scene as `lpm solve scene.toml` would load it: the same checks, the same message.
fn validate(text: &str) -> Result<(String, Scene), ApiError> {
    let scene = Scene::from_toml_str(text, Path::new("scene.toml")).map_err(|e| ApiError::BadRequest(e.to_string()))?;
    Ok((text.to_string(), scene))
}
