//! Publishing a run's outputs as a set: a directory never shows a mix of two runs' files.
//!
//! A run writes every output into a staging directory inside `OUT` ([`Staging`], a fresh
//! `.lpm-staging-<random>`), then [`Staging::commit`]:
//!
//! 1. writes the list of the set's files, `.set`, into the staging directory and fsyncs it;
//! 2. renames the staging directory to `OUT/.lpm-commit` — the commit point, atomic;
//! 3. [`finish_commit`]: removes `report.json`, then every *known* output name ([`KNOWN_OUTPUTS`])
//!    that is not in the new set (so a rerun with `--no-image` leaves no old `image.*`), moves the
//!    new files in (`report.json` last), and removes `.lpm-commit`.
//!
//! `report.json` is present only when the files beside it are one complete set. A run killed
//! before step 2 leaves a staging directory, which the next run removes ([`recover`]); one killed
//! during step 3 leaves `.lpm-commit`, which the next run finishes moving in (step 3 is idempotent,
//! driven by `.set`), so the set that was committed is the one that appears. Files in `OUT` that
//! lpm does not write are never touched.

use super::OutputError;
use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Every file (and directory: `render-data`, `faces`) name `lpm solve` may write into `OUT`.
pub const KNOWN_OUTPUTS: [&str; 13] = [
    "fluence.raw",
    "fluence.json",
    "fluence.nhdr",
    "fluence.vdb",
    "source.raw",
    "source.json",
    "source.nhdr",
    "source.vdb",
    "image.exr",
    "image.png",
    "render-data",
    "faces",
    "report.json",
];
const COMMIT_DIR: &str = ".lpm-commit";
const STAGING_PREFIX: &str = ".lpm-staging-";
const SET_FILE: &str = ".set";
const REPORT: &str = "report.json";

fn io(path: &Path, action: &'static str) -> impl FnOnce(std::io::Error) -> OutputError {
    let path = path.to_path_buf();
    move |source| OutputError::Io { path, action, source }
}

/// What [`recover`] found and did.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Recovery {
    /// Temporary files of a killed write, removed.
    pub temps_removed: usize,
    /// Staging directories of a killed run, removed.
    pub stagings_removed: usize,
    /// A commit interrupted half-way was finished.
    pub commit_finished: bool,
}

/// Cleans `out` after a killed run: finishes an interrupted commit, removes stale staging
/// directories and temporaries. Call only while holding `out`'s [`DirLock`](super::DirLock).
pub fn recover(out: &Path) -> Result<Recovery, OutputError> {
    let mut r = Recovery::default();
    if out.join(COMMIT_DIR).is_dir() {
        finish_commit(out)?;
        r.commit_finished = true;
    }
    r.temps_removed = crate::store::remove_stale_temps(out).map_err(io(out, "remove stale temporary files in"))?;
    for entry in fs::read_dir(out).map_err(io(out, "list"))? {
        let entry = entry.map_err(io(out, "list"))?;
        if entry.file_name().to_string_lossy().starts_with(STAGING_PREFIX) && entry.path().is_dir() {
            fs::remove_dir_all(entry.path()).map_err(io(&entry.path(), "remove the stale staging directory"))?;
            r.stagings_removed += 1;
        }
    }
    if r != Recovery::default() {
        tracing::info!(
            "{}: cleaned up after an interrupted run ({} temporary file(s), {} staging dir(s){})",
            out.display(),
            r.temps_removed,
            r.stagings_removed,
            if r.commit_finished { ", finished publishing its outputs" } else { "" }
        );
    }
    Ok(r)
}

/// A staging directory in `OUT` for one run's outputs; removed on drop unless committed.
#[derive(Debug)]
pub struct Staging {
    out: PathBuf,
    dir: Option<PathBuf>,
}

impl Staging {
    pub fn new(out: &Path) -> Result<Staging, OutputError> {
        let dir = tempfile::Builder::new()
            .prefix(STAGING_PREFIX)
            .tempdir_in(out)
            .map_err(io(out, "create a staging directory in"))?
            .keep();
        Ok(Staging { out: out.to_path_buf(), dir: Some(dir) })
    }

    /// Where the outputs are written.
    pub fn path(&self) -> &Path {
        self.dir.as_deref().unwrap_or(&self.out)
    }

    /// Publishes the staged files named in `outputs` into `OUT` as one set (see the module docs).
    pub fn commit(mut self, outputs: &[String]) -> Result<(), OutputError> {
        let Some(dir) = self.dir.take() else { return Ok(()) };
        let result = (|| {
            for name in outputs {
                let staged = dir.join(name);
                if !KNOWN_OUTPUTS.contains(&name.as_str()) || !(staged.is_file() || staged.is_dir()) {
                    return Err(OutputError::Invalid {
                        path: dir.join(name),
                        message: "not a staged output of this run".to_string(),
                    });
                }
            }
            let set = dir.join(SET_FILE);
            let mut f = File::create(&set).map_err(io(&set, "create"))?;
            f.write_all(outputs.join("\n").as_bytes()).map_err(io(&set, "write"))?;
            f.sync_all().map_err(io(&set, "sync"))?;
            sync_dir(&dir);
            let commit = self.out.join(COMMIT_DIR);
            fs::rename(&dir, &commit).map_err(io(&commit, "rename the staging directory to"))?;
            sync_dir(&self.out);
            Ok(())
        })();
        if result.is_err() {
            let _ = fs::remove_dir_all(&dir);
        }
        result?;
        finish_commit(&self.out)
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if let Some(dir) = self.dir.take() {
            let _ = fs::remove_dir_all(dir);
        }
    }
}

/// Step 3 of a commit (see the module docs); idempotent, so it can be rerun after a kill.
pub fn finish_commit(out: &Path) -> Result<(), OutputError> {
    let commit = out.join(COMMIT_DIR);
    let set_path = commit.join(SET_FILE);
    let text = fs::read_to_string(&set_path).map_err(io(&set_path, "read"))?;
    let set: Vec<&str> = text.lines().filter(|l| KNOWN_OUTPUTS.contains(l)).collect();
    // An output is a file, or a directory (render-data/); a symbolic link is removed, not followed.
    let remove = |name: &str| {
        let path = out.join(name);
        let result = match fs::symlink_metadata(&path) {
            Ok(m) if m.is_dir() => fs::remove_dir_all(&path),
            _ => fs::remove_file(&path),
        };
        match result {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(&path, "remove the old output")(e)),
            _ => Ok(()),
        }
    };
    // First the report: while the set is being replaced, no report vouches for the files.
    if commit.join(REPORT).exists() {
        remove(REPORT)?;
    }
    for name in KNOWN_OUTPUTS.iter().filter(|n| !set.contains(n) && **n != REPORT) {
        remove(name)?;
    }
    let mut names: Vec<&str> = set.iter().copied().filter(|n| *n != REPORT).collect();
    names.push(REPORT);
    for name in names {
        let from = commit.join(name);
        if from.exists() {
            // A rename replaces a file, never a directory: an old directory goes first.
            if from.is_dir() || out.join(name).is_dir() {
                remove(name)?;
            }
            fs::rename(&from, out.join(name)).map_err(io(&out.join(name), "move the new output into place"))?;
        }
    }
    sync_dir(out);
    fs::remove_dir_all(&commit).map_err(io(&commit, "remove"))?;
    Ok(())
}

/// Makes renames in `dir` durable where the platform allows opening a directory (best effort).
fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> =
            fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        v.sort();
        v
    }

    #[test]
    fn a_commit_replaces_the_previous_set_and_leaves_unknown_files() {
        let out = tempfile::tempdir().unwrap();
        for n in ["image.exr", "image.png", "report.json", "fluence.raw", "notes.txt"] {
            fs::write(out.path().join(n), b"old").unwrap();
        }
        let s = Staging::new(out.path()).unwrap();
        for n in ["fluence.raw", "report.json"] {
            fs::write(s.path().join(n), b"new").unwrap();
        }
        s.commit(&["fluence.raw".into(), "report.json".into()]).unwrap();
        assert_eq!(names(out.path()), ["fluence.raw", "notes.txt", "report.json"]);
        assert_eq!(fs::read(out.path().join("fluence.raw")).unwrap(), b"new");
        assert_eq!(fs::read(out.path().join("notes.txt")).unwrap(), b"old");
    }

    #[test]
    fn a_dropped_staging_leaves_nothing() {
        let out = tempfile::tempdir().unwrap();
        let s = Staging::new(out.path()).unwrap();
        fs::write(s.path().join("report.json"), b"x").unwrap();
        drop(s);
        assert!(names(out.path()).is_empty());
    }

    /// A kill in the middle of step 3: half the new set moved in, the old report removed. Recovery
    /// finishes the move; a kill before the commit point leaves the old set, and recovery removes
    /// the staging directory.
    #[test]
    fn recovery_finishes_an_interrupted_commit_and_drops_unfinished_staging() {
        let out = tempfile::tempdir().unwrap();
        let commit = out.path().join(COMMIT_DIR);
        fs::create_dir(&commit).unwrap();
        fs::write(commit.join(SET_FILE), "fluence.raw\nsource.raw\nreport.json").unwrap();
        fs::write(out.path().join("fluence.raw"), b"new").unwrap(); // already moved
        fs::write(out.path().join("image.png"), b"old").unwrap(); // not in the new set
        fs::write(commit.join("source.raw"), b"new").unwrap();
        fs::write(commit.join("report.json"), b"new").unwrap();
        fs::create_dir(out.path().join(".lpm-staging-abc")).unwrap();
        fs::write(out.path().join(".report.json.x1.lpm-tmp"), b"t").unwrap();
        let r = recover(out.path()).unwrap();
        assert_eq!(r, Recovery { temps_removed: 1, stagings_removed: 1, commit_finished: true });
        assert_eq!(names(out.path()), ["fluence.raw", "report.json", "source.raw"]);
        for n in names(out.path()) {
            assert_eq!(fs::read(out.path().join(&n)).unwrap(), b"new", "{n}");
        }
    }
}
