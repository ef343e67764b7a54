//! The solver's fields in the brick store ([`StoreFields`]: the GPU driver's), and checkpoints. The
//! host passes between orders over them are [`super::passes`], shared with the CPU twin.
//!
//! Every field covers the occupied bricks only: empty bricks hold no medium, so nothing scatters
//! there and nothing is solved there (their fluence is exported as NaN, "not solved"). Sources have
//! storage directions × channels components per voxel, fluence has channels.
//!
//! Each order accumulates into fields of its own: `source_next` (the next order's source) and
//! `fluence` (this order's fluence), both zero when the order starts. The committed results —
//! `source_total` and `fluence_total` — have a spare copy each: the pass at the end of an order
//! writes `committed + this order` into the spares; a checkpoint flushes them, and only then writes
//! `checkpoint.json` (atomically) naming the spares as committed. Nothing a checkpoint names is
//! written afterwards until the next checkpoint replaces it, so a solve killed at any moment
//! resumes from its last checkpoint and ends bitwise identical to an uninterrupted one (which
//! runs the very same passes).
//!
//! Checkpoints follow the cadence of [`crate::scene::CheckpointCadence`] (`solver.checkpoint_every_orders` /
//! `solver.checkpoint_every_seconds`), not necessarily every order: flushing the committed fields
//! writes them to disk, which on a large store costs more than a GPU's order. Between two
//! checkpoints the passes keep off what the last one names ([`Named`]); the last order of a solve
//! is always checkpointed.
//!
//! A checkpoint is written in the background ([`OrderFieldSet::start_checkpoint`]): a thread syncs
//! the named fields' files and then writes `checkpoint.json`, while the next order's sweeps run
//! (they write only the order's own accumulators). Until it is on disk, the fields of the
//! checkpoint before it stay protected too (`named_previous`: a crash in that window resumes from
//! that one), and the next commit, the first pass that could write them, waits for it. The last
//! checkpoint of a solve is waited for at once.

use super::energy::Tallies;
use super::exitance::ExitMaps;
use super::orders::OrderRecord;
use super::passes::{Named, OrderFieldSet};
use super::periodic::PeriodicCarry;
use super::plan::Plan;
use super::remaining::RemainingError;
use super::SolveError;
use crate::store::{BrickStore, Coverage, Field, StoreError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

const CHECKPOINT: &str = "checkpoint.json";
/// 2: fluence covers the occupied bricks only (version 1 stored it for every brick); 3: a third
/// source file (`source_scratch`, the diffusion correction's output) rotates with the other two; 4:
/// the boundary tallies are split by the faces of the volume; 5: an accelerated solve's last
/// diffusion correction is saved beside it (`correction_<orders>.f64`); what periodic sweeps
/// carry over is saved too (`carry_<orders>.f64`, optional: an older version-5 checkpoint has none),
/// and so are the exitance maps (`exits_<orders>.f64`, optional in the same way) and the last
/// order's remaining error (`state.last_remaining`, optional too: see `run_orders`).
const CHECKPOINT_VERSION: u32 = 5;

/// The solver's fields as files of f32 in the brick store.
pub type StoreFields = OrderFieldSet<Field>;

/// The order loop's state after a completed order, as saved in `checkpoint.json`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct LoopState {
    /// Orders completed (the next order to propagate).
    pub orders_done: u32,
    /// The boundary power in and out so far, in all and per face.
    pub tallies: Tallies,
    /// The power injected so far and by the last order: scattered into the next order's source,
    /// plus what periodic sweeps carry into the next order ([`super::periodic`]).
    pub total_power: [f64; 3],
    pub last_new_power: [f64; 3],
    /// Of `last_new_power`, what periodic sweeps carry into the next order (not in any source).
    #[serde(default)]
    pub last_carried_power: [f64; 3],
    /// Per channel, the new power of the order before the last, and the ratio of the last two
    /// (for the tail estimate).
    #[serde(default)]
    pub previous_new_power: [f64; 3],
    #[serde(default)]
    pub previous_ratio: [f64; 3],
    pub history: Vec<OrderRecord>,
    /// The solve started from a guess ([`super::warm`]); kept so that a resumed warm solve closes
    /// its energy balance the same way.
    #[serde(default)]
    pub warm_start: bool,
    /// The power the point lights gave the medium before order 0 ([`super::point`]): computed
    /// once by a fresh solve and kept here, so that a resumed solve (which writes nothing before
    /// its orders) closes its energy books the same way.
    #[serde(default)]
    pub point_light_power: [f64; 3],
    /// The traced emission's power ([`super::uncollided`]): what it put out, and what of it left
    /// without interacting; kept like `point_light_power`.
    #[serde(default)]
    pub uncollided_emitted: [f64; 3],
    #[serde(default)]
    pub uncollided_escaped: [f64; 3],
    /// Per face and channel, the power the last order's rays carried out (the tail's split over
    /// the faces, [`super::orders::TailEstimate::face_out`]).
    #[serde(default)]
    pub last_face_out: [[f64; 3]; 6],
    /// The stop rule's remaining error after the last order (max and l2), as the order loop
    /// measured it ([`super::orders::run_orders`]; `None` while no ratio was known). A solve
    /// resumed after its last order (killed in the export or the render) reports this one rather
    /// than measuring again: the measure depends on the loop state it was taken in (the tail
    /// factors read the history before the order's record joined it). Absent from the
    /// checkpoints of earlier versions (see `run_orders`).
    #[serde(default)]
    pub last_remaining: Option<RemainingError>,
}

impl LoopState {
    pub fn tallies(&self) -> Tallies {
        self.tallies
    }
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    version: u32,
    /// Identifies the scene and plan the fields belong to.
    digest: String,
    /// Field file names in their current roles.
    source_prev: String,
    source_next: String,
    source_scratch: String,
    source_total: String,
    source_spare: String,
    fluence_total: String,
    fluence_spare: String,
    /// The file holding the last diffusion correction of an accelerated solve
    /// ([`super::acceleration`]): f64 little-endian, channel after channel.
    #[serde(default)]
    correction: Option<String>,
    /// The file holding what periodic sweeps carry into the next order
    /// ([`super::periodic::PeriodicCarry::to_bytes`]); none when nothing is carried.
    #[serde(default)]
    carry: Option<String>,
    /// The file holding the exitance maps of the orders done ([`ExitMaps::to_bytes`]); none when
    /// the solve makes no maps.
    #[serde(default)]
    exits: Option<String>,
    state: LoopState,
}

/// The correction file of the checkpoint after `orders` orders.
fn correction_file(orders: u32) -> String {
    format!("correction_{orders}.f64")
}

/// The carried-ray-state file of the checkpoint after `orders` orders.
fn carry_file(orders: u32) -> String {
    format!("carry_{orders}.f64")
}

/// The exitance maps' file of the checkpoint after `orders` orders.
fn exits_file(orders: u32) -> String {
    format!("exits_{orders}.f64")
}

impl OrderFieldSet<Field> {
    /// Fresh, zero fields.
    pub fn create(store: &BrickStore, plan: &Plan) -> Result<Self, SolveError> {
        let comps = plan.source_components();
        let c = plan.channels;
        Ok(OrderFieldSet {
            source_prev: store.create_field("source_a", comps, Coverage::Occupied)?,
            source_next: store.create_field("source_b", comps, Coverage::Occupied)?,
            source_scratch: store.create_field("source_c", comps, Coverage::Occupied)?,
            fluence: store.create_field("fluence_order", c, Coverage::Occupied)?,
            source_total: store.create_field("total_a", comps, Coverage::Occupied)?,
            source_spare: store.create_field("total_b", comps, Coverage::Occupied)?,
            fluence_total: store.create_field("fluence_a", c, Coverage::Occupied)?,
            fluence_spare: store.create_field("fluence_b", c, Coverage::Occupied)?,
            clean: true,
            seeded: false,
            initial_guess: false,
            warm_started: false,
            named: Named::default(),
            named_previous: Named::default(),
            acceleration: None,
            resumed_correction: None,
            resumed_carry: None,
            resumed_exits: None,
        })
    }

    /// Reopens the fields of `store` in the roles its checkpoint names, with the saved loop state;
    /// `None` when the store holds no checkpoint.
    pub fn resume(store: &BrickStore, plan: &Plan, digest: &str) -> Result<Option<(Self, LoopState)>, SolveError> {
        let path = store.dir().join(CHECKPOINT);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(StoreError::Io { path, action: "read", source }.into()),
        };
        let cp: Checkpoint =
            serde_json::from_str(&text).map_err(|source| StoreError::Json { path: path.clone(), source })?;
        if cp.version != CHECKPOINT_VERSION || cp.digest != digest {
            return Err(SolveError::CheckpointMismatch { path });
        }
        let comps = plan.source_components();
        let c = plan.channels;
        let read = |name: &str| -> Result<(PathBuf, Vec<u8>), SolveError> {
            let path = store.dir().join(name);
            let bytes = std::fs::read(&path).map_err(StoreError::io(&path, "read"))?;
            Ok((path, bytes))
        };
        let resumed_carry = match &cp.carry {
            None => None,
            Some(name) => {
                let (path, bytes) = read(name)?;
                Some(PeriodicCarry::from_bytes(plan, &bytes).ok_or(SolveError::CheckpointMismatch { path })?)
            }
        };
        let resumed_exits = match &cp.exits {
            None => None,
            Some(name) => {
                let (path, bytes) = read(name)?;
                let maps = ExitMaps::from_bytes(plan.dims, plan.channels as usize, &bytes);
                Some(maps.ok_or(SolveError::CheckpointMismatch { path })?)
            }
        };
        let resumed_correction = match &cp.correction {
            None => None,
            Some(name) => {
                let (path, bytes) = read(name)?;
                if bytes.len() % 8 != 0 {
                    return Err(SolveError::CheckpointMismatch { path });
                }
                let values =
                    bytes.chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8]))).collect();
                Some((path, values))
            }
        };
        let fields = OrderFieldSet {
            source_prev: store.open_field(&cp.source_prev, comps, Coverage::Occupied)?,
            source_next: store.open_field(&cp.source_next, comps, Coverage::Occupied)?,
            source_scratch: store.open_field(&cp.source_scratch, comps, Coverage::Occupied)?,
            fluence: store.open_field("fluence_order", c, Coverage::Occupied)?,
            source_total: store.open_field(&cp.source_total, comps, Coverage::Occupied)?,
            source_spare: store.open_field(&cp.source_spare, comps, Coverage::Occupied)?,
            fluence_total: store.open_field(&cp.fluence_total, c, Coverage::Occupied)?,
            fluence_spare: store.open_field(&cp.fluence_spare, c, Coverage::Occupied)?,
            clean: false,
            seeded: false,
            initial_guess: false,
            warm_started: cp.state.warm_start,
            named: Named::after_checkpoint(),
            named_previous: Named::default(),
            acceleration: None,
            resumed_correction,
            resumed_carry,
            resumed_exits,
        };
        // A killed order's partial sums are cleared when the next order begins; the order fields
        // still hold the last completed order's (the tail estimate may need its fluence).
        Ok(Some((fields, cp.state)))
    }

    /// Flushes the committed state and records it in `checkpoint.json` (atomically), waiting for
    /// both; until the next checkpoint, no order writes what this one names (see [`Named`]).
    pub fn write_checkpoint(&mut self, dir: &Path, digest: &str, state: &LoopState) -> Result<(), SolveError> {
        self.start_checkpoint(dir, digest, state, None, None)?.finish()?;
        self.checkpoint_on_disk();
        Ok(())
    }

    /// Starts writing a checkpoint of the state in a background thread: the files of the fields
    /// it names are synced to disk, then the correction (when accelerated), what periodic sweeps
    /// carry into the next order (`carry`, when anything), the exitance maps of the orders the
    /// state holds (`exits`, [`ExitMaps::to_bytes`] taken when that order ended) and
    /// `checkpoint.json` are written (atomically). The caller goes on with the next order's
    /// sweeps, which write no field this checkpoint or the one before it names ([`Named`]); before
    /// the next commit (the first pass that could write one of the older checkpoint's fields) it
    /// waits for [`PendingCheckpoint::finish`] and calls [`OrderFieldSet::checkpoint_on_disk`].
    pub fn start_checkpoint(
        &mut self,
        dir: &Path,
        digest: &str,
        state: &LoopState,
        carry: Option<&PeriodicCarry>,
        exits: Option<Vec<u8>>,
    ) -> Result<PendingCheckpoint, SolveError> {
        let mut state = state.clone();
        state.warm_start = self.warm_started;
        // The correction under a name of its own: the checkpoint that names it is written after
        // it, and the previous one's file is removed only then.
        let correction = self.acceleration.as_ref().map(|acceleration| {
            let name = correction_file(state.orders_done);
            let bytes: Vec<u8> = acceleration.correction_values().iter().flat_map(|v| v.to_le_bytes()).collect();
            (name, bytes)
        });
        let carry = carry.filter(|c| !c.is_empty()).map(|c| (carry_file(state.orders_done), c.to_bytes()));
        let exits = exits.map(|bytes| (exits_file(state.orders_done), bytes));
        let cp = Checkpoint {
            version: CHECKPOINT_VERSION,
            digest: digest.to_string(),
            source_prev: self.source_prev.name().to_string(),
            source_next: self.source_next.name().to_string(),
            source_scratch: self.source_scratch.name().to_string(),
            source_total: self.source_total.name().to_string(),
            source_spare: self.source_spare.name().to_string(),
            fluence_total: self.fluence_total.name().to_string(),
            fluence_spare: self.fluence_spare.name().to_string(),
            correction: correction.as_ref().map(|(name, _)| name.clone()),
            carry: carry.as_ref().map(|(name, _)| name.clone()),
            exits: exits.as_ref().map(|(name, _)| name.clone()),
            state,
        };
        // The named fields, and the order's fluence (a resumed tail estimate reads the last one).
        let files: Vec<PathBuf> = [&self.source_prev, &self.source_total, &self.fluence_total, &self.fluence]
            .iter()
            .map(|f| f.path().to_path_buf())
            .collect();
        let json_path = dir.join(CHECKPOINT);
        let dir = dir.to_path_buf();
        let spawn_error = |source| {
            SolveError::Checkpoint(crate::output::OutputError::Io {
                path: json_path,
                action: "start the thread that writes",
                source,
            })
        };
        #[cfg(feature = "test-hooks")]
        let delay = std::env::var("LPM_TEST_CHECKPOINT_DELAY_MS").ok().and_then(|v| v.parse::<u64>().ok());
        #[cfg(not(feature = "test-hooks"))]
        let delay: Option<u64> = None;
        // With the hook, the caller goes on only once the fields and the correction are on disk,
        // so that a kill during the delay always finds this checkpoint in flight, all but its json.
        let (written, wait_written) = std::sync::mpsc::channel::<()>();
        let orders = cp.state.orders_done;
        let write = move || -> Result<(), SolveError> {
            let t = std::time::Instant::now();
            // The maps are shared: syncing each file writes back what the solve wrote through
            // them (as an msync of the map would), from a descriptor of this thread's own.
            for path in &files {
                let file = std::fs::File::open(path).map_err(StoreError::io(path, "open for sync"))?;
                file.sync_data().map_err(StoreError::io(path, "sync"))?;
            }
            for (name, bytes) in correction.iter().chain(&carry).chain(&exits) {
                crate::output::write_atomic(&dir.join(name), |w| std::io::Write::write_all(w, bytes))
                    .map_err(SolveError::Checkpoint)?;
            }
            // The kill tests' hook: a checkpoint still being written when the process dies.
            if let Some(ms) = delay {
                let _ = written.send(());
                std::thread::sleep(std::time::Duration::from_millis(ms));
            }
            crate::output::write_json_atomic(&dir.join(CHECKPOINT), &cp).map_err(SolveError::Checkpoint)?;
            if let Some((name, _)) = &correction {
                remove_older(&dir, "correction_", name);
            }
            if let Some((name, _)) = &carry {
                remove_older(&dir, "carry_", name);
            }
            if let Some((name, _)) = &exits {
                remove_older(&dir, "exits_", name);
            }
            tracing::debug!(orders, seconds = t.elapsed().as_secs_f64(), "checkpoint on disk");
            Ok(())
        };
        let handle =
            std::thread::Builder::new().name("lpm-checkpoint".to_string()).spawn(write).map_err(spawn_error)?;
        if delay.is_some() {
            // An error before the send drops the sender: the wait ends and `finish` reports it.
            let _ = wait_written.recv();
        }
        self.checkpoint_started();
        Ok(PendingCheckpoint { handle })
    }
}

/// A checkpoint being written in the background ([`OrderFieldSet::start_checkpoint`]).
pub struct PendingCheckpoint {
    handle: std::thread::JoinHandle<Result<(), SolveError>>,
}

impl PendingCheckpoint {
    /// Waits until the checkpoint is on disk (or its writing failed).
    pub fn finish(self) -> Result<(), SolveError> {
        self.handle.join().unwrap_or(Err(SolveError::Internal("the checkpoint writer panicked")))
    }
}

/// Removes the side files (`prefix….f64`: corrections, carried ray state, exitance maps) of
/// earlier checkpoints, all but `keep`; a file that cannot be removed is only left behind, so
/// failures are logged, not raised.
fn remove_older(dir: &Path, prefix: &str, keep: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        if name != keep && name.starts_with(prefix) && name.ends_with(".f64") {
            if let Err(e) = std::fs::remove_file(entry.path()) {
                tracing::warn!("could not remove the old checkpoint file {}: {e}", entry.path().display());
            }
        }
    }
}
