//! The Slurm side of a sweep: an `sbatch --array` script that runs task `$SLURM_ARRAY_TASK_ID`
//! with this same `lpm` executable, and its submission.
//!
//! `--requeue` lets Slurm put a preempted task (or one requeued by `scontrol requeue`, or whose node
//! failed) back in the queue; the rerun continues from the task's checkpoint (see [`super::task`]).
//! Slurm sends SIGTERM before it preempts or times out a task: the solve stops at its next slice
//! with its checkpoint kept (see [`crate::solver::cancel`]).
//! `--open-mode=append` keeps the output of every attempt in one log per task.

use super::{Sweep, SweepError};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// `[slurm]` in the manifest.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlurmSettings {
    /// Time limit per task (`--time`), e.g. "02:00:00".
    pub time: Option<String>,
    /// GPUs per task (`--gres=gpu:N`); 0 or absent: none requested (CPU-only nodes, lavapipe).
    pub gpus: Option<u32>,
    pub cpus_per_task: Option<u32>,
    /// Memory per task (`--mem`), e.g. "32G".
    pub mem: Option<String>,
    pub partition: Option<String>,
    /// Most tasks running at once (`--array=0-N%M`).
    pub max_running: Option<u32>,
    /// More `#SBATCH` options, each as written on the command line.
    #[serde(default)]
    pub extra: Vec<String>,
}

/// Single quotes for a shell word.
fn quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// The script's text. `lpm` is the executable the tasks run.
pub fn script(sweep: &Sweep, lpm: &Path) -> Result<String, SweepError> {
    let s = &sweep.slurm;
    let n = sweep.tasks.len();
    let name: String = sweep
        .manifest
        .file_stem()
        .map(|s| s.to_string_lossy().chars().filter(|c| c.is_ascii_alphanumeric() || *c == '_' || *c == '-').collect())
        .unwrap_or_default();
    let mut lines = vec!["#!/bin/bash".to_string()];
    let mut opt = |o: String| {
        if o.contains('\n') {
            return Err(SweepError::Slurm(format!("slurm option {o:?} spans lines")));
        }
        lines.push(format!("#SBATCH {o}"));
        Ok(())
    };
    opt(format!("--job-name=lpm-{name}"))?;
    opt(format!("--array=0-{}{}", n.saturating_sub(1), s.max_running.map(|m| format!("%{m}")).unwrap_or_default()))?;
    opt("--requeue".into())?;
    opt("--open-mode=append".into())?;
    opt(format!("--output={}", sweep.dir.join("slurm-%A_%a.out").display()))?;
    if let Some(t) = &s.time {
        opt(format!("--time={t}"))?;
    }
    if let Some(g) = s.gpus.filter(|&g| g > 0) {
        opt(format!("--gres=gpu:{g}"))?;
    }
    if let Some(c) = s.cpus_per_task {
        opt(format!("--cpus-per-task={c}"))?;
    }
    if let Some(m) = &s.mem {
        opt(format!("--mem={m}"))?;
    }
    if let Some(p) = &s.partition {
        opt(format!("--partition={p}"))?;
    }
    for e in &s.extra {
        opt(e.clone())?;
    }
    let manifest = sweep.manifest.canonicalize().unwrap_or_else(|_| sweep.manifest.clone());
    lines.push(String::new());
    lines.push("# One task of the sweep; a rerun after preemption or requeue resumes from its checkpoint.".into());
    lines.push("set -euo pipefail".into());
    lines.push(format!(
        "exec {} solve {} --task \"$SLURM_ARRAY_TASK_ID\"",
        quote(&lpm.to_string_lossy()),
        quote(&manifest.to_string_lossy())
    ));
    Ok(lines.join("\n") + "\n")
}

/// Writes `DIR/sweep.sbatch` and returns its path.
pub fn write_script(sweep: &Sweep, lpm: &Path) -> Result<PathBuf, SweepError> {
    let text = script(sweep, lpm)?;
    std::fs::create_dir_all(&sweep.dir).map_err(|source| SweepError::Io { path: sweep.dir.clone(), source })?;
    let path = sweep.dir.join("sweep.sbatch");
    crate::output::write_atomic(&path, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    Ok(path)
}

/// Runs `sbatch --parsable SCRIPT`; returns the job id.
pub fn submit(script: &Path) -> Result<String, SweepError> {
    let out = std::process::Command::new("sbatch")
        .arg("--parsable")
        .arg(script)
        .output()
        .map_err(|e| SweepError::Slurm(format!("cannot run sbatch: {e} (is Slurm installed and on PATH?)")))?;
    if !out.status.success() {
        return Err(SweepError::Slurm(format!(
            "sbatch {} failed: {}",
            script.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let id = text.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() {
        return Err(SweepError::Slurm("sbatch printed no job id".into()));
    }
    Ok(id)
}
