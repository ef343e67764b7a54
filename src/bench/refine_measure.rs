//! The measures of the refinement study ([`super::refine`]), pure functions of the fields: a fine
//! fluence averaged onto the coarse grid, relative L2 over a voxel mask, the observed order and
//! the Richardson extrapolation from three levels refined by 2, and the slope of a log-log fit.

/// `fine` (component fastest, then x, y, z over `fine_dims`, which are multiples of `factor`)
/// averaged over blocks of `factor`³ voxels onto the grid `factor` times coarser. A block with a
/// non-finite value (a voxel of an empty brick, exported as NaN) averages to NaN.
pub fn average_down(fine: &[f32], fine_dims: [u32; 3], components: usize, factor: u32) -> Vec<f64> {
    let f = factor as usize;
    let [nx, ny, nz] = fine_dims.map(|d| d as usize);
    let [cx, cy, cz] = [nx / f, ny / f, nz / f];
    let mut sum = vec![0.0f64; cx * cy * cz * components];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let coarse = ((z / f * cy + y / f) * cx + x / f) * components;
                let fine_at = ((z * ny + y) * nx + x) * components;
                for k in 0..components {
                    sum[coarse + k] += fine[fine_at + k] as f64;
                }
            }
        }
    }
    let blocks = (f * f * f) as f64;
    sum.iter_mut().for_each(|s| *s /= blocks);
    sum
}

/// ‖a − b‖ / ‖b‖ over the voxels of `mask` (`c` components per voxel); `None` when ‖b‖ = 0.
pub fn relative_l2(a: &[f64], b: &[f64], mask: &[bool], c: usize) -> Option<f64> {
    let (mut diff, mut norm) = (0.0, 0.0);
    for (v, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        for k in v * c..(v + 1) * c {
            diff += (a[k] - b[k]).powi(2);
            norm += b[k].powi(2);
        }
    }
    (norm > 0.0).then(|| (diff / norm).sqrt())
}

/// The observed order from three levels refined by 2 each: log₂(‖φ₂ − φ₁‖ / ‖φ₃ − φ₂‖) over
/// `mask`; `None` unless both changes are positive and the later is the smaller.
pub fn observed_order(coarse: &[f64], mid: &[f64], fine: &[f64], mask: &[bool], c: usize) -> Option<f64> {
    let (first, second) = (diff_norm(mid, coarse, mask, c), diff_norm(fine, mid, mask, c));
    (second > 0.0 && first > second).then(|| (first / second).log2())
}

/// The observed order p ([`observed_order`] over `mask`) and the Richardson extrapolation
/// `fine + (fine − mid) / (2^p − 1)` of every value.
pub fn richardson(coarse: &[f64], mid: &[f64], fine: &[f64], mask: &[bool], c: usize) -> Option<(f64, Vec<f64>)> {
    let p = observed_order(coarse, mid, fine, mask, c)?;
    let d = 2f64.powf(p) - 1.0;
    Some((p, fine.iter().zip(mid).map(|(&f, &m)| f + (f - m) / d).collect()))
}

/// ‖a − b‖ over the voxels of `mask`.
fn diff_norm(a: &[f64], b: &[f64], mask: &[bool], c: usize) -> f64 {
    let mut sum = 0.0;
    for (v, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
        sum += (v * c..(v + 1) * c).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
    }
    sum.sqrt()
}

/// The least-squares slope of ln y against ln x over the points with both positive and finite;
/// `None` with fewer than two such points or a single x.
pub fn fit_slope(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = (logs.iter().map(|p| p.0).sum::<f64>() / n, logs.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}
