//! Which way a solve uses the device, as a type: streamed, resident with the passes between
//! orders on the host, or resident with them on the device. Each variant owns the buffers and
//! kernels it uses (the diffusion acceleration's and correction's as parts of the variant that
//! runs them), so the driver never asks at run time whether a buffer exists: it matches on the
//! mode, and a half-built state cannot be written down.
//!
//! Fields are declared in the order they are freed: descriptor sets before the buffers they
//! name. The driver keeps its [`Mode`] after the [`super::resources::DeviceResources`], whose
//! sweep sets bind the resident buffers, and after the streamer, which waits for the last
//! submission when it drops.

use super::accelerate::DeviceAcceleration;
use super::budget::MemoryPlan;
use super::buffers::{DiffusionBuffers, ResidentBuffers, TotalBuffers};
use super::end_of_order::EndPasses;
use super::resources;
use super::transpose::Transposer;
use crate::solver::plan::Plan;
use crate::solver::SolveError;
use crate::store::BrickStore;
use crate::vk::{Buffer, Context};
use std::sync::Arc;

/// How the solve uses the device ([`super::budget::Residency`] chose it).
// One per solve: boxing the large variant would save nothing worth a pointer chase in every match.
#[allow(clippy::large_enum_variant)]
pub enum Mode {
    /// Every pass streams the medium and the fields through the slots.
    Streamed,
    /// The medium and the fields stay on the device for the whole solve.
    Resident(Resident),
}

/// The resident mode's state and what it owns.
pub struct Resident {
    /// Reorders the resident fields for the x sweeps (its sets name `buffers`).
    pub transposer: Transposer,
    /// Where the passes between orders run.
    pub ends: Ends,
    pub buffers: ResidentBuffers,
    /// Whether the medium is on the device yet.
    pub density_loaded: bool,
    /// Whether the resident fields are in the x sweeps' lateral-major order
    /// ([`super::transpose`]) rather than brick order.
    pub lateral: bool,
}

/// Where a resident solve's passes between orders run.
#[allow(clippy::large_enum_variant)] // one per solve, as `Mode`
pub enum Ends {
    /// On the host: the fields come home every order.
    OnHost,
    /// On the device ([`super::end_of_order`]).
    OnDevice(DeviceEnd),
}

/// The passes between orders on the device, their buffers, and where the solve's state is.
pub struct DeviceEnd {
    pub passes: EndPasses,
    /// The diffusion acceleration, when the plan accelerates.
    pub acceleration: Option<Acceleration>,
    pub totals: TotalBuffers,
    pub state: DeviceState,
}

/// The diffusion acceleration's kernels and the buffers they alone use.
pub struct Acceleration {
    pub kernels: DeviceAcceleration,
    pub buffers: DiffusionBuffers,
}

/// Where the committed state of a solve whose passes between orders run on the device is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DeviceState {
    /// Only on the host: the next order loads it (the first order of a solve or a resume).
    OnHost,
    /// On the device after a commit there, `max_abs` the new source's largest value; also on the
    /// host when `home` (brought there for a checkpoint or the end).
    Committed { max_abs: f32, home: bool },
}

impl Mode {
    /// The mode `memory` planned for `plan` over `store`, with its buffers and kernels made.
    pub fn new(ctx: &Arc<Context>, plan: &Plan, memory: &MemoryPlan, store: &BrickStore) -> Result<Mode, SolveError> {
        if !memory.is_resident() {
            return Ok(Mode::Streamed);
        }
        let occupied = memory.slice.occupied_total;
        let buffers = resources::resident_buffers(ctx, plan, memory)?;
        let ends = if memory.ends_on_device() {
            let totals = resources::total_buffers(ctx, plan, memory)?;
            let acceleration = match resources::diffusion_buffers(ctx, plan, memory)? {
                Some(d) => Some(Acceleration {
                    kernels: DeviceAcceleration::new(ctx, &buffers, &totals, &d, occupied)?,
                    buffers: d,
                }),
                None => None,
            };
            Ends::OnDevice(DeviceEnd {
                passes: EndPasses::new(ctx, plan, &buffers, &totals, occupied, store.grid().bricks)?,
                acceleration,
                totals,
                state: DeviceState::OnHost,
            })
        } else {
            Ends::OnHost
        };
        Ok(Mode::Resident(Resident {
            transposer: Transposer::new(ctx, plan, &buffers, occupied)?,
            ends,
            buffers,
            density_loaded: false,
            lateral: false,
        }))
    }

    /// The resident buffers the sweeps compute on (`None`: streamed).
    pub fn resident_buffers(&self) -> Option<&ResidentBuffers> {
        match self {
            Mode::Streamed => None,
            Mode::Resident(r) => Some(&r.buffers),
        }
    }

    /// The passes between orders on the device, when the mode has them.
    pub fn device_end(&self) -> Option<&DeviceEnd> {
        match self {
            Mode::Resident(Resident { ends: Ends::OnDevice(end), .. }) => Some(end),
            _ => None,
        }
    }

    /// The bytes of the buffers the mode owns.
    pub fn buffer_bytes(&self) -> u64 {
        let Mode::Resident(r) = self else { return 0 };
        let mut every: Vec<&Buffer> = r.buffers.all().to_vec();
        if let Ends::OnDevice(end) = &r.ends {
            every.extend(end.totals.every());
            every.extend(end.acceleration.iter().flat_map(|a| a.buffers.every()));
        }
        every.iter().map(|b| b.size()).sum()
    }
}
