//! Taking the discretisation's numerical diffusion back out of the scattered source
//! (`solver.diffusion_correction = "on"`).
//!
//! **Why.** Every order spreads the scattered light a little further than the physics does. In
//! every plane a ray meets the voxels at a lateral offset from where it really is: the nearest
//! column, off by e ∈ [−½, ½] (`spatial = "constant"`), or the two columns around it with weights
//! (1 − w, w) (`"linear"`), both when it gathers the source and when collect pulls its deposit
//! ([`super::sweep`]). And along the ray, each segment (length s = h/|ω_a| in plane t) takes its
//! voxel's source as one constant and deposits its average over the segment: two spreads of s²/12
//! along ω. One order's spread is small, but in a thick medium of high albedo the light scatters
//! tens to hundreds of times and the spreads add up like a diffusion: light leaks into dense
//! cores too easily and they read bright (+6 % in a cloud's core at 0.8 mean free paths per
//! voxel against Monte Carlo, +6 to +20 % at the centre of thick boxes, `benches/RESULTS.md`),
//! while the error falls like h² with the voxel size h, as a diffusion of variance ∝ h² per order
//! does.
//!
//! **What.** The spread is known from the direction set alone. Per swept direction it is, on each
//! lateral axis, the mean over the direction's planes of the gather's and the deposit's variances,
//! 2e² or 2w(1 − w) (in voxels²), and on every axis i the along-ray spread (ω_i·s)²/6 = δ_i²/6,
//! δ_i = ω_i/|ω_a|; weighted by the directions' fluence weights this gives a variance V_i per
//! volume axis ([`lattice_spread`]). To leading order the order's scattered light comes out as
//! (1 + Σ_i (V_i/2)·∂²_i) applied to the true one. After each order's sweeps, before the source is
//! committed, this pass applies the inverse to leading order with κ_i = V_i/2, as *anti-diffusive
//! fluxes* between voxels that scatter.
//!
//! **Partners two voxels apart.** The second difference that the fluxes form is taken between a
//! voxel and its partners two voxels away along each axis, (u(i − 2) − 2u(i) + u(i + 2))/4 (each
//! flux weighs ¼, [`PARTNER_WEIGHT`]; no flux where the voxel between does not scatter), not
//! between face neighbours. For smooth fields the two are the same Laplacian; they differ at the
//! voxel scale. The face-neighbour stencil multiplies a pattern that alternates from voxel to
//! voxel by 1 + 4·Σκ (about 2 at k = 4) every order, a pattern the lattice does not blur the way
//! the spread model assumes and the diffusion acceleration ([`super::acceleration`]) cannot see:
//! with it, the accelerated series of a 64³ cloud at one mean free path per voxel settled at 0.73
//! per order on such a pattern and took 22 orders to 10⁻⁴ instead of 6. The partner stencil leaves
//! that pattern alone and amplifies no pattern by more than 1 + Σκ (period four voxels): the same
//! cloud converges in 8 orders, its core as close to Monte Carlo (RESULTS).
//!
//! **What is sharpened.** The spreads act on the radiance, which is smooth where the medium jumps
//! (the edge of a dense core), not on the source S = m·(radiance-like u) with m the voxel's
//! scattering weight (density × albedo factor), which jumps with the medium. So the fluxes
//! exchange u = S/m: voxel i hands ¼·κ_i·μ_ij·(u_j − u_i) of source to its partner j along axis i,
//! μ_ij = 2·m_i·m_j/(m_i + m_j) (the harmonic mean, as for conductances in series). In a uniform
//! medium this is ¼·κ_i·(S_j − S_i). Sharpening S itself instead pushed source from the thin side
//! of a core's edge into the dense side every order (up to the per-order positivity cap it then
//! had) and left the core of a 64³ cloud +6 % bright; with u the core is within 0.6 % of Monte
//! Carlo (RESULTS).
//!
//! **Positive, and independent of the path.** The pass sharpens the *committed total* of the
//! scattered source, not each order on its own: C(T) is the total T with the fluxes, each capped
//! at a sixth of the smaller of its two values (a voxel has six partners, so it gives at most
//! what it has and C(T) ≥ 0 wherever T ≥ 0), and what the next order propagates is the change this
//! order's raw source S makes to it, C(T + S) − C(T) ([`sharpen_increment`]); the total itself
//! takes the raw S. The propagated increments add up to C of the total, whatever the orders were:
//! the series converges to the one fixed point of Y = b + K·C(Y) (K: an order's transport and
//! scattering, b: the lights' first scattering), and a warm start's guess, a resumed checkpoint or
//! an octant whose light comes back across its mirrors an order late all end where a cold solve
//! of the whole domain ends. The fluence, the transport of C(Y), is never negative. (Two earlier
//! forms: capping each order's own source made the answer depend on how the orders split the light
//! — warm starts ended up to 5 % from cold solves next to a point light; no cap at all (one
//! linear operator) made a voxel far darker than its neighbours negative: −2·10⁻⁵ of the peak
//! next to a sunlit layer of 1000 mean free paths per voxel.) Where the cap does not bind — a
//! partner at most 1 + 2/(3κ), 8 to 10 times the other — C is linear, and the pass is the plain
//! anti-diffusion described above. The committed source is the raw Y (the estimate of the true
//! in-scattered source; C(Y) is its pre-sharpened copy that the transport blurs back).
//!
//! **Stable in thick voxels.** A voxel of optical thickness τ keeps much of the light it scatters
//! (a share of about 1 − (1 − e^{−x})/x, x = 2τ/3, returns within an order), so a pattern that
//! varies from voxel to voxel is hardly smoothed there by the transport, while the sharpening
//! multiplies it by up to 1 + Σκ per order (with face neighbours it was 1 + 4·Σκ, and at τ ≈ 3
//! and albedo 0.95 such a pattern grew order after order).
//! Each voxel's κ is scaled down just enough to keep that loop's gain at or below
//! [`LARGEST_VOXEL_PATTERN_GROWTH`] ([`Sharpening::stable_share`]): nothing changes up to τ ≈ 1 to
//! 1.3 (by the albedo and the direction set's κ); beyond that the correction thins out (and the
//! thick part keeps some of the excess the correction would remove: a small cloud at τ = 2.5–3
//! per voxel, +33 % → +13 % against Monte Carlo, RESULTS).
//!
//! **Properties.**
//! - *Conservative*: every flux leaves one voxel and enters another (and no flux crosses into a
//!   voxel that does not scatter), so the order's total scattered power is unchanged and the
//!   energy books ([`super::energy`]) are untouched.
//! - *Positive*: C of a non-negative total is non-negative (above), so the propagated light
//!   summed over the orders, and the fluence, are too; a single order's increment may be of
//!   either sign, as a warm start's residuals are.
//! - *Deterministic*: each voxel's new value is its old one plus its six fluxes in a fixed order,
//!   computed from the total and the order's source only (read from them, written to `dst`):
//!   bitwise the same at any thread count, and written once for both backends (the store's
//!   bricks and the twin's voxels are both [`VoxelUnits`]).
//! - *Boundaries*: no flux crosses an open face; across a mirror a partner is a voxel's image
//!   (voxel 0's partner below the face is voxel 1, as in the mirrored domain); across a periodic
//!   axis the partners wrap.
//! - *Second order*: the correction is κ·Δ with κ ∝ (spread in voxels), i.e. O(h²) against a
//!   smooth field, so it changes the constant of the scheme's h² error, not its order.

use super::passes::{FieldPlanes, Medium, StoreMedium, Value, VoxelMedium, RELEASE_UNITS};
use super::plan::{Plan, SweepDirection};
use crate::quadrature::FACES;
use crate::scene::SpatialScheme;
use crate::store::BRICK_EDGE;
use rayon::prelude::*;

/// The fields' units as voxels of the volume: which unit and which voxel of it hold voxel `v`,
/// and the medium's density there. Implemented by the store's medium (a unit is an occupied
/// brick) and the twin's (a unit is a voxel).
pub trait VoxelUnits: Sync {
    type V: Value;
    fn dims(&self) -> [u32; 3];
    /// (unit, voxel within the unit) of voxel `v` (inside the volume), or `None` where no unit
    /// holds it (an empty brick: no medium).
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)>;
    /// The volume coordinates of voxel `local` of unit `unit`.
    fn voxel_of(&self, unit: usize, local: usize) -> [u32; 3];
    /// The density of voxel `local` of unit `unit`.
    fn density_at(&self, unit: usize, local: usize) -> Self::V;
    /// How strongly voxel `local` of unit `unit` scatters, up to a constant per channel: its
    /// density times its albedo factor (`volume.albedo_*`; 1 where the albedo is uniform).
    fn scattering_at(&self, unit: usize, local: usize) -> f64;
}

/// The spread per order the discretisation adds, per volume axis (voxels²): the fluence-weighted
/// mean over the swept directions of the lateral spread, 2e² (constant) or 2w(1 − w) (linear)
/// over their planes on the axes each direction moves across, plus the spread along the ray,
/// δ²/6 on every axis (δ the direction's slope on that axis, 1 on its sweep axis).
pub fn lattice_spread(faces: &[Vec<SweepDirection>], spatial: SpatialScheme) -> [f64; 3] {
    let mut spread = [0.0f64; 3];
    let mut total_weight = 0.0;
    for dir in faces.iter().flatten() {
        let face = FACES[dir.face];
        total_weight += dir.fluence_weight;
        let planes = dir.weights.len().max(1) as f64;
        for (i, &axis) in face.lateral.iter().enumerate() {
            let per_plane = |t: usize| -> f64 {
                match spatial {
                    SpatialScheme::Linear => {
                        let w = dir.weights[t][i];
                        2.0 * w * (1.0 - w)
                    }
                    SpatialScheme::Constant => {
                        // The exact lateral displacement at the middle of plane t is δ·(t + ½)
                        // voxels; the ray meets the nearest column.
                        let d = dir.omega[axis] / dir.omega[face.axis].abs() * (t as f64 + 0.5);
                        let e = d - d.round();
                        2.0 * e * e
                    }
                }
            };
            let mean = (0..dir.weights.len()).map(per_plane).sum::<f64>() / planes;
            spread[axis] += dir.fluence_weight * mean;
        }
        // Along the ray: the segment of plane t (length s = h/|ω_a|) gains the voxel's source as
        // one constant and deposits its average, each a spread of s²/12 along ω; on volume axis i
        // that is (ω_i·s)²/12 = δ_i²/12 twice, δ_i = ω_i/|ω_a| (1 on the sweep axis itself).
        for (axis, s) in spread.iter_mut().enumerate() {
            let slope = dir.omega[axis] / dir.omega[face.axis].abs();
            *s += dir.fluence_weight * slope * slope / 6.0;
        }
    }
    if total_weight > 0.0 {
        spread.map(|s| s / total_weight)
    } else {
        [0.0; 3]
    }
}

/// The anti-diffusion coefficients κ_a = V_a/2 of [`lattice_spread`].
pub fn coefficients(faces: &[Vec<SweepDirection>], spatial: SpatialScheme) -> [f64; 3] {
    lattice_spread(faces, spatial).map(|v| 0.5 * v)
}

/// The plan's side of [`sharpen_increment`]: the coefficients, the axes that wrap, and what the stability
/// limit reads of the medium.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sharpening {
    /// κ per volume axis (voxels²).
    pub kappa: [f64; 3],
    /// The axes whose faces are periodic: partners wrap across them.
    pub periodic: [bool; 3],
    /// Per axis, whether its low and high faces are mirrors: a partner beyond one is a voxel's image.
    pub reflective: [[bool; 2]; 3],
    /// Per channel, the optical thickness σt·h of a voxel at density 1.
    pub thickness: [f64; 3],
    /// Per channel, the medium's albedo (a voxel's is this times its albedo factor).
    pub albedo: [f64; 3],
    /// Channels: component k of a field is channel k mod `channels`.
    pub channels: usize,
}

/// The largest growth per order the stability limit lets the sharpening give a pattern that
/// varies from voxel to voxel (see [`Sharpening::stable_share`]).
pub const LARGEST_VOXEL_PATTERN_GROWTH: f64 = 0.6;

impl Sharpening {
    /// The plan's coefficients, periodic axes and medium.
    pub fn of(plan: &Plan) -> Sharpening {
        Sharpening {
            kappa: plan.diffusion_correction,
            periodic: plan.periodic,
            reflective: plan.reflective,
            thickness: plan.medium.sigma_t.map(|s| s * plan.voxel_size),
            albedo: plan.medium.albedo,
            channels: (plan.channels as usize).max(1),
        }
    }

    /// The share of κ a voxel of `density` and albedo factor `factor` keeps in `channel`: 1 unless
    /// the voxel is optically thick. There a share P of the light a voxel scatters comes back to
    /// it within the next order (P = 1 − (1 − e^{−x})/x, x = 2τ/3: the collision probability of a
    /// cube of optical side τ with its mean chord 2h/3), so a pattern that varies from voxel to
    /// voxel, which the transport hardly smooths there, returns each order with a factor of about
    /// a·P, and the sharpening multiplies it by up to 1 + Σκ. Where their product would pass
    /// [`LARGEST_VOXEL_PATTERN_GROWTH`] κ is scaled down to meet it (to zero in the limit of an
    /// opaque, white voxel): otherwise such a pattern can grow order after order (seen at τ ≈ 3,
    /// albedo 0.95, with the face-neighbour stencil and the bound at 0.8). The lattice's spread,
    /// which κ undoes, is carried by light crossing voxels, which a thick voxel mostly keeps.
    pub fn stable_share(&self, density: f64, factor: f64, channel: usize) -> f64 {
        let x = 2.0 / 3.0 * self.thickness[channel] * density;
        let boost = self.kappa.iter().sum::<f64>();
        // P(x) ≤ x/2: most voxels are thin enough to keep all of κ without the exponential.
        if self.albedo[channel] * factor * 0.5 * x * (1.0 + boost) <= LARGEST_VOXEL_PATTERN_GROWTH {
            return 1.0;
        }
        let returned = if x < SMALL_THICKNESS { 0.5 * x } else { 1.0 + (exp_neg(x) - 1.0) / x };
        let loop_gain = self.albedo[channel] * factor * returned;
        if loop_gain * (1.0 + boost) <= LARGEST_VOXEL_PATTERN_GROWTH || boost <= 0.0 {
            1.0
        } else {
            ((LARGEST_VOXEL_PATTERN_GROWTH / loop_gain - 1.0) / boost).clamp(0.0, 1.0)
        }
    }

    /// The share of κ per channel of a voxel (see [`Self::stable_share`]).
    fn shares<U: VoxelUnits>(&self, units: &U, unit: usize, local: usize, m: f64) -> [f64; 3] {
        let density = units.density_at(unit, local).to_f64();
        let factor = if density > 0.0 { m / density } else { 0.0 };
        std::array::from_fn(|ch| if ch < self.channels { self.stable_share(density, factor, ch) } else { 1.0 })
    }
}

/// Below this x = 2τ/3 the share of its light a voxel keeps is x/2 to within x²/6.
pub const SMALL_THICKNESS: f64 = 1e-6;

/// Where [`exp_neg`] gives 0 (e^−700 ≈ 10⁻³⁰⁴, still a normal f64).
pub const EXP_NEG_LIMIT: f64 = 700.0;

/// ln 2 in two parts (fdlibm's): k·`LN2_HI` is exact for the k [`exp_neg`] meets.
pub const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
pub const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);

/// e^(−x) for x ≥ 0 (0 beyond 700, and for NaN), from additions, multiplications, divisions and
/// an exponent written as bits only: every step is one IEEE operation, so `glsl/sharpen.comp`
/// (which has no f64 exponential) computes the same bits. x = k·ln 2 + r with |r| ≤ ln 2 / 2
/// (ln 2 in two parts, so that r is good to the last bits);
/// e^(−r) by its Taylor series to r¹³/13! (error below 10⁻¹⁷), in Horner form; then × 2^(−k).
/// Within a few ulps of `(-x).exp()`.
pub fn exp_neg(x: f64) -> f64 {
    if !(x < EXP_NEG_LIMIT) {
        return 0.0;
    }
    let k = (x * std::f64::consts::LOG2_E + 0.5) as i64;
    let y = ((k as f64) * LN2_HI - x) + (k as f64) * LN2_LO;
    let mut p = 1.0;
    for n in (1..=13).rev() {
        p = 1.0 + y * p / n as f64;
    }
    p * f64::from_bits(((1023 - k) as u64) << 52)
}

/// The largest share of a voxel's value one flux may carry: with six partners a voxel gives at
/// most all it has, so a sharpened field of non-negative values stays non-negative.
pub const LARGEST_FLUX_SHARE: f64 = 1.0 / 6.0;

/// Writes into `dst` the change of the sharpened committed total that this order's raw source
/// makes, C(`total` + `raw`) − C(`total`) (see the module docs, "Positive, and independent of
/// the path"): what the next order propagates. C is the anti-diffusive fluxes of
/// [`Sharpening`] between partner voxels of the medium (two apart), each capped at
/// [`LARGEST_FLUX_SHARE`] of the smaller of its two values. The increments of successive orders
/// add up to C of the total up to the rounding of the stored total and of each increment. The three
/// fields have the same layout (the twin's or the store's); every value of `dst` is written.
pub fn sharpen_increment<F: FieldPlanes + Sync, U: VoxelUnits<V = F::V>>(
    dst: &mut F,
    total: &F,
    raw: &F,
    units: &U,
    how: &Sharpening,
) {
    let unit_len = raw.unit_len();
    let unit_voxels = raw.unit_voxels();
    let comps = raw.components();
    let dims = units.dims();
    let (before, added) = (total.values(), raw.values());
    let at = |unit: usize, k: usize, local: usize| unit * unit_len + k * unit_voxels + local;
    // The committed total before and after this order at one place. The sum is taken in f64, not
    // rounded as the commit stores it: rounded, the change of a total held in f32 would come in
    // steps of its last bit, and once the orders are that small those steps (up to twice a value
    // just over half a step) kept the series from falling further (an 18³ cloud stalled at a
    // ratio of 1.0 per order near a residual of 10⁻⁷). What the two differ by is the total's own
    // rounding, a few parts in 10⁸ per order.
    let values_at = |i: usize| -> (f64, f64) {
        let t = before[i].to_f64();
        (t, t + added[i].to_f64())
    };
    // Component k at `voxel` (its unit, voxel in the unit, scattering weight and κ shares) of
    // C(after) − C(before): each value plus its capped fluxes to the partners that
    // scatter, summed in the fixed order −x, +x, −y, +y, −z, +z.
    let new_value = |voxel: &ScatteringVoxel, k: usize, partners: &[Option<ScatteringVoxel>; 6]| -> f64 {
        let &(unit, local, m, share) = voxel;
        let ch = k % how.channels;
        let (t, x) = values_at(at(unit, k, local));
        let (mut change_before, mut change_after) = (0.0, 0.0);
        for (n, partner) in partners.iter().enumerate() {
            let Some((nu, nl, mn, other_share)) = *partner else { continue };
            let (t_other, x_other) = values_at(at(nu, k, nl));
            // Anti-diffusion of the radiance-like s/m through the harmonic mean of the weights,
            // μ·(other/mn − s/m) with μ = 2·m·mn/(m + mn), written without the quotients (which
            // overflow where a weight is tiny); κ·(other − s) in a uniform medium. The smaller of
            // the two voxels' stable shares keeps the flux antisymmetric, as does the cap.
            let kappa = PARTNER_WEIGHT * how.kappa[n / 2] * share[ch].min(other_share[ch]);
            let flux = |s: f64, other: f64| -> f64 {
                let limit = LARGEST_FLUX_SHARE * s.min(other).max(0.0);
                (kappa * 2.0 * (m * other - mn * s) / (m + mn)).clamp(-limit, limit)
            };
            change_before -= flux(t, t_other);
            change_after -= flux(x, x_other);
        }
        (x - t) + (change_after - change_before)
    };
    let scatters = |w: [u32; 3]| -> Option<(usize, usize, f64)> {
        let (u, l) = units.unit_of(w)?;
        let m = units.scattering_at(u, l);
        (m > 0.0).then_some((u, l, m))
    };
    let partners_of = |unit: usize, local: usize| -> [Option<ScatteringVoxel>; 6] {
        partner_voxels(units.voxel_of(unit, local), dims, how.periodic, how.reflective).map(|pair| {
            let (partner, between) = pair?;
            scatters(between)?;
            let (u, l, m) = scatters(partner)?;
            Some((u, l, m, how.shares(units, u, l, m)))
        })
    };
    let units_total = raw.units();
    let group = RELEASE_UNITS.max(1);
    let mut first = 0;
    while first < units_total {
        let count = group.min(units_total - first);
        let out = &mut dst.values_mut()[first * unit_len..(first + count) * unit_len];
        out.par_chunks_mut(unit_len).enumerate().for_each(|(i, block)| {
            let unit = first + i;
            for local in 0..unit_voxels {
                let m = units.scattering_at(unit, local);
                let voxel = (m > 0.0).then(|| (unit, local, m, how.shares(units, unit, local, m)));
                let partners = if voxel.is_some() { partners_of(unit, local) } else { [None; 6] };
                for k in 0..comps {
                    let at = k * unit_voxels + local;
                    block[at] = match &voxel {
                        Some(voxel) => F::V::from_f64(new_value(voxel, k, &partners)),
                        None => added[unit * unit_len + at],
                    };
                }
            }
        });
        dst.release(first, count);
        raw.release(first, count);
        total.release(first, count);
        first += count;
    }
}

/// A voxel that scatters (the one sharpened, or a partner): its unit, its voxel in the unit, its
/// scattering weight and its share of κ per channel ([`Sharpening::stable_share`]).
type ScatteringVoxel = (usize, usize, f64, [f64; 3]);

/// The weight of a flux between partners two voxels apart: u(i − 2) − 2u(i) + u(i + 2) is four
/// times the second difference u(i − 1) − 2u(i) + u(i + 1) of a smooth field.
pub const PARTNER_WEIGHT: f64 = 0.25;

/// The partners of `at` two voxels away along each axis, in the order −x, +x, −y, +y, −z, +z,
/// each with the voxel between them; `None` where the partner lies beyond a face, unless the
/// axis is periodic (then the volume goes on into its next period and the coordinates wrap).
fn partner_voxels(
    at: [u32; 3],
    dims: [u32; 3],
    periodic: [bool; 3],
    reflective: [[bool; 2]; 3],
) -> [Option<([u32; 3], [u32; 3])>; 6] {
    let mut out = [None; 6];
    for axis in 0..3 {
        let d = i64::from(dims[axis]);
        for (side, step) in [(0usize, -1i64), (1, 1)] {
            let (mid, far) = (i64::from(at[axis]) + step, i64::from(at[axis]) + 2 * step);
            let inside = |c: i64| (0..d).contains(&c);
            // Across a mirror the volume goes on as its image: c ↦ −1 − c below, 2d − 1 − c above.
            let image = |c: i64| {
                if c < 0 {
                    -1 - c
                } else if c >= d {
                    2 * d - 1 - c
                } else {
                    c
                }
            };
            let (mid, far) = match (inside(mid) && inside(far), periodic[axis], reflective[axis][side]) {
                (true, _, _) => (mid, far),
                (false, true, _) => (mid.rem_euclid(d), far.rem_euclid(d)),
                (false, false, true) if inside(image(far)) => (image(mid), image(far)),
                (false, false, _) => continue,
            };
            let (mut partner, mut between) = (at, at);
            partner[axis] = far as u32;
            between[axis] = mid as u32;
            out[2 * axis + side] = Some((partner, between));
        }
    }
    out
}

impl VoxelUnits for StoreMedium<'_> {
    type V = f32;
    fn dims(&self) -> [u32; 3] {
        self.store.grid().dims
    }
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)> {
        let (brick, local) = self.store.grid().locate(v);
        Some((self.store.slot(brick)? as usize, local))
    }
    fn voxel_of(&self, unit: usize, local: usize) -> [u32; 3] {
        let grid = self.store.grid();
        let origin = grid.brick_origin(grid.brick_coords(self.bricks[unit]));
        let e = BRICK_EDGE as usize;
        [origin[0] + (local % e) as u32, origin[1] + ((local / e) % e) as u32, origin[2] + (local / (e * e)) as u32]
    }
    fn density_at(&self, unit: usize, local: usize) -> f32 {
        self.density(unit).map_or(0.0, |d| d[local])
    }
    fn scattering_at(&self, unit: usize, local: usize) -> f64 {
        let albedo = if self.has_albedo() { self.albedo(unit).map_or(0.0, |a| a[local]) } else { 1.0 };
        f64::from(self.density_at(unit, local)) * f64::from(albedo)
    }
}

impl VoxelUnits for VoxelMedium {
    type V = f64;
    fn dims(&self) -> [u32; 3] {
        self.dims
    }
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)> {
        let [nx, ny, _] = self.dims.map(|d| d as usize);
        Some((v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize), 0))
    }
    fn voxel_of(&self, unit: usize, _local: usize) -> [u32; 3] {
        let [nx, ny, _] = self.dims.map(|d| d as usize);
        [(unit % nx) as u32, ((unit / nx) % ny) as u32, (unit / (nx * ny)) as u32]
    }
    fn density_at(&self, unit: usize, _local: usize) -> f64 {
        self.density[unit]
    }
    fn scattering_at(&self, unit: usize, _local: usize) -> f64 {
        self.density[unit] * self.albedo.get(unit).copied().unwrap_or(1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_portable_exponential_is_the_exponential() {
        for i in 0..7000 {
            let x = i as f64 * 0.1 + (i % 7) as f64 * 1e-3;
            let (ours, std) = (exp_neg(x), (-x).exp());
            assert!((ours - std).abs() <= 4.0 * f64::EPSILON * std, "{x}: {ours:e} vs {std:e}");
        }
        assert_eq!(exp_neg(700.0), 0.0);
        assert_eq!(exp_neg(f64::NAN), 0.0);
        assert_eq!(exp_neg(0.0), 1.0);
    }
    use crate::solver::passes::MemField;

    fn field(dims: [u32; 3], comps: usize, f: impl Fn([u32; 3], usize) -> f64) -> MemField {
        let n = dims.iter().map(|&d| d as usize).product::<usize>();
        let layout = VoxelMedium { density: vec![], albedo: vec![], dims };
        let mut m = MemField::zeros(comps, n);
        for i in 0..n {
            let v = layout.voxel_of(i, 0);
            for k in 0..comps {
                m.values[i * comps + k] = f(v, k);
            }
        }
        m
    }

    /// κ and the periodic axes alone: a medium too thin for the stability limit to act.
    fn uniform_sharpening(kappa: [f64; 3], periodic: [bool; 3]) -> Sharpening {
        Sharpening { kappa, periodic, reflective: [[false; 2]; 3], thickness: [0.0; 3], albedo: [1.0; 3], channels: 1 }
    }

    fn medium(dims: [u32; 3], density: impl Fn([u32; 3]) -> f64) -> VoxelMedium {
        let f = field(dims, 1, |v, _| density(v));
        VoxelMedium { density: f.values, albedo: vec![], dims }
    }

    /// C(`src`): the sharpened field itself, the increment over a total of zero.
    fn sharpen(dst: &mut MemField, src: &MemField, med: &VoxelMedium, how: &Sharpening) {
        let comps = src.components();
        let zero = MemField::zeros(comps, src.values.len() / comps);
        sharpen_increment(dst, &zero, src, med, how);
    }

    #[test]
    fn conserves_the_total_and_leaves_uniform_fields_alone() {
        let dims = [9, 7, 5];
        // A medium with a hole (no exchange across it) and a source with sharp jumps and zeros.
        let med = medium(dims, |v| if v == [4, 3, 2] { 0.0 } else { 1.0 });
        let hole = med.unit_of([4, 3, 2]).map(|(u, _)| u);
        let src = field(dims, 2, |v, k| {
            let r = ((v[0] * 7 + v[1] * 3 + v[2] * 5 + k as u32) % 11) as f64;
            if v == [4, 3, 2] || r < 3.0 {
                0.0
            } else {
                r * r
            }
        });
        let mut dst = MemField::zeros(2, src.values.len() / 2);
        sharpen(&mut dst, &src, &med, &uniform_sharpening([0.06, 0.05, 0.08], [false; 3]));
        for k in 0..2 {
            let before: f64 = src.values.iter().skip(k).step_by(2).sum();
            let after: f64 = dst.values.iter().skip(k).step_by(2).sum();
            assert!((before - after).abs() < 1e-12 * before, "component {k}: {before} → {after}");
        }
        assert_ne!(dst.values, src.values, "nothing was sharpened");
        // Nothing flowed into the voxel without medium.
        assert_eq!(dst.values[hole.expect("inside") * 2], 0.0);

        let uniform = field(dims, 1, |_, _| 3.5);
        let mut out = MemField::zeros(1, uniform.values.len());
        sharpen(&mut out, &uniform, &med, &uniform_sharpening([0.1; 3], [false; 3]));
        assert_eq!(out.values, uniform.values);
    }

    /// However the orders split the light, their increments add up to the sharpened total: the
    /// answer does not depend on the path. And a voxel far darker than its neighbours (a sunlit
    /// layer next to a shadowed one) gives at most what it has: C of a non-negative field is
    /// non-negative, where the uncapped fluxes would take the dark voxels below zero.
    #[test]
    fn increments_add_up_to_the_sharpened_total_which_stays_non_negative() {
        let dims = [6, 5, 4];
        let med = medium(dims, |v| 1.0 + f64::from(v[1]));
        // A lit layer x = 0 a trillion times brighter than the rest, which has some zeros.
        let lit = field(dims, 1, |v, _| if v[0] == 0 { 1e12 } else { f64::from((v[1] + v[2]) % 3) });
        let how = uniform_sharpening([0.07, 0.09, 0.05], [false, true, false]);
        let mut whole = MemField::zeros(1, lit.values.len());
        sharpen(&mut whole, &lit, &med, &how);
        assert!(whole.values.iter().all(|&v| v >= 0.0), "C went negative: {:?}", whole.values);
        assert_ne!(whole.values, lit.values, "nothing was sharpened");
        let total_of = |m: &MemField| m.values.iter().sum::<f64>();
        assert!((total_of(&whole) - total_of(&lit)).abs() < 1e-12 * total_of(&lit));

        // The same light in three orders of either sign: the propagated increments sum to C(lit).
        let first: Vec<f64> = lit.values.iter().map(|l| 0.7 * l).collect();
        let second: Vec<f64> = lit.values.iter().map(|l| 0.5 * l).collect();
        let third: Vec<f64> = lit.values.iter().zip(&first).zip(&second).map(|((l, a), b)| l - a - b).collect();
        let mut total = MemField::zeros(1, lit.values.len());
        let mut propagated = vec![0.0; lit.values.len()];
        for order in [first, second, third] {
            let mut raw = MemField::zeros(1, order.len());
            raw.values = order;
            let mut step = MemField::zeros(1, lit.values.len());
            sharpen_increment(&mut step, &total, &raw, &med, &how);
            for ((p, s), (t, r)) in
                propagated.iter_mut().zip(&step.values).zip(total.values.iter_mut().zip(&raw.values))
            {
                *p += s;
                *t += r;
            }
        }
        for (p, w) in propagated.iter().zip(&whole.values) {
            assert!((p - w).abs() <= 1e-3 + 1e-12 * w.abs(), "{p} vs {w}");
        }
    }

    /// κ is kept whole in thin voxels and thinned out in thick, white ones, down to nothing in an
    /// opaque one, so that a voxel-to-voxel pattern cannot grow from order to order.
    #[test]
    fn thick_white_voxels_keep_a_stable_share_of_kappa() {
        let how = Sharpening {
            kappa: [0.07; 3],
            periodic: [false; 3],
            reflective: [[false; 2]; 3],
            thickness: [1.0, 1.0, 1.0],
            albedo: [0.95, 0.5, 1.0],
            channels: 3,
        };
        assert_eq!(how.stable_share(0.5, 1.0, 0), 1.0, "τ = 0.5");
        assert_eq!(how.stable_share(1.0, 1.0, 0), 1.0, "τ = 1");
        let thick = how.stable_share(3.0, 1.0, 0);
        assert!(thick > 0.0 && thick < 1.0, "τ = 3: {thick}");
        // The loop gain a·P·(1 + Σκ·share) is held at the bound.
        let x: f64 = 2.0;
        let p = 1.0 - (1.0 - (-x).exp()) / x;
        let gain = 0.95 * p * (1.0 + 0.21 * thick);
        assert!((gain - LARGEST_VOXEL_PATTERN_GROWTH).abs() < 1e-12, "{gain}");
        assert!(how.stable_share(3.0, 1.0, 1) == 1.0, "albedo 0.5 keeps κ");
        assert!(how.stable_share(3.0, 0.5, 0) > thick, "an albedo factor of ½ keeps more");
        assert_eq!(how.stable_share(1e6, 1.0, 2), 0.0, "an opaque white voxel keeps none");
    }

    /// The fluxes exchange the radiance-like S/m, not S: a source that jumps only because the
    /// medium does (the edge of a dense core under uniform light) is left as it is, while the
    /// same jump in a uniform medium is sharpened; across a periodic axis the partners wrap.
    #[test]
    fn a_jump_of_the_medium_alone_is_not_sharpened_and_periodic_axes_wrap() {
        let dims = [8, 3, 2];
        let dense = |v: [u32; 3]| if v[0] >= 4 { 5.0 } else { 1.0 };
        let med = medium(dims, dense);
        let src = field(dims, 1, |v, _| 0.3 * dense(v));
        let mut out = MemField::zeros(1, src.values.len());
        sharpen(&mut out, &src, &med, &uniform_sharpening([0.08; 3], [true, false, true]));
        assert_eq!(out.values, src.values, "a uniform radiance over a density jump changed");

        let uniform = medium(dims, |_| 1.0);
        sharpen(&mut out, &src, &uniform, &uniform_sharpening([0.08; 3], [false; 3]));
        assert!(out.values[3] < src.values[3] && out.values[4] > src.values[4], "the jump was not sharpened");
        // Periodic along x: the ends x = 0 and x = 7 exchange too.
        let mut wrapped = MemField::zeros(1, src.values.len());
        sharpen(&mut wrapped, &src, &uniform, &uniform_sharpening([0.08; 3], [true, false, false]));
        assert!(wrapped.values[0] < out.values[0] && wrapped.values[7] > out.values[7]);
        let total = |m: &MemField| m.values.iter().sum::<f64>();
        assert!((total(&wrapped) - total(&src)).abs() < 1e-12 * total(&src));
    }

    #[test]
    fn undoes_a_small_diffusion_to_leading_order() {
        // Smooth a smooth bump by one explicit diffusion step of coefficient κ and sharpen it back
        // with the same κ: what remains is O(κ²), far below the diffusion's own change.
        let dims = [48, 1, 1];
        let med = medium(dims, |_| 1.0);
        let bump = |x: f64| (-(x - 23.5).powi(2) / 50.0).exp();
        let exact = field(dims, 1, |v, _| bump(v[0] as f64));
        let kappa = 0.05;
        let n = exact.values.len();
        let mut smoothed = MemField::zeros(1, n);
        for i in 0..n {
            let left = if i > 0 { exact.values[i - 1] } else { exact.values[i] };
            let right = if i + 1 < n { exact.values[i + 1] } else { exact.values[i] };
            smoothed.values[i] = exact.values[i] + kappa * (left - 2.0 * exact.values[i] + right);
        }
        let mut back = MemField::zeros(1, n);
        sharpen(&mut back, &smoothed, &med, &uniform_sharpening([kappa, 0.0, 0.0], [false; 3]));
        let err = |a: &MemField| a.values.iter().zip(&exact.values).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(err(&back) < 0.05 * err(&smoothed), "{} vs {}", err(&back), err(&smoothed));
    }
}
