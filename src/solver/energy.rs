//! Energy bookkeeping: what enters, what leaves, what is absorbed, what is still in flight.
//!
//! Per channel, in watts up to the common factor of the world unit: rays born at the boundary carry
//! `L·h²|ω_a|Ω_i` (a beam: `E·h²|ω_a|`), emission adds `4π·σa·Le·h³` per voxel, absorption takes
//! `σa·φ·h³`, rays leaving the volume take their power with them, and the source of the last order
//! (computed but not propagated) holds `Σ_d Ω_d J^d·h³`. The discretisation conserves energy
//! exactly, so `in + emitted = out + absorbed + unpropagated` to round-off.

use serde::Serialize;

/// Radiance tallies of one sweep, already multiplied by the ray power factors.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tallies {
    pub boundary_in: [f64; 3],
    pub boundary_out: [f64; 3],
}

impl Tallies {
    pub fn add(&mut self, other: &Tallies) {
        for c in 0..3 {
            self.boundary_in[c] += other.boundary_in[c];
            self.boundary_out[c] += other.boundary_out[c];
        }
    }
}

/// The whole solve's balance, per channel (only the first `channels` entries are meaningful).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct EnergyBalance {
    pub boundary_in: [f64; 3],
    pub emitted: [f64; 3],
    pub boundary_out: [f64; 3],
    pub absorbed: [f64; 3],
    /// Scattered power of the last computed order, not propagated further.
    pub unpropagated: [f64; 3],
    /// max over channels of |in + emitted − out − absorbed − unpropagated| / (in + emitted).
    pub relative_imbalance: f64,
}

impl EnergyBalance {
    pub fn new(
        tallies: &Tallies,
        emitted: [f64; 3],
        absorbed: [f64; 3],
        unpropagated: [f64; 3],
        channels: usize,
    ) -> Self {
        let mut worst: f64 = 0.0;
        for c in 0..channels {
            let source = tallies.boundary_in[c] + emitted[c];
            let sink = tallies.boundary_out[c] + absorbed[c] + unpropagated[c];
            if source > 0.0 {
                worst = worst.max((source - sink).abs() / source);
            } else if sink > 0.0 {
                worst = f64::INFINITY;
            }
        }
        EnergyBalance {
            boundary_in: tallies.boundary_in,
            emitted,
            boundary_out: tallies.boundary_out,
            absorbed,
            unpropagated,
            relative_imbalance: worst,
        }
    }
}
