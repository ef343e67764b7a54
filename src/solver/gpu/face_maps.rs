//! The GPU backend's per-face exitance maps ([`crate::solver::exitance`]): what the kernels record
//! of each pass's exits, folded into the maps on the host with the twin's own placement.
//!
//! **Side exits.** `propagate.comp` (with `FLAG_EXITS`) stores the radiance of every ray that
//! leaves through a side, times its share (½ across an edge), where it left: per pass direction
//! and channel, the exits through a side of lateral axis b by (plane t − 1, the ray's lattice
//! column along c at plane t − 1), then those through a side of axis c by (plane t − 1, its column
//! along b). Lattice offsets move by at most one column per plane, so along each axis at most one
//! slot column (row) of a direction wraps between two planes, and a direction's rays hold distinct
//! lattice columns in every plane: each record has exactly one writer, which stores it once. No
//! floating-point atomics, no order to race over: the records are the same bits on every run, and
//! in the resident and streamed modes alike (the kernels compute the same radiances). The host
//! knows from the offsets which planes had wraps ([`FaceSweep::column`]), so it reads only the
//! records written in this pass and the buffer needs no clearing.
//!
//! **Far-face exits.** The ray buffer after a pass's last slice holds what each slot carries out
//! of the far face; it comes home with the tallies (`read_tallies`), and is placed as the twin
//! places it (the last plane's columns and weights; on a periodic sweep axis the shares that
//! leave by a side in the step between periods, [`PeriodStep::side_exits`]).
//!
//! **Why on the host.** The placement (the two-by-two columns and their lattice weights, the
//! vacuum column's halves on the rim pixels, edges half to each side, periodic wraps) is the
//! twin's `exitance::record_exit` called on the recorded values, so the two backends cannot drift
//! apart; the work is a few operations per exit, against the kernels' per-voxel work. The maps
//! are summed in f64 in a fixed order (directions of the pass, then side exits plane by plane,
//! then the far face row by row of slots), so they are the same bits run to run. What it costs is
//! memory: the records of a pass, `directions × channels × planes × (lattice columns along b +
//! along c)` f32 ([`super::sizes::side_exit_cells`]), host-visible, counted by the budget planner
//! (on a tight budget they may cost passes or thinner slices; where no cut fits with them, it
//! drops the maps, not the solve). Folding each slice's records on the device would bound them by
//! a slice's planes instead: the refinement to make if that memory matters for very large
//! volumes.
//!
//! The values are f32 (the kernels' precision); the twin's are f64, so the two backends' maps
//! agree to the f32 propagation's round-off, not bitwise (`tests/it/exitance.rs`).

use crate::solver::energy::volume_face;
use crate::solver::exitance::{record_exit, record_far_exit, Exit, ExitEntry, ExitMaps};
use crate::solver::periodic::PeriodStep;
use crate::solver::plan::SweepDirection;
use crate::solver::sweep::FaceSweep;

/// Side-exit records per direction and channel of `sweep`: planes × (lattice columns along b +
/// along c), the layout `propagate.comp` writes.
pub fn record_stride(sweep: &FaceSweep) -> usize {
    let [lb, lc] = sweep.lattice();
    sweep.n[0] as usize * (lb as usize + lc as usize)
}

/// Adds the exits of one pass of `dirs` through `sweep` to `maps`: `records`, the side exits as
/// the kernel left them (`[dir][ch][`[`record_stride`]`]`), and `far`, what each slot carried out
/// of the far face (the ray buffer: `[dir][ch][ray]`), both for `channels` channels.
pub(super) fn add_pass(
    maps: &mut ExitMaps,
    sweep: &FaceSweep,
    dirs: &[SweepDirection],
    channels: usize,
    records: &[f32],
    far: &[f32],
) {
    for (d, dir) in dirs.iter().enumerate() {
        let mut out = Placed { maps, entries: Vec::new(), power: dir.power_per_radiance };
        add_side_exits(&mut out, sweep, dir, channels, &records[d * channels * record_stride(sweep)..]);
        add_far_exits(&mut out, sweep, dir, channels, &far[d * channels * sweep.rays()..]);
    }
}

/// The exits of one direction being placed: gathered a plane (a row of slots) at a time and then
/// added to the maps, so that the list stays a row's size however wide the lattice (a direction's
/// far face alone would be four entries per ray: 170 MB for a 1024² lattice).
struct Placed<'m> {
    maps: &'m mut ExitMaps,
    entries: Vec<ExitEntry>,
    power: f64,
}

impl Placed<'_> {
    fn flush(&mut self) {
        self.maps.add(&self.entries, self.power);
        self.entries.clear();
    }
}

/// The side exits of `dir` (its `records`, from its first channel's), plane by plane: along each
/// open lateral axis whose offset moved between planes t − 1 and t, one slot column wrapped, each
/// of its rays recorded at its column along the other axis.
fn add_side_exits(out: &mut Placed, sweep: &FaceSweep, dir: &SweepDirection, channels: usize, records: &[f32]) {
    let stride = record_stride(sweep);
    let [lb, lc] = sweep.lattice().map(|l| l as usize);
    let na = sweep.n[0] as usize;
    let lateral = sweep.geometry().lateral;
    // Per axis k: where its records start, and how many columns of the other axis it has.
    let layout = [(0, lc), (na * lc, lb)];
    for t in 1..na {
        let (before, now) = (dir.offsets[t - 1], dir.offsets[t]);
        for k in 0..2 {
            if sweep.periodic[1 + k] || before[k] == now[k] {
                continue;
            }
            // The offset grew: the slot past column n wrapped, leaving through the + side.
            let face = volume_face(lateral[k], now[k] > before[k]);
            let (start, columns) = layout[k];
            for column in 0..columns {
                let mut l = [0.0; 3];
                for (ch, v) in l.iter_mut().enumerate().take(channels) {
                    *v = records[ch * stride + start + (t - 1) * columns + column] as f64;
                }
                // The share is in the record already; only the other axis's column counts.
                let mut at = [0u32; 2];
                at[1 - k] = column as u32;
                let w = dir.weights[t - 1];
                record_exit(&mut out.entries, sweep, face, Exit::Side(k), at, w, t as u32 - 1, 1.0, l);
            }
            out.flush();
        }
    }
}

/// What `dir`'s slots carried out of the far face (`far`, from its first channel's), placed as
/// the twin places it.
fn add_far_exits(out: &mut Placed, sweep: &FaceSweep, dir: &SweepDirection, channels: usize, far: &[f32]) {
    let f = sweep.geometry();
    let far_face = volume_face(f.axis, f.sign > 0.0);
    let [lb, lc] = sweep.lattice();
    let rays = sweep.rays();
    let last = sweep.n[0] - 1;
    let (o, weights) = (dir.offsets[last as usize], dir.weights[last as usize]);
    let period = sweep.periodic[0].then(|| PeriodStep::new(sweep, dir));
    for q in 0..lc {
        let cc = sweep.column(1, q, o[1]).0;
        for p in 0..lb {
            let columns = [sweep.column(0, p, o[0]).0, cc];
            let ray = (q * lb + p) as usize;
            let mut l = [0.0; 3];
            for (ch, v) in l.iter_mut().enumerate().take(channels) {
                *v = far[ch * rays + ray] as f64;
            }
            let sides = period.as_ref().map_or([None; 2], |s| s.side_exits(p as usize, q as usize));
            record_far_exit(&mut out.entries, sweep, far_face, sides, columns, weights, last, l);
        }
        out.flush();
    }
}
