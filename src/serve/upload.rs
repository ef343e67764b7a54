//! `POST /v1/jobs` as `multipart/form-data`: the scene and its volume file(s) in one request.
//!
//! The form has one `scene` field (the scene TOML) and one or more `volume` file fields. A volume
//! path in the scene (`volume.raw`, `volume.vdb` or `volume.nrrd`) that is exactly the file name of
//! an uploaded part names that part; for a detached NRRD header send its data file too (under the
//! name the header gives). Any other path is confined to the data root as for a plain scene.
//!
//! The files are streamed, never held in memory, into a fresh staging directory
//! `DATA/uploads/.incoming-XXXX` (removed if anything fails); the scene is validated against them
//! as the CLI would; and inside the transaction that inserts the job, the directory becomes
//! `DATA/jobs/ID/inputs` and the stored scene names the files there. A server killed in the middle
//! leaves at most a staging directory, removed when the next server starts.
//!
//! Limits: the whole body at most `--max-upload` bytes, the scene part at most `--max-body`, and
//! part file names are plain names ([`super::confine::plain_name`]), each at most once.

use super::api::{self, ApiError, Finalize, Reply, Uploads};
use super::confine;
use super::multipart::{self, Multipart, MultipartError};
use super::Shared;
use crate::scene::Scene;
use std::path::{Path, PathBuf};
use tiny_http::Request;

/// The staging directories live here, under the data root.
pub fn uploads_dir(data: &Path) -> PathBuf {
    data.join("uploads")
}

/// Removes staging directories a killed server left (at start-up, before requests are taken).
pub fn remove_stale_staging(data: &Path) {
    let Ok(entries) = std::fs::read_dir(uploads_dir(data)) else { return };
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().starts_with(".incoming-") {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

impl From<MultipartError> for ApiError {
    fn from(e: MultipartError) -> Self {
        match e {
            MultipartError::TooLarge(n) => ApiError::TooLarge(n),
            MultipartError::PartTooLarge { limit, .. } => ApiError::TooLarge(limit),
            MultipartError::Write { .. } => ApiError::Internal(e.to_string()),
            e => ApiError::BadRequest(e.to_string()),
        }
    }
}

/// Reads the form, stages its files, validates the scene and hands it to `enqueue` with what moves
/// the files into the job's directory once its id is known.
pub fn submit_multipart(
    shared: &Shared,
    request: &mut Request,
    enqueue: impl FnOnce(String, Scene, Finalize) -> Result<Reply, ApiError>,
) -> Result<Reply, ApiError> {
    let content_type = request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Content-Type"))
        .map(|h| h.value.as_str().to_string())
        .unwrap_or_default();
    let boundary = multipart::boundary(&content_type)
        .ok_or_else(|| ApiError::BadRequest("multipart/form-data without a boundary".into()))?;
    let limit = shared.opts.max_upload_bytes;
    if request.body_length().is_some_and(|n| n as u64 > limit) {
        return Err(ApiError::TooLarge(limit));
    }
    let root = uploads_dir(&shared.data);
    std::fs::create_dir_all(&root).map_err(|e| ApiError::Internal(format!("cannot create {}: {e}", root.display())))?;
    let staging = tempfile::Builder::new()
        .prefix(".incoming-")
        .tempdir_in(&root)
        .map_err(|e| ApiError::Internal(format!("cannot create a staging directory in {}: {e}", root.display())))?;

    let mut form = Multipart::new(request.as_reader(), &boundary, limit);
    let mut scene: Option<Vec<u8>> = None;
    let mut names: Vec<String> = Vec::new();
    while let Some(part) = form.next_part()? {
        match part.name.as_str() {
            "scene" => {
                if scene.is_some() {
                    return Err(ApiError::BadRequest("multipart: more than one scene part".into()));
                }
                let mut text = Vec::new();
                form.read_part(&part, &mut text, shared.opts.max_body_bytes).map_err(|e| match e {
                    MultipartError::PartTooLarge { .. } => ApiError::TooLarge(shared.opts.max_body_bytes),
                    e => e.into(),
                })?;
                scene = Some(text);
            }
            "volume" => {
                let Some(name) = part.filename.clone() else {
                    return Err(ApiError::BadRequest("multipart: a volume part without a file name".into()));
                };
                if !confine::plain_name(&name) {
                    return Err(ApiError::BadRequest(format!(
                        "multipart: volume file name {name:?}: use letters, digits, '.', '_' and '-' only, not starting with '.'"
                    )));
                }
                if names.contains(&name) {
                    return Err(ApiError::BadRequest(format!("multipart: the volume file {name:?} is sent twice")));
                }
                let path = staging.path().join(&name);
                let file = std::fs::File::create(&path)
                    .map_err(|e| ApiError::Internal(format!("cannot create {}: {e}", path.display())))?;
                let mut writer = std::io::BufWriter::with_capacity(1 << 20, file);
                form.read_part(&part, &mut writer, limit)?;
                let file = writer.into_inner().map_err(|e| ApiError::Internal(format!("{}: {e}", path.display())))?;
                file.sync_all().map_err(|e| ApiError::Internal(format!("{}: {e}", path.display())))?;
                names.push(name);
            }
            other => {
                return Err(ApiError::BadRequest(format!(
                    "multipart: unknown part {other:?} (send a \"scene\" part and \"volume\" file parts)"
                )))
            }
        }
    }
    let Some(scene) = scene else {
        return Err(ApiError::BadRequest("multipart: no \"scene\" part (the scene TOML)".into()));
    };
    let text =
        String::from_utf8(scene).map_err(|_| ApiError::BadRequest("scene.toml: the scene is not UTF-8".into()))?;
    let staged = Uploads { dir: staging.path(), names: &names };
    let (scene_text, scene) = api::prepare_scene_with(&shared.data, &text, Some(&staged))?;

    let mut moved: Option<PathBuf> = None;
    let mut finalize = |id: i64| -> Result<String, ApiError> {
        let job_dir = shared.job_dir(id);
        // A directory for a fresh id is left from a transaction that was rolled back: not a job's.
        let _ = std::fs::remove_dir_all(&job_dir);
        std::fs::create_dir_all(&job_dir)
            .map_err(|e| ApiError::Internal(format!("cannot create {}: {e}", job_dir.display())))?;
        let inputs = job_dir.join("inputs");
        std::fs::rename(staging.path(), &inputs)
            .map_err(|e| ApiError::Internal(format!("cannot move the upload to {}: {e}", inputs.display())))?;
        moved = Some(inputs.clone());
        let there = Uploads { dir: &inputs, names: &names };
        Ok(api::prepare_scene_with(&shared.data, &text, Some(&there))?.0)
    };
    let result = enqueue(scene_text, scene, Some(&mut finalize));
    if result.is_err() {
        // Not queued (the queue is full, say): the files go.
        if let Some(job_dir) = moved.as_deref().and_then(Path::parent) {
            let _ = std::fs::remove_dir_all(job_dir);
        }
    }
    result
}
