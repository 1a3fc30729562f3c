//! The estimate: runs in a low-priority task, outside `tick()`.
//!
//! [`run_estimate`] takes the [`EstimateRequest`] handed out after the step settled,
//! back-dates the contact point, applies the paper's two-point method (Eq. 1: K̂c = ΔT_a/Δθa,
//! inverted at the contact configuration) through [`pts::Model`], classifies the phalanx and
//! returns an integer [`EstimateResult`] for [`Controller::deliver`](crate::Controller::deliver).
//!
//! The request keeps the samples from contact to settle (bounded, [`PATH_CAPACITY`]) so
//! that a whole-path estimator can be selected later without touching the tick path.

use heapless::Vec;
use pts::{Finger, Model, Phalanx, PtsError, Real};

use crate::config::HISTORY;

/// The numeric back end of the estimator on the target. One place to switch
/// (to `pts::fixed::Fx32` / `pts::FirmwareReal` once available).
pub type EstReal = f32;

/// Capacity of the contact-to-settle path (samples; the stride doubles when it fills).
pub const PATH_CAPACITY: usize = 128;

/// Relative band above K_c,proximal in which a "distal" reading is reported as
/// [`Located::ProximalOrNearO2`]: a proximal contact measured with a finite ΔT_a reads
/// slightly above K_c,proximal (MODEL.md, traps).
pub const O2_AMBIGUITY_BAND: f64 = 0.15;

/// Δθa (rad) below which the estimate is flagged [`Quality::LowSignal`].
pub const MIN_GOOD_DTHETA_RAD: f64 = 2e-3;

/// One averaged sample (over `sample_ticks` ticks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// Tick at the end of the averaging interval.
    pub tick: u32,
    /// Mean θa (µrad), absolute model angle.
    pub theta_a_urad: i32,
    /// Mean measured T_a (µN·m).
    pub torque_unm: i32,
    /// Torque reference at the end of the interval (µN·m).
    pub torque_ref_unm: i32,
}

impl Sample {
    /// All zero.
    pub const ZERO: Sample = Sample {
        tick: 0,
        theta_a_urad: 0,
        torque_unm: 0,
        torque_ref_unm: 0,
    };
}

/// Everything the estimator needs, moved out of the controller once the step settled.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EstimateRequest {
    /// The contact sample found by the tick-level knee scan (θa,c, T_a,c).
    pub contact: Sample,
    /// Settled end point: means over the settle window (θa, T_a).
    pub end: Sample,
    /// History before and up to the detection, oldest first.
    pub pre: Vec<Sample, HISTORY>,
    /// Samples from the detection to the settle, oldest first, every `path_stride`-th.
    pub path: Vec<Sample, PATH_CAPACITY>,
    /// Ticks per sample.
    pub sample_ticks: u32,
    /// Samples per path entry.
    pub path_stride: u32,
    /// The commanded ΔT_a (µN·m).
    pub delta_ta_cmd_unm: i32,
    /// The detection stiffness threshold (µN·m/rad).
    pub detect_k_unm_per_rad: i32,
}

/// Where the contact is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Located {
    /// On the proximal phalanx (detected, not locatable).
    Proximal,
    /// On the distal phalanx at `k2_um`.
    Distal,
    /// K̂c within [`O2_AMBIGUITY_BAND`] above K_c,proximal: a proximal contact or a distal
    /// one near O2 (`k2_um` is the distal reading).
    ProximalOrNearO2,
}

/// How much to trust the estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Quality {
    /// Δθa spans enough encoder resolution and the inversion is well inside its range.
    Good,
    /// Δθa below [`MIN_GOOD_DTHETA_RAD`]: noise- and friction-dominated.
    LowSignal,
    /// Within the proximal/O2 ambiguity.
    Ambiguous,
}

/// The estimate, in integers (µ-units), so the controller holds no float.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimateResult {
    /// Phalanx.
    pub located: Located,
    /// Distal contact location from O2 (µm), when distal or ambiguous.
    pub k2_um: Option<i32>,
    /// K̂c = ΔT_a/Δθa (µN·m/rad).
    pub kc_hat_unm_per_rad: i32,
    /// K_c of a proximal contact at the contact configuration (µN·m/rad).
    pub kc_proximal_unm_per_rad: i32,
    /// K_c of a contact at the tip at the contact configuration (µN·m/rad).
    pub kc_tip_unm_per_rad: i32,
    /// ΔT_a actually applied, T_a − T_a,c (µN·m).
    pub delta_ta_unm: i32,
    /// Δθa (µrad).
    pub delta_theta_a_urad: i32,
    /// θa,c used (µrad).
    pub theta_a_c_urad: i32,
    /// T_a,c used (µN·m).
    pub ta_c_unm: i32,
    /// Trust.
    pub quality: Quality,
}

/// The finger the default estimator uses (the paper's prototype).
pub const FINGER: Finger = Finger::PAPER;

/// Runs the two-point estimate for the paper's finger on [`EstReal`].
pub fn run_estimate(req: &EstimateRequest) -> Result<EstimateResult, PtsError> {
    let model = Model::<EstReal>::new(&FINGER)?;
    run_estimate_with(&model, req)
}

/// Runs the two-point estimate with a given model (any back end).
pub fn run_estimate_with<R: Real>(
    model: &Model<R>,
    req: &EstimateRequest,
) -> Result<EstimateResult, PtsError> {
    let (theta_c, ta_c) = contact_point(req);
    let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
    let est = model.estimate_two_point(
        conv(theta_c)?,
        conv(ta_c)?,
        conv(f64::from(req.end.theta_a_urad) * 1e-6)?,
        conv(f64::from(req.end.torque_unm) * 1e-6)?,
    )?;
    let c = est.contact;
    let micro = |v: R| -> i32 { to_micro(v.to_f64()) };
    let kc = est.kc_hat.to_f64();
    let kc_prox = c.kc_proximal.to_f64();
    let (located, k2) = match c.phalanx {
        Phalanx::None => return Err(PtsError::StiffnessBelowFree),
        Phalanx::Proximal => (Located::Proximal, None),
        Phalanx::Distal if kc <= kc_prox * (1.0 + O2_AMBIGUITY_BAND) => {
            (Located::ProximalOrNearO2, c.k2.map(micro))
        }
        Phalanx::Distal => (Located::Distal, c.k2.map(micro)),
    };
    let dtheta = est.dtheta_a.to_f64();
    let quality = if located == Located::ProximalOrNearO2 {
        Quality::Ambiguous
    } else if dtheta < MIN_GOOD_DTHETA_RAD {
        Quality::LowSignal
    } else {
        Quality::Good
    };
    Ok(EstimateResult {
        located,
        k2_um: k2,
        kc_hat_unm_per_rad: micro(est.kc_hat),
        kc_proximal_unm_per_rad: micro(c.kc_proximal),
        kc_tip_unm_per_rad: micro(c.kc_tip),
        delta_ta_unm: micro(est.dta),
        delta_theta_a_urad: micro(est.dtheta_a),
        theta_a_c_urad: to_micro(theta_c),
        ta_c_unm: to_micro(ta_c),
        quality,
    })
}

/// The contact point (θa,c rad, T_a,c N·m) used by the estimate.
fn contact_point(req: &EstimateRequest) -> (f64, f64) {
    (
        f64::from(req.contact.theta_a_urad) * 1e-6,
        f64::from(req.contact.torque_unm) * 1e-6,
    )
}

fn to_micro(v: f64) -> i32 {
    let x = v * 1e6;
    if !x.is_finite() {
        return 0;
    }
    let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    r as i32
}
