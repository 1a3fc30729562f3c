//! Path fit: locate a distal contact from every (θa, T_a) sample between contact and the end
//! of the torque step, with the full quasi-static contact-path model.
//!
//! The paper's two-point estimate (Eq. 1) reads the stiffness of the contact instant from a
//! finite step and so drifts as ΔT_a grows and with the object's radius (MODEL.md, "After
//! contact"). This estimator instead predicts the whole path T_a(θa) for a hypothesis
//! (k2,c, R) — the contact configuration from θa,c by free motion, then the equilibrium with
//! a contact force, the contact point sliding on a vertex or rolling on a cylinder of radius R
//! (see [`path`]) — and fits it to the measured samples:
//!
//! 1. What the board sees is cleaned first, in one backwards pass over the samples (no copy):
//!    the drive's inertia reflected to the actuator ([`PathFitConfig::inertia_kgm2`]) is
//!    removed from the current torque (T_meas − J θ̈a, θ̈a from second differences: the finger
//!    on its contact stiffness is a ≈ 2 Hz oscillator, and the impact carries it ~10 mrad
//!    past the contact); only the lower envelope in time is kept (drops the overshoot and
//!    the bounce, keeps one sample — the last — per stiction plateau, paper Fig. 9).
//! 2. Samples are binned by θa (the encoder is the precise axis); each bin keeps its count,
//!    mean θa and mean T_a; the noise is the scatter about each bin's local trend.
//! 3. Coulomb friction in the transmission shifts the measured torque by a constant while the
//!    finger moves one way: an offset T_f, eliminated in closed form, with a prior from the
//!    approach (T_a,c measured on the free-motion line minus the model's free torque there).
//! 4. Levenberg–Marquardt on (k2,c, T_f, θa,c) with the vertex model (R = 0) first: θa,c is
//!    fitted too (a controller sees the contact late), pinned by its prior, by the friction
//!    prior and by the free-motion curve the path starts from. The analytic sensitivity ∂T/∂R
//!    tells whether a radius would matter and shows in these data — checked at the first
//!    evaluation (a clear radius goes straight to the cylinder fit, started by the
//!    Gauss–Newton step with R free) and else at the vertex solution; only then (object
//!    model `Auto`) the fit is extended to R: a vertex, or a radius that cannot be seen or
//!    does not matter, never pays for the curvature fit (its possible bias goes into σ).
//! 5. σ(k2,c) from the fit covariance with the noise level the larger of the residual scatter
//!    and the within-bin scatter, widened by [`PathFitConfig::sigma_inflation`], plus the bias
//!    an unseen radius could cause, plus a floor. Refused with a typed [`PathFitError`]: too
//!    little motion or too few bins, σ above [`PathFitConfig::max_sigma_frac_l2`] (the path
//!    does not determine k2), χ² far above the noise (the model does not explain the path),
//!    a fitted path that ends at the tip or an object that cuts the proximal phalanx.
//!
//! 6. Levenberg–Marquardt takes Gauss–Newton steps from one LDLᵀ per accepted hypothesis
//!    (shared with the radius decision and the final covariance), damped only after a step
//!    failed; a radius on its bound that the step pushes further out is held there (the
//!    other parameters take the step optimal with it held). It ends on the step projected
//!    on the bounds (below 0.1 % of l2 and 1e-5 rad), on a Gauss–Newton step that would
//!    lower χ² by less than 0.05, or after an accepted step that lowered it by less than
//!    0.05: the parameters are then within about a quarter of their σ (a poorly determined
//!    radius is not iterated further).
//!
//! No allocation, no panics, bounded iterations ([`MAX_EVALS`] path evaluations of at most
//! [`MAX_BINS`] points, each a warm-started Newton solve of ≤ [`path::MAX_PATH_NEWTON`] steps;
//! each point is warm-started from the previous hypothesis through its sensitivities).
//! The fit is written once (priors, LM, the radius decision, σ, refusals) against a
//! `Kernel`: the path model and the binned samples. [`fit_path`] runs the generic kernel
//! ([`path`], any [`Real`]: f64 on the host is the reference); [`q::fit_path_q`] runs the
//! firmware's 32-bit integer kernel on the controller's own integer samples. Its cost on
//! thumbv7em is measured by `benches/icount` (`cargo xtask bench`). It runs once per contact
//! in the firmware's low-priority task.
//!
//! ```
//! use pathfit::{fit_path, PathFitConfig, PathSample};
//! let model = pts::Model::<f64>::paper().unwrap();
//! // (θa, T_a) pairs from the controller, in time order; here a short, flat, useless path.
//! let samples = (0..50).map(|i| PathSample {
//!     time_s: 0.004 * i as f64,
//!     theta_a_rad: -0.2238 + 1e-5 * i as f64,
//!     torque_nm: 0.42,
//! });
//! let r = fit_path(&model, &PathFitConfig::DEFAULT, -0.2238, Some(0.42), samples);
//! assert_eq!(r.unwrap_err().kind(), "no_motion");
//! ```
#![no_std]
#![forbid(unsafe_code)]
// `!(a > b)` is deliberate throughout: it is true for NaN, so a NaN fails every range check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod path;
pub mod q;

use path::{PathFail, PathModel};
use pts::{Config, Model, PtsError, Real};

/// Parameter indices of the fit: k2,c/l2, R/l2, T_f (N·m), θa,c (rad).
const K: usize = 0;
const RAD: usize = 1;
const TF: usize = 2;
const TC: usize = 3;
/// Number of parameters.
const NP: usize = 4;

/// A fitted k2,c at or below this fraction of l2 is a proximal contact (refused: not
/// locatable on the distal phalanx).
const PROXIMAL_FRAC: f64 = 0.02;
/// The fit's lower bound of k2,c (fraction of l2): below [`PROXIMAL_FRAC`], so that a fit
/// held on it is a proximal contact.
const K_LO_FRAC: f64 = 0.01;
const _: () = assert!(K_LO_FRAC < PROXIMAL_FRAC);

/// Largest number of θa bins.
pub const MAX_BINS: usize = 12;
/// Fewest bins with data the fit accepts.
pub const MIN_BINS: usize = 4;
/// Torque scale of the fit's statistics: residuals, columns and variances are kept in
/// mN·m so that their squares stay well inside fixed point's resolution (2⁻³² for Fx32).
const TSCALE: f64 = 1000.0;

/// Gauss–Newton steps below this (fraction of l2) end the fit without evaluating them: a
/// tenth of the 1 % accuracy target, below the 0.1 mm σ floor (0.13 % l2).
const STEP_TOL: f64 = 1e-3;

/// Budget of path evaluations (each: ≤ [`MAX_BINS`] path points) over the whole fit: it
/// bounds the run time. On the plant grid (both plants, four noise seeds) a fit needs 2–4;
/// only refusals (a path leaving the tip) reach the budget, and 5 against 6 changed no
/// grid figure.
pub const MAX_EVALS: usize = 5;

/// One measurement: actuator angle and torque at the same instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSample<R> {
    /// Time of the sample (s), any origin, increasing (used for the inertial correction).
    pub time_s: R,
    /// θa, absolute model angle (rad).
    pub theta_a_rad: R,
    /// T_a at the actuator (N·m).
    pub torque_nm: R,
}

/// Which object model to fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ObjectModel {
    /// A vertex; add the radius only when the data can show it.
    Auto,
    /// Always a vertex (R = 0); the unseen-radius bias is still added to σ.
    Vertex,
    /// Always fit the radius (costs the curvature terms).
    Cylinder,
}

/// Tuning of the path fit. Plain data, const-constructible; f64 converted once per call.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathFitConfig {
    /// Number of θa bins (clamped to [`MIN_BINS`]..=[`MAX_BINS`]).
    pub bins: u8,
    /// Samples with θa − θa,c below this are skipped (rad): stiction plateau and impact.
    pub dead_band_rad: f64,
    /// Fraction of the θa range after the dead band also skipped (the slip right after the
    /// stiction breaks is dynamic, not quasi-static).
    pub skip_fraction: f64,
    /// Least θa travel after the dead band (rad); below it the step did not move the finger.
    pub min_travel_rad: f64,
    /// Largest object radius considered (m).
    pub max_radius_m: f64,
    /// Object model.
    pub object: ObjectModel,
    /// Radius declared observable when σ(R)/R is below this.
    pub radius_rel_sigma: f64,
    /// Floor of σ(T_a) of one sample (N·m), e.g. the ADC step over √12.
    pub torque_noise_floor_nm: f64,
    /// σ(k2,c) floor (m): model and discretisation errors not in the fit.
    pub sigma_floor_m: f64,
    /// Refuse when χ²/dof exceeds this (the path model does not explain the samples).
    pub max_chi2: f64,
    /// Refuse when σ(k2,c) exceeds this fraction of l2 (k2 not determined by the path).
    pub max_sigma_frac_l2: f64,
    /// Coverage factor applied to the statistical σ (few bins: a t-like widening).
    pub sigma_inflation: f64,
    /// σ (N·m) of the friction offset read from the approach: T_a,c measured while the finger
    /// still moved freely minus the model's free-motion torque at θa,c. Coulomb friction
    /// resists the motion the same way before and after contact, so this anchors the fitted
    /// path at contact (as the two-point estimate implicitly does). ≤ 0 disables the prior.
    pub friction_prior_sigma_nm: f64,
    /// Refuse when the fitted contact ends within this fraction of l2 of the tip.
    pub tip_margin_frac_l2: f64,
    /// σ (rad) of the given θa,c: it enters σ(k2,c), and is the prior when θa,c is fitted
    /// ([`PathFitConfig::fit_contact_angle`]). The finger's inertia carries it past the
    /// contact and the detection sees the kink late, so a controller's contact angle is off
    /// by a few mrad (`grasp::estimate::contact_point_model`: 1.7–3.1 mrad late on the
    /// realistic plant). ≤ 0: θa,c taken as exact.
    pub contact_angle_sigma_rad: f64,
    /// Fit θa,c (else it stays where the caller put it and only its σ enters σ(k2,c)).
    /// On by default: with the drive's measurement model (η J N² inertia, encoder lead,
    /// plateaus dropped) the fit finds θa,c better than a controller's contact point
    /// (realistic plant grid: max error 2.3 % of l2 fitted vs 12.2 % taken as given).
    pub fit_contact_angle: bool,
    /// Drive inertia as the measured torque sees it (kg·m²): rotor inertia × gear ratio² ×
    /// the driving efficiency η. The board's torque is N η kt i, and the motor's equation
    /// kt i = J N θ̈a + T_a/(N η) + friction makes that T_a + η J N² θ̈a + N η T_fric: the
    /// finger on its contact stiffness is a slow oscillator (≈ 2 Hz for the paper's finger
    /// on an RE10 with 3072:1), so θ̈a from the samples' second differences is removed with
    /// this coefficient (J N² alone over-corrects by 1/η: 60 % on the paper's drive). 0: off.
    /// See [`PathFitConfig::with_drive_model`].
    pub inertia_kgm2: f64,
    /// How far the encoder angle leads the finger's θa while the drive loads it in flexion
    /// (rad): the encoder is on the motor shaft, the backlash sits between, and after the
    /// rest-pose zeroing the gear crosses half the backlash before it pushes the finger. The
    /// caller's θa,c and the samples are encoder angles; the contact configuration is taken
    /// at θa,c minus this (on the plant: θa,meas − θa = 1.46–1.49 mrad along the whole
    /// loading, backlash 3 mrad). See [`PathFitConfig::with_drive_model`].
    pub encoder_lead_rad: f64,
    /// A sample is used only while its θa stays within this (rad) of every later sample's:
    /// drops the overshoot after impact (≈ 10 mrad on the paper's finger), keeps the
    /// oscillation about the path.
    pub envelope_tol_rad: f64,
    /// With θa,c fitted, samples down to this far (rad) below the given θa,c are used too:
    /// the approach (free motion, T = T_free(θa) + T_f) meets the contact path at θa,c, so
    /// the fit sees the kink instead of extrapolating the path down to it. Pass the approach
    /// samples in `samples` for this to work. 0: only samples above θa,c (the default: on
    /// the realistic plant the break-away torque of the stiction plateau at the start of the
    /// loading pulls the kink early; on the ideal plant 0.015 finds θa,c within 0.1 mrad).
    pub approach_span_rad: f64,
    /// Drop every sample whose θa equals a neighbour's: a stiction plateau, including its
    /// break-away sample. While the drive stands still its friction is anywhere in the
    /// stiction band (on the plant the measured torque minus the finger's runs from +0.007
    /// to +0.116 N·m over one hold), not the sliding Coulomb offset the fit eliminates, so
    /// these samples say nothing about the path. For averaged samples (the controller's, the
    /// default); raw quantised encoder samples repeat while moving slowly.
    pub drop_plateaus: bool,
    /// Coulomb friction coefficient µ at the object contact (dimensionless, 0 ≤ µ < 2). While
    /// the step loads the finger the contact slides outward along the distal phalanx (θ1
    /// falls as θ2 rises), and the friction the object puts on the phalanx resists it: the
    /// tangential force µ f at the material point, whose motion along the phalanx is
    /// l1 sin θ2 · δθ1, enters the balance of the O1 joint. The path model then reads
    /// L = l1 (cos θ2 − µ sin θ2) + k2 instead of l1 cos θ2 + k2 (MODEL.md, "After contact");
    /// leaving it at 0 on a rough object reads the extra stiffness as a contact further out.
    pub contact_mu: f64,
}

impl PathFitConfig {
    /// Defaults for the paper's finger on a board with a quadrature encoder and a current ADC.
    pub const DEFAULT: PathFitConfig = PathFitConfig {
        bins: 8,
        dead_band_rad: 0.0,
        skip_fraction: 0.0,
        min_travel_rad: 2e-3,
        max_radius_m: 0.12,
        object: ObjectModel::Auto,
        radius_rel_sigma: 0.06,
        torque_noise_floor_nm: 1e-5,
        sigma_floor_m: 1e-4,
        max_chi2: 400.0,
        max_sigma_frac_l2: 0.1,
        sigma_inflation: 1.5,
        friction_prior_sigma_nm: 0.003,
        tip_margin_frac_l2: 0.02,
        contact_angle_sigma_rad: 0.003,
        fit_contact_angle: true,
        inertia_kgm2: 0.6175 * 7.0e-9 * 3072.0 * 3072.0,
        encoder_lead_rad: 1.5e-3,
        envelope_tol_rad: 2e-3,
        approach_span_rad: 0.0,
        drop_plateaus: true,
        contact_mu: 0.0,
    };

    /// This configuration with the measurement model of a drive: its inertia as the measured
    /// torque sees it (kg·m²; η × rotor inertia × gear ratio²) and its backlash at the base
    /// link (rad), of which the encoder leads by half while the drive loads in flexion.
    /// [`PathFitConfig::DEFAULT`] is the paper's finger on the RE10 + GP10A drive
    /// (η 0.6175 × 7.0e-9 kg·m² × 3072², 3 mrad).
    pub const fn with_drive_model(self, inertia_kgm2: f64, backlash_rad: f64) -> Self {
        PathFitConfig {
            inertia_kgm2,
            encoder_lead_rad: 0.5 * backlash_rad,
            ..self
        }
    }

    /// This configuration with the priors of a finger ([`FitPriors`]).
    pub const fn with_priors(self, priors: FitPriors) -> Self {
        PathFitConfig {
            contact_angle_sigma_rad: priors.contact_angle_sigma_urad as f64 / 1e6,
            friction_prior_sigma_nm: priors.friction_offset_sigma_unm as f64 / 1e6,
            ..self
        }
    }
}

/// The priors of a fit that belong to a finger and its drive rather than to the algorithm
/// (a finger file's `[estimate]` section), in micro-units: the firmware carries them in its
/// drive configuration, where they cost 8 bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FitPriors {
    /// How far the contact angle a detection finds may lie from the true one (µrad at the
    /// crank): [`PathFitConfig::contact_angle_sigma_rad`]. 0: taken as exact.
    pub contact_angle_sigma_urad: u32,
    /// How far the transmission's friction offset while loading may differ from the one read
    /// on the approach (µN·m at the base link): [`PathFitConfig::friction_prior_sigma_nm`].
    /// 0: no prior.
    pub friction_offset_sigma_unm: u32,
}

impl FitPriors {
    /// The priors of [`PathFitConfig::DEFAULT`] (the paper's finger and drive): 3 mrad and
    /// 3 mN·m.
    pub const DEFAULT: FitPriors = FitPriors {
        contact_angle_sigma_urad: 3000,
        friction_offset_sigma_unm: 3000,
    };
}

impl Default for FitPriors {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Default for PathFitConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Which object the fit settled on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FittedObject {
    /// Vertex model (R = 0); the radius was not fitted.
    Vertex,
    /// Cylinder model with a fitted radius.
    Cylinder,
}

/// The result of a path fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathFit<R> {
    /// Initial contact location k2,c from O2 (m).
    pub k2_contact_m: R,
    /// Standard uncertainty of k2,c (m).
    pub sigma_k2_m: R,
    /// Contact location at the end of the step (m), on the fitted path.
    pub k2_final_m: R,
    /// Fitted radius (m); zero for the vertex model.
    pub radius_m: R,
    /// Standard uncertainty of the radius (m) (of the linearised fit when the vertex model was
    /// kept: how well R could have been seen).
    pub sigma_radius_m: R,
    /// True when σ(R)/R is small enough to trust the radius ([`PathFitConfig::radius_rel_sigma`]).
    pub radius_observable: bool,
    /// Model used for the result.
    pub object: FittedObject,
    /// Friction offset of the measured torque while loading (N·m).
    pub friction_nm: R,
    /// Stiffness dT_a/dθa of the fitted path at contact (N·m/rad) (= Eq. 2 at k2,c).
    pub kc_contact: R,
    /// RMS of the bin residuals (N·m).
    pub rms_residual_nm: R,
    /// χ² per degree of freedom of the fit against the noise estimate.
    pub chi2_per_dof: R,
    /// θa bins used.
    pub bins: u8,
    /// Samples used (past the dead band).
    pub samples_used: u32,
    /// Path evaluations spent.
    pub path_evals: u8,
    /// Newton iterations spent on path points.
    pub newton_iters: u32,
    /// Exact four-bar closures evaluated.
    pub closures: u16,
    /// Configuration at contact (free motion from the fitted θa,c minus
    /// [`PathFitConfig::encoder_lead_rad`]: the finger's own θa).
    pub contact_config: Config<R>,
    /// The fitted actuator angle at contact (rad), in the caller's (encoder) frame.
    pub theta_a_c_rad: R,
    /// σ of the fitted θa,c (rad).
    pub sigma_theta_a_c_rad: R,
}

/// Why the path fit refused to answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PathFitError {
    /// The model failed at the contact configuration.
    Model(PtsError),
    /// Fewer than [`MIN_BINS`] θa bins hold samples after the dead band.
    TooFewSamples,
    /// The finger did not move enough during the step ([`PathFitConfig::min_travel_rad`]).
    NoMotion,
    /// The path is that of a proximal contact (k2,c at O2): detectable, not locatable.
    ProximalContact,
    /// The fitted contact slides past the distal tip during the step (or starts beyond it).
    PastTip,
    /// The fitted object cuts the proximal phalanx: a second contact.
    SecondContact,
    /// The residuals are far above the noise: the path model does not explain the samples.
    BadFit,
    /// σ(k2,c) is too large: this path does not determine k2.
    NotDetermined,
    /// The fit did not converge within its budget.
    NoConvergence,
}

impl PathFitError {
    /// A stable snake_case name for logs and JSON.
    pub const fn kind(&self) -> &'static str {
        match self {
            PathFitError::Model(e) => e.kind(),
            PathFitError::TooFewSamples => "too_few_samples",
            PathFitError::NoMotion => "no_motion",
            PathFitError::ProximalContact => "proximal_contact",
            PathFitError::PastTip => "past_tip",
            PathFitError::SecondContact => "second_contact",
            PathFitError::BadFit => "bad_fit",
            PathFitError::NotDetermined => "not_determined",
            PathFitError::NoConvergence => "no_convergence",
        }
    }
}

impl From<PtsError> for PathFitError {
    fn from(e: PtsError) -> Self {
        PathFitError::Model(e)
    }
}

impl core::fmt::Display for PathFitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PathFitError::Model(e) => write!(f, "model: {e}"),
            PathFitError::TooFewSamples => f.write_str("too few samples after the dead band"),
            PathFitError::NoMotion => f.write_str("the finger did not move during the step"),
            PathFitError::ProximalContact => f.write_str("proximal contact: not locatable"),
            PathFitError::PastTip => f.write_str("the contact slides past the distal tip"),
            PathFitError::SecondContact => f.write_str("second contact on the proximal phalanx"),
            PathFitError::BadFit => f.write_str("the path model does not explain the samples"),
            PathFitError::NotDetermined => f.write_str("k2 is not determined by this path"),
            PathFitError::NoConvergence => f.write_str("the fit did not converge"),
        }
    }
}

#[cfg(feature = "std")]
extern crate std;
#[cfg(feature = "std")]
impl std::error::Error for PathFitError {}

/// One θa bin: count and mean abscissa/ordinate.
#[derive(Clone, Copy, Debug)]
struct Bin<R> {
    n: u32,
    /// Mean θa − θa,c (given) (rad).
    dta: R,
    /// Mean measured T_a (N·m).
    t: R,
    /// Normalised weight n / N.
    w: R,
}

/// A solved path point kept for warm starts: hypothesis, configuration, sensitivities.
#[derive(Clone, Copy, Debug)]
struct Prev<R> {
    k2c: R,
    radius: R,
    dphi: R,
    d2: R,
    sens_k: (R, R),
    sens_r: (R, R),
}

/// The statistics of one fit shared by every kernel: bin counts, noise, priors, budget.
struct Work<R> {
    nb: usize,
    /// Pooled within-bin variance of one sample ((mN·m)²).
    var_sample: R,
    /// Total samples used.
    n_total: u32,
    /// 1 / N.
    inv_n: R,
    evals: usize,
    /// [`TSCALE`] in the back end.
    ks: R,
    /// Prior value and weight of each parameter (weight 0: none). T_f in N·m, θa,c in rad.
    prior: [R; NP],
    prior_w: [R; NP],
    /// θa,c the bins are measured from (rad).
    theta_a_c0: R,
}

impl<R: Real> Work<R> {
    fn new(theta_a_c0: R) -> Self {
        let z = R::zero();
        Self {
            nb: 0,
            var_sample: z,
            n_total: 0,
            inv_n: z,
            evals: 0,
            ks: R::from_f64(TSCALE),
            prior: [z; NP],
            prior_w: [z; NP],
            theta_a_c0,
        }
    }
}

/// What the fit needs from a path model and the binned samples: the generic
/// [`GenericKernel`] (any [`Real`], the reference) or the firmware's integer kernel
/// ([`q`]). The orchestration (priors, Levenberg–Marquardt, the radius decision, σ and the
/// refusals) is written once against it.
trait Kernel<R: Real> {
    /// Distal phalanx length (m).
    fn l2(&self) -> R;
    /// θa,c of the current contact configuration (rad, the finger's frame).
    fn theta_a_c(&self) -> R;
    /// T_a of the free-motion equilibrium at the current contact (N·m).
    fn tac(&self) -> R;
    /// The current contact configuration.
    fn contact(&self) -> Config<R>;
    /// Moves the contact to another θa,c (rad); drops the warm starts.
    fn set_contact(&mut self, theta_a_c: R) -> Result<(), PtsError>;
    /// The path at every bin for p = (k2c, R, ·, θa,c) (m, m, ·, rad), with the normal
    /// equations (see [`Eval`]); counts one evaluation in `w`.
    fn evaluate(&mut self, w: &mut Work<R>, p: &[R; NP], out: &mut Eval<R>)
        -> Result<(), PathFail>;
    /// Chord stiffness (N·m/rad) from the first bin above θa,c to the middle of the rest
    /// (`None` when the bins do not span enough θa).
    fn chord_stiffness(&self, nb: usize) -> Option<R>;
    /// See [`PathModel::proximal_clearance`].
    fn proximal_clearance(&self, k2c: R, radius: R, dphi: R, d2: R) -> Option<R>;
    /// Newton iterations and exact closures spent so far.
    fn counters(&self) -> (u32, u16);
}

/// The reference kernel: [`PathModel`] in the back end's own arithmetic.
struct GenericKernel<'m, R> {
    pm: PathModel<R>,
    model: &'m Model<R>,
    bins: [Bin<R>; MAX_BINS],
    /// The last solved point of each bin, to warm-start the next hypothesis.
    prev: [Option<Prev<R>>; MAX_BINS],
}

/// Result of one path evaluation at the bins.
#[derive(Clone, Copy, Debug)]
struct Eval<R> {
    /// Normal matrix JᵀWJ (+ priors) for (k2c/l2, R/l2, T_f, θa,c), in (mN·m)² units.
    a: [[R; NP]; NP],
    /// Gradient of ½ Σ w r² (+ priors).
    g: [R; NP],
    /// Σ w r² at the optimal T_f, priors included ((mN·m)²).
    sse: R,
    /// Optimal friction offset (N·m).
    tf: R,
    /// Contact location at the last bin (m).
    k2_last: R,
    /// Path stiffness at the first bin (N·m/rad).
    k_first: R,
    /// δφ, δ2 at the last bin (rad).
    last: (R, R),
}

impl<R: Real> Eval<R> {
    /// An evaluation slot before its first use.
    const ZERO: Self = Eval {
        a: [[R::ZERO; NP]; NP],
        g: [R::ZERO; NP],
        sse: R::ZERO,
        tf: R::ZERO,
        k2_last: R::ZERO,
        k_first: R::ZERO,
        last: (R::ZERO, R::ZERO),
    };
}

/// Converts a small count to the back end without going through f64 arithmetic at run time.
fn from_count<R: Real>(n: u32) -> R {
    // Binary expansion from the top set bit (≤ 8 doublings for the counts here), exact for
    // every back end that holds n.
    let mut acc = R::zero();
    if n == 0 {
        return acc;
    }
    let mut bit = 1u32 << (31 - n.leading_zeros());
    while bit > 0 {
        acc = acc + acc;
        if n & bit != 0 {
            acc = acc + R::one();
        }
        bit >>= 1;
    }
    acc
}

/// Fits the contact path.
///
/// `theta_a_c_rad` is the actuator angle at contact (absolute model angle) as the controller
/// found it (refined by the fit when [`PathFitConfig::contact_angle_sigma_rad`] > 0),
/// `approach_torque_nm` the torque measured on the free-motion (approach) line at that angle
/// (`None` if unknown: the friction offset is then fitted from the path alone), and
/// `samples` every (θa, T_a) from contact to the end of the step in time order (loading):
/// any cloneable, double-ended iterator (a slice's `iter().copied()`, or a map over the
/// controller's own buffer, so no copy is needed). It is traversed backwards once: a
/// sample counts only while θa stays below every later sample (the lower envelope in time),
/// which drops the inertial overshoot after impact; stiction plateaus are dropped
/// ([`PathFitConfig::drop_plateaus`]).
/// Returns the initial and final contact locations with σ, or why the path cannot determine
/// them.
pub fn fit_path<R: Real, I>(
    model: &Model<R>,
    cfg: &PathFitConfig,
    theta_a_c_rad: R,
    approach_torque_nm: Option<R>,
    samples: I,
) -> Result<PathFit<R>, PathFitError>
where
    I: IntoIterator<Item = PathSample<R>>,
    I::IntoIter: Clone + DoubleEndedIterator,
{
    let samples = samples.into_iter();
    if !theta_a_c_rad.is_finite() {
        return Err(PathFitError::Model(PtsError::NonFinite));
    }
    let c = FitConsts::new(cfg)?;
    // The bins are measured from the caller's (encoder) θa,c; the model works at the finger's
    // θa, behind the encoder by the backlash lead. Only θa differences enter the bins.
    let meas_c = theta_a_c_rad;
    let theta_a_c_rad = meas_c - c.lead;
    let mut pm = PathModel::new(model, theta_a_c_rad)?;
    pm.set_contact_mu(
        R::try_from_f64(cfg.contact_mu)
            .filter(|_| (0.0..2.0).contains(&cfg.contact_mu))
            .ok_or(PathFitError::Model(PtsError::OutOfRange))?,
    );
    let mut w = Work::new(theta_a_c_rad);
    let mut k = GenericKernel {
        pm,
        model,
        bins: [Bin {
            n: 0,
            dta: R::zero(),
            t: R::zero(),
            w: R::zero(),
        }; MAX_BINS],
        prev: [None; MAX_BINS],
    };
    bin_samples(&mut k.bins, &mut w, cfg, meas_c, samples)?;
    run_fit(&mut k, model, &c, &mut w, approach_torque_nm)
}

/// [`PathFitConfig`] in the back end (converted once: run-time f64 conversions cost soft
/// double on the target).
#[derive(Clone, Copy, Debug)]
struct FitConsts<R> {
    lead: R,
    noise_floor: R,
    friction_prior_sigma: R,
    contact_angle_sigma: R,
    fit_contact_angle: bool,
    object: ObjectModel,
    max_radius: R,
    inflation: R,
    sigma_floor: R,
    max_chi2: R,
    max_sigma_frac: R,
    tip_margin: R,
    radius_rel_sigma: R,
}

impl<R: Real> FitConsts<R> {
    fn new(cfg: &PathFitConfig) -> Result<Self, PathFitError> {
        let conv = |v: f64| R::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
        Ok(Self {
            lead: conv(cfg.encoder_lead_rad)?,
            noise_floor: conv(cfg.torque_noise_floor_nm)?,
            friction_prior_sigma: conv(cfg.friction_prior_sigma_nm)?,
            contact_angle_sigma: conv(cfg.contact_angle_sigma_rad)?,
            fit_contact_angle: cfg.fit_contact_angle,
            object: cfg.object,
            max_radius: conv(cfg.max_radius_m)?,
            inflation: conv(cfg.sigma_inflation)?,
            sigma_floor: conv(cfg.sigma_floor_m)?,
            max_chi2: conv(cfg.max_chi2)?,
            max_sigma_frac: conv(cfg.max_sigma_frac_l2)?,
            tip_margin: conv(cfg.tip_margin_frac_l2)?,
            radius_rel_sigma: conv(cfg.radius_rel_sigma)?,
        })
    }
}

/// Everything after the binning: priors, the fits, σ and the refusals (see [`fit_path`]).
#[inline(never)]
fn run_fit<R: Real, K: Kernel<R>>(
    pm: &mut K,
    model: &Model<R>,
    c: &FitConsts<R>,
    w: &mut Work<R>,
    approach_torque_nm: Option<R>,
) -> Result<PathFit<R>, PathFitError> {
    let zero = R::zero();
    let theta_a_c_rad = pm.theta_a_c();
    let l2 = pm.l2();
    let noise_s = c.noise_floor * w.ks;
    let s2_bins = (w.var_sample * w.inv_n).max(noise_s * noise_s * w.inv_n);
    let mut n_priors = 0u32;
    if let Some(tac) = approach_torque_nm {
        let sp = c.friction_prior_sigma;
        if !tac.is_finite() {
            return Err(PathFitError::Model(PtsError::NonFinite));
        }
        if sp > zero {
            w.prior[TF] = tac - pm.tac();
            let sps = sp * w.ks;
            w.prior_w[TF] = s2_bins / (sps * sps);
            n_priors += 1;
        }
    }
    let sc = c.contact_angle_sigma;
    let fit_contact = sc > zero && c.fit_contact_angle;
    let has_tc = sc > zero;
    if has_tc {
        w.prior[TC] = theta_a_c_rad;
        w.prior_w[TC] = s2_bins / (sc * sc);
        n_priors += 1;
    }

    // Initial k2,c from the chord stiffness of the first half of the bins, inverted at the
    // contact configuration (the two-point estimate on the early path).
    let k2_init = initial_k2(model, &pm.contact(), pm.chord_stiffness(w.nb), l2);
    let rmax = c.max_radius;
    let bounds = Bounds {
        k_lo: l2 * R::from_f64(K_LO_FRAC),
        l2,
        rmax,
        tc_lo: theta_a_c_rad - sc * R::from_f64(3.0),
        tc_hi: theta_a_c_rad + sc * R::from_f64(3.0),
        s2: s2_bins,
    };

    // Vertex model on (k2c, T_f[, θa,c]) first.
    let mut p = [k2_init, zero, zero, theta_a_c_rad];
    let vset = [true, false, true, fit_contact];
    let cset = [true, true, true, fit_contact];
    let nb_r = from_count::<R>(w.nb as u32);
    let dof = |npar: u32| (nb_r + from_count::<R>(n_priors) - from_count::<R>(npar)).max(R::one());
    let s2_of = |sse: R, npar: u32| -> R { (sse / dof(npar)).max(s2_bins) };
    let count = |s: &[bool; NP]| s.iter().filter(|&&b| b).count() as u32;

    // At a vertex hypothesis: marginal σ(R), the Gauss–Newton step with R free, and what an
    // unseen radius could do to k2c (regress the R column on the vertex parameters: δk2c =
    // per_r · R, for any R the data allow, ≤ 3σ(R), ≤ Rmax). The radius is fitted only when
    // such a radius would move k2c by more than half its σ and the data point to a positive
    // radius: a vertex, or a radius that cannot be seen or does not matter, costs no
    // curvature fit (its effect goes into σ).
    let decide = |e: &Eval<R>, full: &Option<Ldl<R>>| -> Result<Decision<R>, PathFitError> {
        let s2v = s2_of(e.sse, count(&vset));
        // One factorisation with R eliminated last (the one LM keeps for its next step): the
        // Gauss–Newton step with R free, the marginal variance of R (its reciprocal last
        // pivot), and, by the Schur complement, the vertex variance of k2c (the reciprocal
        // pivot of K just before) and the regression of the R column on the vertex
        // parameters (−L_RK).
        let (sigma_r_lin, var_kv, per_r) = match full {
            Some(f) => {
                let (var_kv, per_r, c_rr) = f.all().last_two();
                ((c_rr * s2v).max(zero).sqrt() * l2, var_kv, per_r)
            }
            None => {
                let mut own = None;
                ldl(&e.a, &vset, &mut own);
                let f = own.as_ref().ok_or(PathFitError::NotDetermined)?.all();
                let mut col = [zero; NP];
                for (j, on) in vset.iter().enumerate() {
                    if *on {
                        col[j] = e.a[j][RAD];
                    }
                }
                (rmax, f.last_var(), f.solve(&col)[K])
            }
        };
        let sigma_kv = (var_kv * s2v).max(zero).sqrt() * l2;
        let r_allowed = (sigma_r_lin * R::from_f64(3.0)).min(rmax);
        let bias_pot = (per_r * r_allowed).abs();
        // The Gauss–Newton step with R free only when the radius could matter (a vertex
        // hypothesis far from the threshold pays for no substitution).
        let matters = match c.object {
            ObjectModel::Vertex => false,
            ObjectModel::Cylinder => true,
            ObjectModel::Auto => bias_pot > sigma_kv * R::from_f64(0.5),
        };
        let (dk_lin, dr_lin, dtc_lin) = match (full, matters) {
            (Some(full), true) => {
                let f = full.all();
                let d = f.solve(&e.g);
                // The cylinder fit starts from this step; past the largest radius, from the
                // step with R there and the others optimal for it (R is eliminated last:
                // the leading block is the factorisation without it).
                let lead = full.without_last().filter(|_| d[RAD] * l2 > rmax);
                let (dk, dtc) = match lead {
                    Some(lead) => {
                        let dh = lead.solve_r_fixed(&e.a, &e.g, rmax / l2);
                        (dh[K], dh[TC])
                    }
                    None => (d[K], d[TC]),
                };
                (dk * l2, d[RAD] * l2, dtc)
            }
            _ => (zero, zero, zero),
        };
        let want = match c.object {
            ObjectModel::Auto => matters && dr_lin > sigma_r_lin && dr_lin > zero,
            _ => matters,
        };
        Ok(Decision {
            want,
            bias_pot,
            sigma_r_lin,
            dk_lin,
            dr_lin,
            dtc_lin,
        })
    };

    // The radius is decided at the first evaluation and after every accepted step of the
    // vertex fit: as soon as it clearly matters, its Gauss–Newton step with R free starts
    // the cylinder fit (the vertex fit's remaining iterations would be spent on a model that
    // is then dropped); otherwise the vertex fit runs to convergence and decides there.
    let mut lm = Lm {
        pm: &mut *pm,
        w: &mut *w,
        b: &bounds,
        full: cset,
        spare: Eval::ZERO,
    };
    let mut vertex: Factored<R> = (Eval::ZERO, None);
    lm.start(&mut p, &mut vertex)?;
    let mut dec = decide(&vertex.0, &vertex.1)?;
    let mut vertex_converged = false;
    if !dec.want {
        let mut last = None;
        let mut hook = |e: &Eval<R>, f: &Option<Ldl<R>>| match decide(e, f) {
            Ok(d) => {
                last = Some(d);
                d.want
            }
            Err(_) => false,
        };
        lm.run(&mut p, &vset, 8, &mut vertex, Some(&mut hook))?;
        // The decision at the returned (last accepted) hypothesis.
        dec = match last {
            Some(d) => d,
            None => dec,
        };
        vertex_converged = !dec.want;
    }
    let p_vertex = p;
    let mut pfit = p;
    let mut object = FittedObject::Vertex;
    let mut set = vset;
    let mut bias_k = dec.bias_pot;
    let mut cylinder = false;
    let mut cyl: Factored<R> = (Eval::ZERO, None);
    if dec.want {
        let mut pc = p_vertex;
        pc[K] = (pc[K] + dec.dk_lin).max(bounds.k_lo).min(l2);
        pc[RAD] = dec.dr_lin.max(zero).min(rmax);
        if fit_contact {
            pc[TC] = (pc[TC] + dec.dtc_lin).max(bounds.tc_lo).min(bounds.tc_hi);
        }
        let cyl_fit = lm
            .start(&mut pc, &mut cyl)
            .and_then(|()| lm.run(&mut pc, &cset, 10, &mut cyl, None));
        match cyl_fit {
            Ok(()) if cyl.0.sse <= vertex.0.sse => {
                pfit = pc;
                object = FittedObject::Cylinder;
                set = cset;
                bias_k = zero;
                cylinder = true;
            }
            // The cylinder fit failed or is no better: keep the vertex, with the bias.
            _ => {
                if fit_contact {
                    lm.pm.set_contact(p_vertex[TC])?;
                }
            }
        }
    }
    if !cylinder && !vertex_converged {
        // The cylinder fit was refused: the vertex fit to convergence after all.
        let mut pv = p_vertex;
        lm.run(&mut pv, &vset, 8, &mut vertex, None)?;
        dec = decide(&vertex.0, &vertex.1)?;
        pfit = pv;
        bias_k = dec.bias_pot;
    }
    let fit = if cylinder { &cyl } else { &vertex };
    let sigma_r_lin = dec.sigma_r_lin;
    let k2c = pfit[K];
    let radius = pfit[RAD];

    let npar = count(&set);
    let s2 = s2_of(fit.0.sse, npar);
    let chi2_raw = fit.0.sse / dof(npar) / s2_bins;
    // Refusals that need no covariance first (a refused path pays for no inversion).
    if !(k2c > l2 * R::from_f64(PROXIMAL_FRAC)) {
        return Err(PathFitError::ProximalContact);
    }
    if k2c > l2 || fit.0.k2_last > l2 * (R::one() - c.tip_margin) {
        return Err(PathFitError::PastTip);
    }
    if chi2_raw > c.max_chi2 {
        return Err(PathFitError::BadFit);
    }
    // The covariance also carries θa,c's uncertainty (its prior) when it was not fitted.
    let mut cset_final = set;
    cset_final[TC] = has_tc;
    let mut scratch = None;
    let var = factor_for(&fit.0.a, &cset_final, &cset, fit.1.as_ref(), &mut scratch)
        .map(|f| f.inverse_diagonal())
        .ok_or(PathFitError::NotDetermined)?;
    let fit = &fit.0;
    let var_k = var[K] * s2;
    let var_r = if object == FittedObject::Cylinder {
        var[RAD] * s2
    } else {
        sigma_r_lin * sigma_r_lin / (l2 * l2)
    };
    let var_tc = if has_tc { var[TC] * s2 } else { zero };
    let infl = c.inflation;
    let floor = c.sigma_floor;
    let sig_stat = var_k.max(zero).sqrt() * l2 * infl;
    // Bias of an unseen radius: half its possible range as one σ.
    let sig_bias = bias_k * R::from_f64(0.5);
    let sigma_k2 = (sig_stat * sig_stat + sig_bias * sig_bias + floor * floor).sqrt();
    let sigma_r = var_r.max(zero).sqrt() * l2;
    let chi2 = s2 / s2_bins;
    if sigma_k2 > l2 * c.max_sigma_frac {
        return Err(PathFitError::NotDetermined);
    }
    let zero_c = pm.proximal_clearance(k2c, radius, zero, zero);
    let end_c = pm.proximal_clearance(k2c, radius, fit.last.0, fit.last.1);
    if zero_c.is_some_and(|c| c < zero) || end_c.is_some_and(|c| c < zero) {
        return Err(PathFitError::SecondContact);
    }
    let radius_observable =
        object == FittedObject::Cylinder && radius > zero && sigma_r < radius * c.radius_rel_sigma;
    let rms = (fit.sse).max(zero).sqrt() / w.ks;
    Ok(PathFit {
        k2_contact_m: k2c,
        sigma_k2_m: sigma_k2,
        k2_final_m: fit.k2_last,
        radius_m: radius,
        sigma_radius_m: sigma_r,
        radius_observable,
        object,
        friction_nm: fit.tf,
        kc_contact: fit.k_first,
        rms_residual_nm: rms,
        chi2_per_dof: chi2,
        bins: w.nb as u8,
        samples_used: w.n_total,
        path_evals: w.evals as u8,
        newton_iters: pm.counters().0,
        closures: pm.counters().1,
        contact_config: pm.contact(),
        theta_a_c_rad: pfit[TC] + c.lead,
        sigma_theta_a_c_rad: var_tc.max(zero).sqrt(),
    })
}

/// The samples backwards in time with the inertial torque J θ̈a removed (θ̈a from the
/// second difference over each sample's neighbours; the end samples are left as they are).
struct Corrected<R, I> {
    it: I,
    inertia: R,
    drop_plateaus: bool,
    /// The later sample and the current one (reverse order: `next` was seen first).
    next: Option<PathSample<R>>,
    cur: Option<PathSample<R>>,
    done: bool,
    /// The uniform sample period h (s), its tolerance (s) and J/h² (kg·m²/s²).
    uniform: Option<(R, R, R)>,
}

impl<R: Real, I: Iterator<Item = PathSample<R>>> Iterator for Corrected<R, I> {
    type Item = PathSample<R>;
    fn next(&mut self) -> Option<PathSample<R>> {
        loop {
            if self.done {
                // Flush the earliest sample uncorrected.
                return self.cur.take();
            }
            let Some(prev) = self.it.next() else {
                self.done = true;
                continue;
            };
            let out = match (self.next, self.cur) {
                (Some(n), Some(c))
                    if self.drop_plateaus
                        && (c.theta_a_rad == prev.theta_a_rad
                            || c.theta_a_rad == n.theta_a_rad) =>
                {
                    None
                }
                (Some(n), Some(c)) => {
                    let (dt1, dt2) = (c.time_s - prev.time_s, n.time_s - c.time_s);
                    let mut s = c;
                    if dt1 > R::zero() && dt2 > R::zero() && self.inertia > R::zero() {
                        let (d1, d2) = (
                            c.theta_a_rad - prev.theta_a_rad,
                            n.theta_a_rad - c.theta_a_rad,
                        );
                        let near = |a: R, b: R, tol: R| (a - b).abs() <= tol;
                        let jacc = match self.uniform {
                            // A uniform sample period (the controller's, to rounding): J/h²
                            // once, no division per sample.
                            Some((h, tol, k)) if near(dt1, h, tol) && near(dt2, h, tol) => {
                                k * (d2 - d1)
                            }
                            _ => {
                                let tol = dt1 * R::from_f64(1e-6);
                                if near(dt1, dt2, tol) {
                                    let k = self.inertia / (dt1 * dt1);
                                    self.uniform = Some((dt1, tol, k));
                                    k * (d2 - d1)
                                } else {
                                    let span = n.time_s - prev.time_s;
                                    self.inertia * (d2 / dt2 - d1 / dt1) * R::from_f64(2.0) / span
                                }
                            }
                        };
                        s.torque_nm = c.torque_nm - jacc;
                    }
                    Some(s)
                }
                (None, Some(c)) => Some(c),
                _ => None,
            };
            self.next = self.cur;
            self.cur = Some(prev);
            if out.is_some() {
                return out;
            }
        }
    }
}

fn corrected_rev<R: Real, I: DoubleEndedIterator<Item = PathSample<R>>>(
    samples: I,
    inertia: R,
    drop_plateaus: bool,
) -> Corrected<R, core::iter::Rev<I>> {
    Corrected {
        it: samples.rev(),
        inertia,
        drop_plateaus,
        next: None,
        cur: None,
        done: false,
        uniform: None,
    }
}

/// The lower envelope in time of samples given backwards: a sample is kept when its θa is
/// below every later sample's plus `tol` (the inertial overshoot after impact is dropped,
/// the small oscillation about the path, whose torque J θ̈a removed, is kept), and differs
/// from the previously kept one (one sample per stiction plateau: the last, in time).
fn envelope<R: Real, I: Iterator<Item = PathSample<R>>>(
    samples: I,
    tol: R,
) -> impl Iterator<Item = PathSample<R>> {
    let mut min: Option<R> = None;
    let mut last: Option<R> = None;
    let eps = R::from_f64(1e-7);
    samples.filter(move |s| {
        let th = s.theta_a_rad;
        let below = min.is_none_or(|m| th < m + tol);
        let moved = last.is_none_or(|l| (th - l).abs() > eps);
        let keep = below && moved;
        if keep {
            last = Some(th);
        }
        min = Some(min.map_or(th, |m| m.min(th)));
        keep
    })
}

/// Bins the samples in one backwards pass (inertia removed, plateaus dropped, lower
/// envelope in time). The bins span θa,c (+ dead band and skip) to the θa of the last sample
/// the envelope keeps — the first one this pass sees; every later kept sample lies below it
/// plus the envelope tolerance and falls in the last bin. Each bin also accumulates the
/// second moments about its first sample, so the within-bin scatter about the local trend
/// needs no second pass.
fn bin_samples<R: Real, I: Iterator<Item = PathSample<R>> + Clone + DoubleEndedIterator>(
    bins: &mut [Bin<R>; MAX_BINS],
    w: &mut Work<R>,
    cfg: &PathFitConfig,
    theta_a_c: R,
    samples: I,
) -> Result<(), PathFitError> {
    let conv = |v: f64| R::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
    let nbins = (cfg.bins as usize).clamp(MIN_BINS, MAX_BINS);
    let dead = conv(cfg.dead_band_rad)?;
    let min_travel = conv(cfg.min_travel_rad)?;
    let span = conv(cfg.approach_span_rad)?;
    let skip = conv(cfg.skip_fraction)?;
    let approach = cfg.fit_contact_angle && cfg.contact_angle_sigma_rad > 0.0 && span > R::zero();
    let inertia = conv(cfg.inertia_kgm2)?;
    let tol = conv(cfg.envelope_tol_rad)?;
    let z = R::zero();
    // Per bin: count, reference sample (θ, T), Σdθ, Σdt, Σdθ², Σdt², Σdθ·dt about it.
    let mut cnt = [0u32; MAX_BINS];
    let mut acc = [[z; 7]; MAX_BINS];
    let mut bad = false;
    let mut frame: Option<(R, R)> = None; // (lo, width)
    let finite = samples.inspect(|s| {
        if !s.theta_a_rad.is_finite() || !s.torque_nm.is_finite() || !s.time_s.is_finite() {
            bad = true;
        }
    });
    for s in envelope(corrected_rev(finite, inertia, cfg.drop_plateaus), tol) {
        let (lo, width) = match frame {
            Some(f) => f,
            None => {
                let hi = s.theta_a_rad;
                let travel = hi - theta_a_c - dead;
                if !(travel > min_travel) {
                    return Err(PathFitError::NoMotion);
                }
                let lo = if approach {
                    theta_a_c - span
                } else {
                    theta_a_c + dead + travel * skip
                };
                let f = (lo, (hi - lo) / from_count::<R>(nbins as u32));
                frame = Some(f);
                f
            }
        };
        let th = s.theta_a_rad;
        if th < lo {
            continue;
        }
        let mut edge = lo + width;
        let mut i = 0usize;
        while i + 1 < nbins && th >= edge {
            edge = edge + width;
            i += 1;
        }
        if let (Some(c), Some(a)) = (cnt.get_mut(i), acc.get_mut(i)) {
            if *c == 0 {
                a[0] = th - theta_a_c;
                a[1] = s.torque_nm;
            }
            let dth = th - theta_a_c - a[0];
            let dt = (s.torque_nm - a[1]) * w.ks;
            a[2] = a[2] + dth;
            a[3] = a[3] + dt;
            a[4] = a[4] + dth * dth;
            a[5] = a[5] + dt * dt;
            a[6] = a[6] + dth * dt;
            *c = c.saturating_add(1);
        }
    }
    if bad {
        return Err(PathFitError::Model(PtsError::NonFinite));
    }
    if frame.is_none() {
        return Err(PathFitError::NoMotion);
    }
    let mut nb = 0usize;
    let mut total = 0u32;
    // Centered second moments of each used bin: (Sθθ, Stt, Sθt) in (rad², (mN·m)², rad·mN·m).
    let mut mom = [[z; 3]; MAX_BINS];
    for (&c, a) in cnt.iter().zip(acc.iter()).take(nbins) {
        if c == 0 {
            continue;
        }
        let inv = R::one() / from_count::<R>(c);
        let (mth, mt) = (a[2] * inv, a[3] * inv);
        if let (Some(b), Some(m)) = (bins.get_mut(nb), mom.get_mut(nb)) {
            *b = Bin {
                n: c,
                dta: a[0] + mth,
                t: a[1] + mt / w.ks,
                w: z,
            };
            *m = [a[4] - a[2] * mth, a[5] - a[3] * mt, a[6] - a[2] * mt];
        }
        nb += 1;
        total = total.saturating_add(c);
    }
    if nb < MIN_BINS {
        return Err(PathFitError::TooFewSamples);
    }
    // Within-bin scatter about the local trend (slope from the neighbouring bin means): the
    // noise estimate must not contain the path's own rise across a bin.
    let mut ss = z;
    for i in 0..nb {
        let a = bins.get(i.saturating_sub(1));
        let b = bins.get((i + 1).min(nb - 1));
        let mut sl = z;
        if let (Some(a), Some(b)) = (a, b) {
            let dth = b.dta - a.dta;
            if dth > R::from_f64(1e-7) {
                sl = (b.t - a.t) * w.ks / dth;
            }
        }
        if let Some(m) = mom.get(i) {
            // sl·(sl·Sθθ), not sl²·Sθθ: sl² (mN·m/rad)² can leave Fx32's range.
            let v = m[1] - R::from_f64(2.0) * sl * m[2] + sl * (sl * m[0]);
            ss = ss + v.max(z);
        }
    }
    let n_r = from_count::<R>(total);
    let dof = from_count::<R>(total.saturating_sub(nb as u32).max(1));
    w.var_sample = ss / dof;
    w.inv_n = R::one() / n_r;
    for b in bins.iter_mut().take(nb) {
        b.w = from_count::<R>(b.n) * w.inv_n;
    }
    w.nb = nb;
    w.n_total = total;
    Ok(())
}

/// Initial k2,c: the chord stiffness of the early path inverted at the contact
/// configuration (the two-point estimate on the first half of the bins).
fn initial_k2<R: Real>(model: &Model<R>, cfg: &Config<R>, chord: Option<R>, l2: R) -> R {
    let fallback = l2 * R::from_f64(0.5);
    let Some(kc) = chord else {
        return fallback;
    };
    match model.invert(cfg, kc) {
        Ok(c) => match c.k2 {
            Some(k) => k.max(l2 * R::from_f64(0.05)).min(l2 * R::from_f64(0.95)),
            None => l2 * R::from_f64(0.1),
        },
        Err(PtsError::BeyondTip) => l2 * R::from_f64(0.9),
        Err(_) => fallback,
    }
}

/// Chord from the first bin above θa,c to the middle of the rest (N·m/rad).
fn chord_of<R: Real>(bins: &[Bin<R>]) -> Option<R> {
    let i0 = bins.iter().position(|b| b.dta > R::zero()).unwrap_or(0);
    let a = bins.get(i0)?;
    let b = bins.get(i0 + (bins.len().saturating_sub(i0)) / 2)?;
    let dth = b.dta - a.dta;
    if !(dth > R::from_f64(1e-6)) {
        return None;
    }
    Some((b.t - a.t) / dth)
}

impl<R: Real> Kernel<R> for GenericKernel<'_, R> {
    fn l2(&self) -> R {
        self.pm.l2()
    }
    fn theta_a_c(&self) -> R {
        self.pm.theta_a_c
    }
    fn tac(&self) -> R {
        self.pm.tac
    }
    fn contact(&self) -> Config<R> {
        self.pm.contact
    }
    fn set_contact(&mut self, theta_a_c: R) -> Result<(), PtsError> {
        if theta_a_c != self.pm.theta_a_c {
            self.pm.set_contact(self.model, theta_a_c)?;
            self.prev = [None; MAX_BINS];
        }
        Ok(())
    }
    fn evaluate(
        &mut self,
        w: &mut Work<R>,
        p: &[R; NP],
        out: &mut Eval<R>,
    ) -> Result<(), PathFail> {
        *out = evaluate(self, w, p)?;
        Ok(())
    }
    fn chord_stiffness(&self, nb: usize) -> Option<R> {
        chord_of(self.bins.get(..nb)?)
    }
    fn proximal_clearance(&self, k2c: R, radius: R, dphi: R, d2: R) -> Option<R> {
        self.pm.proximal_clearance(k2c, radius, dphi, d2)
    }
    fn counters(&self) -> (u32, u16) {
        (self.pm.newton_iters, self.pm.closures)
    }
}

/// Evaluates the path at every bin for p = (k2c, R, ·, θa,c) (m, m, ·, rad) and accumulates
/// the normal equations.
#[allow(clippy::needless_range_loop)]
fn evaluate<R: Real>(
    k: &mut GenericKernel<'_, R>,
    w: &mut Work<R>,
    p: &[R; NP],
) -> Result<Eval<R>, PathFail> {
    w.evals += 1;
    let (k2c, radius, tc) = (p[K], p[RAD], p[TC]);
    k.set_contact(tc)?;
    let (pm, model) = (&mut k.pm, k.model);
    let shift = tc - w.theta_a_c0;
    let l2 = pm.l2();
    let z = R::zero();
    let ks = w.ks;
    let mut prev_pt: Option<(R, R, R, (R, R))> = None;
    let mut prev_first = true;
    let mut tf = z;
    let mut k_first = z;
    let mut k2_last = z;
    let mut last = (z, z);
    let mut res = [z; MAX_BINS];
    let mut cols = [[z; NP]; MAX_BINS];
    for (i, b) in k.bins.iter().take(w.nb).enumerate() {
        let dta = b.dta - shift;
        if !(dta > R::from_f64(1e-6)) {
            // Below the contact: free motion, linearised about θa,c (its slope is the
            // free-motion stiffness, so moving θa,c does not move these points).
            let r = b.t - (pm.tac + pm.kfree * dta);
            tf = tf + b.w * r;
            if let (Some(x), Some(c)) = (res.get_mut(i), cols.get_mut(i)) {
                *x = r;
                *c = [z, z, ks, z];
            }
            continue;
        }
        // Warm start: this bin's point of the previous hypothesis moved by its sensitivities,
        // else the previous bin's point moved along its tangent, else the tangent at contact.
        let guess = match (k.prev.get(i).copied().flatten(), prev_pt) {
            (Some(q), _) => {
                let (dk, dr) = (k2c - q.k2c, radius - q.radius);
                (
                    q.dphi + q.sens_k.0 * dk + q.sens_r.0 * dr,
                    q.d2 + q.sens_k.1 * dk + q.sens_r.1 * dr,
                )
            }
            (None, Some((dta0, dphi0, d20, t))) => {
                let step = dta - dta0;
                (dphi0 + t.0 * step, d20 + t.1 * step)
            }
            (None, None) => {
                let t = pm.tangent(model, k2c, radius, z, z)?;
                (t.0 * dta, t.1 * dta)
            }
        };
        let pt = pm.point(model, k2c, radius, dta, guess)?;
        prev_pt = Some((dta, pt.dphi, pt.d2, pt.tangent));
        if let Some(slot) = k.prev.get_mut(i) {
            *slot = Some(Prev {
                k2c,
                radius,
                dphi: pt.dphi,
                d2: pt.d2,
                sens_k: pt.sens_k,
                sens_r: pt.sens_r,
            });
        }
        if prev_first {
            k_first = pt.stiffness;
            prev_first = false;
        }
        k2_last = pt.k2;
        last = (pt.dphi, pt.d2);
        let r = b.t - pt.ta;
        tf = tf + b.w * r;
        if let (Some(x), Some(c)) = (res.get_mut(i), cols.get_mut(i)) {
            *x = r;
            // ∂T_model/∂p, in mN·m per (l2, l2, N·m, rad).
            *c = [
                pt.dta_dk2c * l2 * ks,
                pt.dta_dr * l2 * ks,
                ks,
                (pm.kfree - pt.stiffness) * ks,
            ];
        }
    }
    // Optimal offset with the approach prior: (Σ w r + w_p T_f,prior)/(1 + w_p) (Σ w = 1).
    let wp = w.prior_w[TF];
    tf = (tf + wp * w.prior[TF]) / (R::one() + wp);
    let mut a = [[z; NP]; NP];
    let mut g = [z; NP];
    let dp = (w.prior[TF] - tf) * ks;
    let mut sse = wp * dp * dp;
    a[TF][TF] = wp * ks * ks;
    g[TF] = -wp * ks * dp;
    let wc = w.prior_w[TC];
    let dc = w.prior[TC] - tc;
    sse = sse + wc * dc * dc;
    a[TC][TC] = wc;
    g[TC] = -wc * dc;
    // The upper triangle with the weight applied once per column, then mirrored.
    for ((b, &r0), col) in k.bins.iter().take(w.nb).zip(res.iter()).zip(cols.iter()) {
        let r = (r0 - tf) * ks;
        let wr = b.w * r;
        sse = sse + wr * r;
        for (i, ci) in col.iter().enumerate() {
            g[i] = g[i] - wr * *ci;
            let wci = b.w * *ci;
            for j in i..NP {
                a[i][j] = a[i][j] + wci * col[j];
            }
        }
    }
    for i in 1..NP {
        for j in 0..i {
            a[i][j] = a[j][i];
        }
    }
    Ok(Eval {
        a,
        g,
        sse,
        tf,
        k2_last,
        k_first,
        last,
    })
}

/// The radius decision at a vertex hypothesis (see `fit_path`).
#[derive(Clone, Copy)]
struct Decision<R> {
    /// Fit the radius.
    want: bool,
    /// Largest k2c bias (m) a radius the data allow could cause.
    bias_pot: R,
    /// Marginal σ(R) of the linearised fit (m).
    sigma_r_lin: R,
    /// Gauss–Newton step of k2c and R with R free (m), and of θa,c (rad).
    dk_lin: R,
    dr_lin: R,
    dtc_lin: R,
}

/// Parameter bounds of the fit.
struct Bounds<R> {
    k_lo: R,
    l2: R,
    rmax: R,
    tc_lo: R,
    tc_hi: R,
    /// Noise variance of the bin means ((mN·m)²): the scale of χ² for the stop test.
    s2: R,
}

/// LM ends when the step would lower χ² by less than this: the parameters would move by
/// less than a quarter of their σ (√0.05 ≈ 0.22), and a poorly determined radius is not
/// iterated to the absolute tolerance. On the grid 0.05 against 0.01 moved the realistic
/// mean/max error from 0.51/1.84 to 0.52/1.79 % of l2 and took 32 of 160 fits from 4 path
/// evaluations to 3.
const CHI2_TOL: f64 = 0.05;
/// LM ends after an accepted step that lowered χ² by less than this.
const CHI2_GAIN_TOL: f64 = 0.05;

/// A hypothesis LM accepted: its evaluation and the factorisation of its normal matrix on
/// the full parameter set (`None` where that is singular). The factorisation serves the
/// next Gauss–Newton step (on a subset that leaves out R, its leading block), the radius
/// decision and the final covariance: one LDLᵀ per accepted evaluation.
type Factored<R> = (Eval<R>, Option<Ldl<R>>);

/// LM's hook on every accepted hypothesis: `true` ends the fit (see `run_fit`).
type StopHook<'a, R> = &'a mut dyn FnMut(&Eval<R>, &Option<Ldl<R>>) -> bool;

/// What the Levenberg–Marquardt runs of one fit share: the path model, the work, the
/// bounds, the full parameter set (the one the kept factorisations cover) and the trial
/// evaluation's slot. The evaluations and factorisations are written in place, never moved:
/// on the Cortex-M4 each move of an evaluation is a 208-byte copy.
struct Lm<'a, R, K> {
    pm: &'a mut K,
    w: &'a mut Work<R>,
    b: &'a Bounds<R>,
    full: [bool; NP],
    spare: Eval<R>,
}

impl<R: Real, K: Kernel<R>> Lm<'_, R, K> {
    /// The evaluation at `p` into `fit`, with its factorisation; a hypothesis whose path
    /// leaves the phalanx moves k2c inward (at most four tries).
    #[inline(never)]
    fn start(&mut self, p: &mut [R; NP], fit: &mut Factored<R>) -> Result<(), PathFitError> {
        let b = self.b;
        let mut tries = 0;
        loop {
            match self.pm.evaluate(self.w, p, &mut fit.0) {
                Ok(()) => {
                    ldl(&fit.0.a, &self.full, &mut fit.1);
                    return Ok(());
                }
                Err(PathFail::Model(e)) => return Err(PathFitError::Model(e)),
                Err(PathFail::PastTip) => p[K] = (p[K] + b.k_lo) * R::from_f64(0.5),
                Err(_) => p[K] = (p[K] + b.l2) * R::from_f64(0.5),
            }
            tries += 1;
            if tries >= 4 || self.w.evals >= MAX_EVALS {
                return Err(PathFitError::PastTip);
            }
        }
    }

    /// Levenberg–Marquardt on the parameters marked in `set` (T_f is always eliminated inside
    /// [`evaluate`] but kept in the normal matrix for its coupling), from `fit`, the
    /// evaluation at `p`, which receives the last accepted hypothesis. Undamped
    /// (Gauss–Newton, from the kept factorisation) until a step fails; damped from then on
    /// until steps succeed again. Bounded: `iters` steps and the global [`MAX_EVALS`]; `stop`
    /// sees every accepted evaluation and may end the fit.
    /// One instance per back end (the hook is `dyn`, the function never inlined): four
    /// inlined copies cost the firmware ≈ 9 KB of flash for nothing measurable in time.
    #[inline(never)]
    fn run(
        &mut self,
        p: &mut [R; NP],
        set: &[bool; NP],
        iters: usize,
        fit: &mut Factored<R>,
        mut stop: Option<StopHook<'_, R>>,
    ) -> Result<(), PathFitError> {
        let Lm {
            pm,
            w,
            b,
            full,
            spare,
        } = self;
        let (b, full) = (*b, &*full);
        let z = R::zero();
        let step_tol = R::from_f64(STEP_TOL);
        let tc_tol = R::from_f64(1e-5);
        // The accepted evaluation and the trial's: two slots (`fit`'s and `spare`) whose roles
        // swap on acceptance.
        let mut best_in_spare = false;
        // The factorisation of a damped or reduced matrix, when the kept one does not serve.
        let mut scratch: Option<Ldl<R>> = None;
        {
            let (best_slot, fact) = (&mut fit.0, &mut fit.1);
            let (mut best, mut trial_e) = (best_slot, &mut *spare);
            // Damping: 0 (Gauss–Newton) until a step fails, then 1e-2, ×10 per failure and ×0.3
            // per success, back to 0 below 1e-3 (where it changes the step by < 0.1 %).
            let mut mu = z;
            let mu_off = R::from_f64(1e-3);
            let mut iter = 0usize;
            while iter < iters && w.evals < MAX_EVALS {
                iter += 1;
                let best_e: &Eval<R> = best;
                // The Gauss–Newton (or damped) step on `set`; with R's step fixed at `r_fixed`
                // (units of l2) when given.
                let step = |set: &[bool; NP], scratch: &mut Option<Ldl<R>>, r_fixed: Option<R>| {
                    let f = if mu == z {
                        factor_for(&best_e.a, set, full, fact.as_ref(), scratch)
                    } else {
                        let mut a = best_e.a;
                        for (i, row) in a.iter_mut().enumerate() {
                            if let Some(d) = row.get_mut(i) {
                                *d = *d * (R::one() + mu);
                            }
                        }
                        ldl(&a, set, scratch);
                        scratch.as_ref().map(Ldl::all)
                    }?;
                    Some(match r_fixed {
                        None => f.solve(&best_e.g),
                        Some(dr) => f.solve_r_fixed(&best_e.a, &best_e.g, dr),
                    })
                };
                let Some(mut d) = step(set, &mut scratch, None) else {
                    break;
                };
                // A step that takes the radius past a bound stops it there, and the other
                // parameters take the step that is optimal with R's step so fixed (the active
                // set), not the one that assumed it goes on (that projected step can raise χ²:
                // a wasted path).
                if set[RAD] {
                    let r = p[RAD] + d[RAD] * b.l2;
                    let r_to = if r > b.rmax {
                        Some(b.rmax)
                    } else if r < z {
                        Some(z)
                    } else {
                        None
                    };
                    if let Some(r_to) = r_to {
                        let mut held = *set;
                        held[RAD] = false;
                        match step(&held, &mut scratch, Some((r_to - p[RAD]) / b.l2)) {
                            Some(dh) => d = dh,
                            None => break,
                        }
                    }
                }
                // k2c held on its lower bound by a step that pushes it further in: the contact
                // is proximal there, which the fit refuses whatever T_f and θa,c become (the
                // bound lies below the refusal threshold). The others' steps, computed as if k2c
                // moved on, would only be spent, rejected one after another, on that refusal.
                if set[K] && !(p[K] > b.k_lo) && d[K] < z {
                    break;
                }
                let mut trial = *p;
                trial[K] = (p[K] + d[K] * b.l2).max(b.k_lo).min(b.l2);
                trial[RAD] = (p[RAD] + d[RAD] * b.l2).max(z).min(b.rmax);
                trial[TC] = (p[TC] + d[TC]).max(b.tc_lo).min(b.tc_hi);
                // Converged when the step that would be taken (projected on the bounds: a radius
                // pushed against its bound does not move) is below the tolerances.
                let moved = |i: usize, tol: R| (trial[i] - p[i]).abs() >= tol;
                if !moved(K, step_tol * b.l2) && !moved(RAD, step_tol * b.l2) && !moved(TC, tc_tol)
                {
                    break;
                }
                // The Gauss–Newton model's decrease of the objective, −gᵀd, against χ²'s scale.
                let mut pred = z;
                for (i, on) in set.iter().enumerate() {
                    if *on {
                        pred = pred - best_e.g[i] * d[i];
                    }
                }
                if pred < b.s2 * R::from_f64(CHI2_TOL) {
                    break;
                }
                match pm.evaluate(w, &trial, trial_e) {
                    Ok(()) if trial_e.sse <= best.sse => {
                        *p = trial;
                        let gain = best.sse - trial_e.sse;
                        core::mem::swap(&mut best, &mut trial_e);
                        best_in_spare = !best_in_spare;
                        ldl(&best.a, full, fact);
                        mu = mu * R::from_f64(0.3);
                        if mu < mu_off {
                            mu = z;
                        }
                        if stop.as_mut().is_some_and(|f| f(best, &*fact)) {
                            break;
                        }
                        // A step that lowered χ² by less than the tolerance: the valley is flat
                        // (the Gauss–Newton model over-promises there), more steps buy nothing.
                        if gain < b.s2 * R::from_f64(CHI2_GAIN_TOL) {
                            break;
                        }
                    }
                    Err(PathFail::Model(e)) => return Err(PathFitError::Model(e)),
                    _ => {
                        mu = if mu == z {
                            R::from_f64(1e-1)
                        } else {
                            mu * R::from_f64(10.0)
                        };
                        if mu > R::from_f64(1e4) {
                            break;
                        }
                    }
                }
            }
        }
        if best_in_spare {
            fit.0 = *spare;
        }
        // Leave the path model at the accepted contact (a rejected trial may have moved it).
        pm.set_contact(p[TC])?;
        Ok(())
    }
}

/// The factorisation of `a` on `set`: `f` (of `a` on `full`) itself when the sets agree,
/// its leading block when `set` is `full` without R (eliminated last, see [`ORDER`]),
/// else a new one, written to `scratch`.
fn factor_for<'a, R: Real>(
    a: &[[R; NP]; NP],
    set: &[bool; NP],
    full: &[bool; NP],
    f: Option<&'a Ldl<R>>,
    scratch: &'a mut Option<Ldl<R>>,
) -> Option<Factor<'a, R>> {
    let same_but_r = (0..NP).all(|i| i == RAD || set[i] == full[i]);
    match f {
        Some(f) if same_but_r && set[RAD] == full[RAD] => return Some(f.all()),
        Some(f) if same_but_r && full[RAD] && !set[RAD] => {
            if let Some(lead) = f.without_last() {
                return Some(lead);
            }
        }
        _ => {}
    }
    ldl(a, set, scratch);
    scratch.as_ref().map(Ldl::all)
}

/// LDLᵀ of the active submatrix of A scaled by powers of two, B = D A D with
/// D = diag(2^-k_i) ([`Real::half_log2`]: a diagonal in [½, 2), so that fixed point neither
/// overflows nor loses the pivots, and the scaling is exact): the active indices, their
/// count, the exponents, the unit lower factor L and the reciprocal pivots 1/P.
#[derive(Clone, Copy)]
struct Ldl<R> {
    idx: [usize; NP],
    n: usize,
    k: [i32; NP],
    l: [[R; NP]; NP],
    ip: [R; NP],
}

impl<R: Real> Ldl<R> {
    const ZERO: Self = Ldl {
        idx: [0; NP],
        n: 0,
        k: [0; NP],
        l: [[R::ZERO; NP]; NP],
        ip: [R::ZERO; NP],
    };
}

/// A factorisation on its first `n` parameters (all of them, or its leading block): what
/// the solves read, by reference.
#[derive(Clone, Copy)]
struct Factor<'a, R> {
    f: &'a Ldl<R>,
    n: usize,
}

/// The elimination order: R last and k2c just before it, so that their marginal
/// (co)variances come from the last two pivots ([`Factor::last_two`]).
const ORDER: [usize; NP] = [TF, TC, K, RAD];

/// `i` as an index into an `NP` array, without a bounds check (and so without a panic path
/// on the firmware): the identity for every index the factorisation forms, all below `NP`
/// (a power of two).
#[inline(always)]
const fn ix(i: usize) -> usize {
    i & (NP - 1)
}
const _: () = assert!(NP.is_power_of_two());

/// The factorisation of `a` on `set` into `out` (`None` when a pivot is not positive),
/// built in place.
#[allow(clippy::needless_range_loop)]
fn ldl<R: Real>(a: &[[R; NP]; NP], set: &[bool; NP], out: &mut Option<Ldl<R>>) {
    let z = R::zero();
    // Every entry the solves read (the strict lower triangle, the first n pivots, indices
    // and exponents) is written below: a slot is cleared only when first used.
    let f = out.get_or_insert(Ldl::ZERO);
    let mut n = 0usize;
    for &i in ORDER.iter() {
        if set[ix(i)] {
            // n ≤ 3 here: one of the NP entries of ORDER not yet seen.
            f.idx[ix(n)] = i;
            n += 1;
        }
    }
    let n = n.min(NP);
    f.n = n;
    for i in 0..n {
        let d = ix(f.idx[i]);
        match a[d][d].half_log2() {
            Some(k) => f.k[i] = k,
            None => {
                *out = None;
                return;
            }
        }
    }
    // U = L P below the diagonal (the eliminated entries before their division by the
    // pivot): every inner product then costs one multiplication per term.
    let mut u = [[z; NP]; NP];
    for j in 0..n {
        let jj = ix(f.idx[j]);
        let mut dj = a[jj][jj].ldexp(-2 * f.k[j]);
        for m in 0..j {
            dj = dj - f.l[j][m] * u[j][m];
        }
        if !(dj > R::from_f64(1e-7)) {
            *out = None;
            return;
        }
        f.ip[j] = R::one() / dj;
        for i in j + 1..n {
            let mut v = a[ix(f.idx[i])][jj].ldexp(-f.k[i] - f.k[j]);
            for m in 0..j {
                v = v - f.l[i][m] * u[j][m];
            }
            u[i][j] = v;
            f.l[i][j] = v * f.ip[j];
        }
    }
}

impl<R: Real> Ldl<R> {
    /// The factorisation on all its parameters.
    fn all(&self) -> Factor<'_, R> {
        Factor {
            f: self,
            n: self.n.min(NP),
        }
    }

    /// The factorisation of the leading block: without the parameter eliminated last (R,
    /// see [`ORDER`]). `None` when nothing is left.
    fn without_last(&self) -> Option<Factor<'_, R>> {
        let n = self.n.min(NP).checked_sub(1).filter(|&n| n > 0)?;
        Some(Factor { f: self, n })
    }
}

impl<R: Real> Factor<'_, R> {
    /// −A⁻¹ g on the active parameters (zero elsewhere): L y = −D g, Lᵀ x = y / P, D x.
    #[allow(clippy::needless_range_loop)]
    fn solve(&self, g: &[R; NP]) -> [R; NP] {
        let z = R::zero();
        let (idx, n, k, l) = (&self.f.idx, self.n.min(NP), &self.f.k, &self.f.l);
        let mut y = [z; NP];
        for i in 0..n {
            let mut v = -g[ix(idx[i])].ldexp(-k[i]);
            for m in 0..i {
                v = v - l[i][m] * y[m];
            }
            y[i] = v;
        }
        let mut x = [z; NP];
        for i in (0..n).rev() {
            let mut v = y[i] * self.f.ip[i];
            for m in i + 1..n {
                v = v - l[m][i] * x[m];
            }
            x[i] = v;
        }
        let mut out = [z; NP];
        for i in 0..n {
            out[ix(idx[i])] = x[i].ldexp(-k[i]);
        }
        out
    }

    /// The Gauss–Newton step with R's step fixed at `dr` (units of l2), for a factorisation
    /// on a set without R: the others' optimum given it, −A_oo⁻¹ (g_o + A_oR dr).
    fn solve_r_fixed(&self, a: &[[R; NP]; NP], g: &[R; NP], dr: R) -> [R; NP] {
        let mut gr = *g;
        for (i, v) in gr.iter_mut().enumerate() {
            if i != RAD {
                *v = *v + a[i][RAD] * dr;
            }
        }
        let mut d = self.solve(&gr);
        d[RAD] = dr;
        d
    }

    /// (A⁻¹)_ii of the last parameter eliminated (its reciprocal pivot, unscaled).
    fn last_var(&self) -> R {
        let j = ix(self.n.saturating_sub(1));
        self.f.ip[j].ldexp(-2 * self.f.k[j])
    }

    /// For the last two parameters eliminated, a then b: (the variance of a with b held,
    /// the regression of b's column on a, the marginal variance of b) =
    /// (1/P_a, −L_ba, (A⁻¹)_bb), unscaled.
    fn last_two(&self) -> (R, R, R) {
        let (a, b) = (ix(self.n.saturating_sub(2)), ix(self.n.saturating_sub(1)));
        let f = self.f;
        (
            f.ip[a].ldexp(-2 * f.k[a]),
            -f.l[b][a].ldexp(f.k[b] - f.k[a]),
            f.ip[b].ldexp(-2 * f.k[b]),
        )
    }

    /// The diagonal of the factored matrix's inverse at its parameters (zero elsewhere):
    /// (B⁻¹)_ii = Σ_q M_qi² / P_q with M = L⁻¹ by forward substitution, unscaled. The fit's
    /// variances need no more of the covariance.
    #[allow(clippy::needless_range_loop)]
    fn inverse_diagonal(&self) -> [R; NP] {
        let z = R::zero();
        let (n, f) = (self.n.min(NP), self.f);
        let l = &f.l;
        // M = L⁻¹ (unit lower): M[i][j] = −Σ_{m=j}^{i−1} L[i][m] M[m][j].
        let mut m = [[z; NP]; NP];
        for i in 0..n {
            m[i][i] = R::one();
            for j in 0..i {
                let mut v = z;
                for q in j..i {
                    v = v - l[i][q] * m[q][j];
                }
                m[i][j] = v;
            }
        }
        let mut out = [z; NP];
        for i in 0..n {
            let mut v = z;
            for q in i..n {
                v = v + m[q][i] * (m[q][i] * f.ip[q]);
            }
            out[ix(f.idx[i])] = v.ldexp(-2 * f.k[i]);
        }
        out
    }
}
