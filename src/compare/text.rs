//! The human-readable form of a [`Comparison`]: a few header lines and a table of metrics.

use super::{Comparison, Metrics};
use std::fmt;

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.3e}"))
}

fn row(f: &mut fmt::Formatter<'_>, name: &str, m: &Metrics, extra: &str) -> fmt::Result {
    let line = format!(
        "{name:<9} {:>11} {:>11} {:>11} {:>11} {:>11}  {extra}",
        cell(m.relative_l2),
        cell(m.rmse),
        cell(m.max_relative_error),
        cell(m.mean_bias),
        m.values
    );
    writeln!(f, "{}", line.trim_end())
}

impl fmt::Display for Comparison {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let fl = &self.fluence;
        writeln!(f, "candidate  {}", self.candidate)?;
        writeln!(f, "reference  {}", self.reference)?;
        let [nx, ny, nz] = fl.dims;
        write!(
            f,
            "fluence    {nx}×{ny}×{nz}, {} component(s); {} of {} voxels compared",
            fl.components, fl.voxels_used, fl.voxels_total
        )?;
        match fl.max_relative_stderr {
            Some(t) => write!(
                f,
                " ({} excluded: reference fluence ≤ 0 or relative standard error > {t}",
                fl.voxels_excluded - fl.voxels_not_solved
            )?,
            None => write!(f, " (the reference has no standard errors")?,
        }
        if fl.voxels_not_solved > 0 {
            write!(f, "; {} not solved: empty bricks", fl.voxels_not_solved)?;
        }
        writeln!(f, ")")?;
        writeln!(f)?;
        writeln!(f, "{:<9} {:>11} {:>11} {:>11} {:>11} {:>11}", "", "rel. L2", "RMSE", "max rel.", "bias", "values")?;
        row(f, "fluence", &fl.metrics, "")?;
        if let Some(core) = &fl.core {
            let extra =
                format!("densest {:.0} % (density ≥ {:.4})", 100.0 * (1.0 - core.quantile), core.density_threshold);
            row(f, "core", &core.metrics, &extra)?;
        }
        if let Some(img) = &self.image {
            row(f, "image", &img.metrics, &format!("{}×{} px", img.width, img.height))?;
            let b = img.block;
            row(f, "blocks", &img.blocks, &format!("{b}×{b}-pixel block means"))?;
            row(f, "medium", &img.medium_blocks, &format!("{b}×{b} blocks where the candidate's alpha ≥ 0.5"))?;
        }
        if let (Some(noise), Some(corrected)) = (fl.reference_noise_relative_l2, fl.noise_corrected_relative_l2) {
            writeln!(
                f,
                "reference noise alone gives rel. L2 {noise:.3e}; with it taken out the fluence error is {corrected:.3e}"
            )?;
        }
        for note in &self.notes {
            writeln!(f, "note: {note}")?;
        }
        Ok(())
    }
}
