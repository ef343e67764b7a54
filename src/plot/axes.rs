//! Axis ranges, ticks and tick labels, for linear and log10 scales.
//!
//! A log axis puts a labelled tick on every decade inside its range (every n-th decade when the
//! range spans more than [`MAX_LOG_LABELS`] decades) and unlabelled minor ticks at 2..9 × each
//! decade. A linear axis puts about five ticks at multiples of 1, 2 or 5 × 10^k. The range of an
//! axis is the data range padded by 5 % of its span on each side (in log10 units on a log axis); a
//! degenerate range (one value) is widened around the value.

/// Most labelled decades on a log axis before every n-th decade is labelled instead.
pub const MAX_LOG_LABELS: i32 = 8;

const PAD: f64 = 0.05;

/// One fitted axis: its range in data units, its ticks and the labels of its major ticks.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    pub log: bool,
    /// Lower end of the axis, in data units (positive on a log axis).
    pub lo: f64,
    /// Upper end of the axis, in data units; `hi > lo`.
    pub hi: f64,
    /// Labelled ticks, inside `lo..=hi`, increasing.
    pub major: Vec<f64>,
    /// Unlabelled ticks, inside `lo..=hi`, increasing.
    pub minor: Vec<f64>,
    /// One label per major tick.
    pub labels: Vec<String>,
}

impl Axis {
    /// Fits an axis to `values` (finite, and positive on a log axis; others are ignored). With no
    /// usable value the axis spans 1..10 (log) or 0..1 (linear).
    pub fn fit(values: impl IntoIterator<Item = f64>, log: bool) -> Axis {
        let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values.into_iter().filter(|v| v.is_finite() && (!log || *v > 0.0)) {
            min = min.min(v);
            max = max.max(v);
        }
        if log {
            fit_log(min, max)
        } else {
            fit_linear(min, max)
        }
    }

    /// Where `v` lies along the axis: 0 at `lo`, 1 at `hi` (in log10 units on a log axis).
    pub fn frac(&self, v: f64) -> f64 {
        if self.log {
            let (a, b) = (self.lo.log10(), self.hi.log10());
            (v.log10() - a) / (b - a)
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }
}

fn fit_log(min: f64, max: f64) -> Axis {
    let (mut a, mut b) = if min <= max { (min.log10(), max.log10()) } else { (0.0, 1.0) };
    let span = b - a;
    if min > max {
        // No data: exactly one decade.
    } else if span < 1e-9 {
        a -= 0.5;
        b += 0.5;
    } else {
        a -= PAD * span;
        b += PAD * span;
    }
    // Fewer than two decades inside: widen to the enclosing decades so the axis has labels.
    if (b + 1e-9).floor() - (a - 1e-9).ceil() < 1.0 {
        a = (a + 1e-9).floor();
        b = (b - 1e-9).ceil().max(a + 1.0);
    }
    let (lo, hi) = (10f64.powf(a), 10f64.powf(b));
    let (lo, hi) = if lo > 0.0 && hi.is_finite() && hi > lo { (lo, hi) } else { (1.0, 10.0) };
    let major = log_ticks(lo, hi);
    let labels = major.iter().map(|&v| log_label(v)).collect();
    Axis { log: true, lo, hi, minor: log_minor_ticks(lo, hi), major, labels }
}

fn fit_linear(min: f64, max: f64) -> Axis {
    let (mut lo, mut hi) = if min <= max { (min, max) } else { (0.0, 1.0) };
    let span = hi - lo;
    if min > max {
        // No data: exactly 0..1.
    } else if span <= 1e-12 * lo.abs().max(hi.abs()) || span == 0.0 {
        let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        lo -= d;
        hi += d;
    } else {
        lo -= PAD * span;
        hi += PAD * span;
    }
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        (lo, hi) = (0.0, 1.0);
    }
    let (major, step) = linear_ticks_with_step(lo, hi);
    let labels = linear_labels(&major, step);
    Axis { log: false, lo, hi, major, minor: Vec::new(), labels }
}

/// 10^e, exactly as the literal `1e{e}` parses.
fn decade(e: i32) -> f64 {
    format!("1e{e}").parse().unwrap_or_else(|_| 10f64.powi(e))
}

/// The decade exponents inside `lo..=hi` and the labelling step (every `step`-th decade).
fn decades(lo: f64, hi: f64) -> Option<(i32, i32, i32)> {
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        return None;
    }
    let e0 = (lo.log10() - 1e-9).ceil() as i32;
    let e1 = (hi.log10() + 1e-9).floor() as i32;
    if e1 < e0 {
        return None;
    }
    let n = e1 - e0 + 1;
    let step = (n + MAX_LOG_LABELS - 1) / MAX_LOG_LABELS;
    Some((e0, e1, step.max(1)))
}

/// The labelled ticks of a log axis spanning `lo..=hi`: the powers of ten inside the range (every
/// n-th power when there are more than [`MAX_LOG_LABELS`]). For 3e-4..20: 1e-3, 1e-2, 0.1, 1, 10.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    match decades(lo, hi) {
        Some((e0, e1, step)) => (e0..=e1).filter(|e| e.rem_euclid(step) == 0).map(decade).collect(),
        None => Vec::new(),
    }
}

/// The unlabelled ticks of a log axis: 2..9 × 10^k inside `lo..=hi` when every decade is labelled,
/// otherwise the unlabelled decades.
pub fn log_minor_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    match decades(lo, hi) {
        Some((e0, e1, step)) if step > 1 => (e0..=e1).filter(|e| e.rem_euclid(step) != 0).map(decade).collect(),
        _ => {
            let first = (lo.log10() + 1e-9).floor() as i32;
            let last = (hi.log10() - 1e-9).floor() as i32;
            let mut ticks = Vec::new();
            for e in first..=last {
                for m in 2..=9 {
                    let v = f64::from(m) * decade(e);
                    if v >= lo * (1.0 - 1e-12) && v <= hi * (1.0 + 1e-12) {
                        ticks.push(v);
                    }
                }
            }
            ticks
        }
    }
}

/// The label of a power of ten on a log axis: `0.1`, `1`, `10`, `100` written out, others as `1e-3`,
/// `1e3`.
pub fn log_label(v: f64) -> String {
    let e = v.log10().round() as i32;
    match e {
        -1 => "0.1".to_string(),
        0 => "1".to_string(),
        1 => "10".to_string(),
        2 => "100".to_string(),
        _ => format!("1e{e}"),
    }
}

/// A 1, 2 or 5 × 10^k step near `raw`.
pub fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let e = (raw.log10() + 1e-9).floor() as i32;
    let mag = decade(e);
    let norm = raw / mag;
    let m = if norm < 1.5 {
        1.0
    } else if norm < 3.5 {
        2.0
    } else if norm < 7.5 {
        5.0
    } else {
        10.0
    };
    m * mag
}

/// About five ticks at multiples of a 1/2/5 × 10^k step inside `lo..=hi`.
pub fn linear_ticks(lo: f64, hi: f64) -> Vec<f64> {
    linear_ticks_with_step(lo, hi).0
}

fn linear_ticks_with_step(lo: f64, hi: f64) -> (Vec<f64>, f64) {
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return (Vec::new(), 1.0);
    }
    let step = nice_step((hi - lo) / 5.0);
    let k0 = (lo / step - 1e-9).ceil();
    let k1 = (hi / step + 1e-9).floor();
    if !(k0.is_finite() && k1.is_finite()) || k1 - k0 > 100.0 {
        return (Vec::new(), step);
    }
    let ticks = (k0 as i64..=k1 as i64).map(|k| if k == 0 { 0.0 } else { k as f64 * step }).collect();
    (ticks, step)
}

/// Labels for linear ticks `step` apart: fixed-point with as many decimals as the step needs, or
/// scientific when the values are very large or very small.
pub fn linear_labels(ticks: &[f64], step: f64) -> Vec<String> {
    let max_abs = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let step_e = (step.log10() + 1e-9).floor() as i32;
    let scientific = max_abs >= 1e6 || (max_abs > 0.0 && max_abs < 1e-3);
    ticks
        .iter()
        .map(|&v| {
            let s = if scientific && v == 0.0 {
                "0".to_string()
            } else if scientific {
                let e = (max_abs.log10() + 1e-9).floor() as i32;
                let digits = (e - step_e).clamp(0, 6) as usize;
                format!("{v:.digits$e}")
            } else {
                let decimals = (-step_e).max(0) as usize;
                format!("{v:.decimals$}")
            };
            // No "-0" or "-0.00".
            if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
                s[1..].to_string()
            } else {
                s
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_log_ticks_are_the_decades_in_range() {
        assert_eq!(log_ticks(3e-4, 20.0), vec![1e-3, 1e-2, 1e-1, 1.0, 10.0]);
        assert_eq!(log_ticks(1.0, 10.0), vec![1.0, 10.0]);
        assert!(log_ticks(2.0, 8.0).is_empty());
        assert!(log_ticks(-1.0, 8.0).is_empty());
        let wide = log_ticks(1e-30, 1e30);
        assert!(wide.len() <= MAX_LOG_LABELS as usize + 1, "{wide:?}");
    }

    #[test]
    fn plot_log_minor_ticks() {
        let m = log_minor_ticks(0.5, 30.0);
        assert_eq!(m.len(), 5 + 8 + 2); // 0.5..0.9, 2..9, 20 30
        assert!(m.contains(&0.5) && m.contains(&30.0) && !m.contains(&1.0));
    }

    #[test]
    fn plot_labels() {
        let labels: Vec<String> = [1e-3, 1e-2, 0.1, 1.0, 10.0, 1e3].iter().map(|&v| log_label(v)).collect();
        assert_eq!(labels, ["1e-3", "1e-2", "0.1", "1", "10", "1e3"]);
        assert_eq!(linear_labels(&[0.0, 0.5, 1.0], 0.5), ["0.0", "0.5", "1.0"]);
        assert_eq!(linear_labels(&[-20.0, 0.0, 20.0], 20.0), ["-20", "0", "20"]);
        assert_eq!(linear_labels(&[2e6, 4e6], 2e6), ["2e6", "4e6"]);
    }

    #[test]
    fn plot_linear_ticks_are_nice() {
        assert_eq!(linear_ticks(0.0, 1.0), vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]);
        assert_eq!(linear_ticks(-3.0, 47.0), vec![0.0, 10.0, 20.0, 30.0, 40.0]);
        assert!(linear_ticks(1.0, 1.0).is_empty());
    }

    #[test]
    fn plot_fit_handles_degenerate_and_empty_ranges() {
        let a = Axis::fit([5.0], true);
        assert!(a.lo < 5.0 && a.hi > 5.0 && a.major.len() >= 2);
        let a = Axis::fit([5.0], false);
        assert!(a.lo < 5.0 && a.hi > 5.0 && !a.major.is_empty());
        let a = Axis::fit([0.0], false);
        assert!(a.lo < 0.0 && a.hi > 0.0);
        let a = Axis::fit([], true);
        assert_eq!((a.lo, a.hi), (1.0, 10.0));
        let a = Axis::fit([f64::NAN, -1.0], true);
        assert_eq!((a.lo, a.hi, a.major.len()), (1.0, 10.0, 2));
        let a = Axis::fit([], false);
        assert_eq!((a.lo, a.hi), (0.0, 1.0));
        let a = Axis::fit([3e-4, 20.0], true);
        assert_eq!(a.major, vec![1e-3, 1e-2, 1e-1, 1.0, 10.0]);
        assert!((a.frac(3e-4) - 0.05 / 1.1).abs() < 1e-12);
    }
}
