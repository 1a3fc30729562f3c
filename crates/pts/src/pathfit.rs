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
//! 1. Samples are binned by θa (the encoder is the precise axis) after a dead band that skips
//!    the stiction plateau and the impact right after contact (paper Fig. 9). Each bin keeps
//!    its sample count, mean θa, mean T_a and T_a scatter.
//! 2. Coulomb friction in the transmission shifts the measured torque by a constant while the
//!    finger moves one way: it is a free offset T_f of the fit (T_meas = T_path(θa) + T_f).
//! 3. Levenberg–Marquardt on (k2,c, T_f) with the vertex model (R = 0) first; the analytic
//!    sensitivity ∂T/∂R at that solution tells whether the radius can be seen in these data.
//!    Only then (object model `Auto`) the fit is extended to (k2,c, R, T_f): a vertex or an
//!    unobservable radius never pays for the curvature terms.
//! 4. σ(k2,c) from the fit covariance, with the noise level the larger of the residual scatter
//!    and the within-bin scatter, plus the bias an unseen radius could cause, plus a floor.
//!    A misfit (χ² far above the noise: second contact, contact past the tip, a path the model
//!    cannot produce) and a fitted path that ends past the tip or cuts the proximal phalanx are
//!    refused with a typed [`PathFitError`].
//!
//! No allocation, no panics, bounded iterations ([`MAX_EVALS`] path evaluations of at most
//! [`MAX_BINS`] points, each a warm-started Newton solve of ≤ [`path::MAX_PATH_NEWTON`] steps).
//! Generic over [`Real`]: f64 on the host, fixed point on the target.

#[path = "pathfit_path.rs"]
pub mod path;

use crate::{Config, Model, PtsError, Real};
use path::{PathFail, PathModel};

/// Largest number of θa bins.
pub const MAX_BINS: usize = 12;
/// Fewest bins with data the fit accepts.
pub const MIN_BINS: usize = 4;
/// Torque scale of the fit's statistics: residuals, columns and variances are kept in
/// mN·m so that their squares stay well inside fixed point's resolution (2⁻³² for Fx32).
const TSCALE: f64 = 1000.0;

/// Gauss–Newton steps below this (fraction of l2) end the fit without evaluating them.
const STEP_TOL: f64 = 2e-4;

/// Budget of path evaluations (each: ≤ [`MAX_BINS`] path points) over the whole fit.
pub const MAX_EVALS: usize = 24;

/// One measurement: actuator angle and torque at the same instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSample<R> {
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
}

impl PathFitConfig {
    /// Defaults for the paper's finger on a board with a quadrature encoder and a current ADC.
    pub const DEFAULT: PathFitConfig = PathFitConfig {
        bins: 12,
        dead_band_rad: 0.0,
        skip_fraction: 0.08,
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
    };
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
    /// Configuration at contact (free motion from θa,c).
    pub contact_config: Config<R>,
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
    /// Mean Δθa since contact (rad).
    dta: R,
    /// Mean measured T_a (N·m).
    t: R,
    /// Normalised weight n / N.
    w: R,
}

/// The working state of one fit: bins and constants (≈ 0.6 KB with Fx32, see the README).
struct Work<R> {
    bins: [Bin<R>; MAX_BINS],
    nb: usize,
    /// Pooled within-bin variance of one sample (N·m²).
    var_sample: R,
    /// Total samples used.
    n_total: u32,
    /// 1 / N.
    inv_n: R,
    evals: usize,
    /// Friction offset read from the approach (N·m) and its weight (0: no prior).
    tf_prior: R,
    w_prior: R,
    /// [`TSCALE`] in the back end.
    ks: R,
    /// The last solved point of each bin, to warm-start the next hypothesis.
    prev: [Option<Prev<R>>; MAX_BINS],
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

/// Result of one path evaluation at the bins.
#[derive(Clone, Copy, Debug)]
struct Eval<R> {
    /// Normal matrix JᵀWJ for (k2c/l2, R/l2, T_f) (symmetric, upper part used).
    a: [[R; 3]; 3],
    /// JᵀW r.
    g: [R; 3],
    /// Σ w r² at the optimal T_f for these (k2c, R) (N·m²).
    sse: R,
    /// Weighted mean of (T_meas − T_path): the optimal friction offset (N·m).
    tf: R,
    /// Contact location at the last bin (m).
    k2_last: R,
    /// Path stiffness at the first point (N·m/rad).
    k_first: R,
    /// δφ, δ2 at the last bin (rad).
    last: (R, R),
}

impl<R: Real> Work<R> {
    fn new() -> Self {
        let z = R::zero();
        Self {
            bins: [Bin {
                n: 0,
                dta: z,
                t: z,
                w: z,
            }; MAX_BINS],
            nb: 0,
            var_sample: z,
            n_total: 0,
            inv_n: z,
            evals: 0,
            tf_prior: z,
            w_prior: z,
            ks: R::from_f64(TSCALE),
            prev: [None; MAX_BINS],
        }
    }
}

/// Converts a small count to the back end without going through f64 arithmetic at run time.
fn from_count<R: Real>(n: u32) -> R {
    // Binary expansion: ≤ 32 doublings, exact for every back end that holds n.
    let mut acc = R::zero();
    let mut bit = 1u64 << 31;
    while bit > 0 {
        acc = acc + acc;
        if u64::from(n) & bit != 0 {
            acc = acc + R::one();
        }
        bit >>= 1;
    }
    acc
}

/// Fits the contact path.
///
/// `theta_a_c_rad` is the actuator angle at contact (absolute model angle),
/// `approach_torque_nm` the torque measured while the finger still moved freely just before
/// contact (`None` if unknown: the friction offset is then fitted from the path alone), and
/// `samples` every (θa, T_a) from contact to the end of the step in time order (loading):
/// any cloneable iterator (a slice's `iter().copied()`, or a map over the controller's own
/// sample buffer, so no copy is needed). It is traversed three times.
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
    I::IntoIter: Clone,
{
    let samples = samples.into_iter();
    if !theta_a_c_rad.is_finite() {
        return Err(PathFitError::Model(PtsError::NonFinite));
    }
    let conv = |v: f64| R::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
    let mut pm = PathModel::new(model, theta_a_c_rad)?;
    let l2 = pm.l2();
    let mut w = Work::new();
    bin_samples(&mut w, cfg, theta_a_c_rad, samples)?;

    // Initial k2,c from the chord stiffness of the first half of the bins, inverted at the
    // contact configuration (the two-point estimate on the early path).
    let contact_config = {
        let mut c = pm.contact;
        c.ta = pm.tac;
        c
    };
    let k2_init = initial_k2(model, &contact_config, &w, l2);
    let noise_w = conv(cfg.torque_noise_floor_nm)?;
    let noise_s = noise_w * w.ks;
    let s2_bins = (w.var_sample * w.inv_n).max(noise_s * noise_s * w.inv_n);
    if let Some(tac) = approach_torque_nm {
        let sp = conv(cfg.friction_prior_sigma_nm)?;
        if !tac.is_finite() {
            return Err(PathFitError::Model(PtsError::NonFinite));
        }
        if sp > R::zero() {
            w.tf_prior = tac - pm.tac;
            let sps = sp * w.ks;
            w.w_prior = s2_bins / (sps * sps);
        }
    }

    let zero = R::zero();
    let rmax = conv(cfg.max_radius_m)?;
    // Vertex fit on (k2c, T_f).
    let mut p = [k2_init, zero];
    let vertex = lm(&mut pm, model, &mut w, &mut p)?;
    let mut fit = vertex;
    let mut k2c = p[0];
    let mut radius = zero;
    let mut object = FittedObject::Vertex;

    // Noise per unit weight: the larger of residual scatter and within-bin scatter.
    let nb_r = from_count::<R>(w.nb as u32);
    let s2_of = |sse: R, npar: u32| -> R {
        let dof = nb_r - from_count::<R>(npar);
        let dof = dof.max(R::one());
        (sse / dof).max(s2_bins)
    };

    // Marginal σ(R) at the vertex solution, from the 3-parameter normal matrix.
    let s2v = s2_of(vertex.sse, 2);
    let cov3 = invert3(&vertex.a);
    let sigma_r_lin = match cov3 {
        Some(c) => (c[1][1] * s2v).sqrt() * l2,
        None => rmax,
    };
    // What an unseen radius could do to k2c: regress the R column on (k2c, T_f) at the vertex
    // solution (δk2c = per_r · R), for any R the data allow (≤ 3σ(R), ≤ Rmax).
    let (sigma_kv, per_r) = match invert2(&[
        [vertex.a[0][0], vertex.a[0][2]],
        [vertex.a[2][0], vertex.a[2][2]],
    ]) {
        Some(c2) => (
            (c2[0][0] * s2v).max(zero).sqrt() * l2,
            -(c2[0][0] * vertex.a[0][1] + c2[0][1] * vertex.a[2][1]),
        ),
        None => return Err(PathFitError::NotDetermined),
    };
    let r_allowed = (sigma_r_lin * R::from_f64(3.0)).min(rmax);
    let bias_pot = (per_r * r_allowed).abs();
    // The linearised (k2c, R, T_f) step off the vertex: does the data ask for a radius?
    let (dk_lin, dr_lin) = match cov3 {
        Some(c) => (
            -(c[0][0] * vertex.g[0] + c[0][1] * vertex.g[1] + c[0][2] * vertex.g[2]) * l2,
            -(c[1][0] * vertex.g[0] + c[1][1] * vertex.g[1] + c[1][2] * vertex.g[2]) * l2,
        ),
        None => (zero, zero),
    };
    let want_radius = match cfg.object {
        ObjectModel::Vertex => false,
        ObjectModel::Cylinder => true,
        // Fit the radius only when a radius the data allow would move k2c by more than half
        // its σ and the data point to a positive radius: a vertex, or a radius that cannot
        // be seen or does not matter, costs no curvature fit (its effect goes into σ).
        ObjectModel::Auto => {
            bias_pot > sigma_kv * R::from_f64(0.5) && dr_lin > sigma_r_lin && dr_lin > zero
        }
    };
    let mut bias_k = zero;
    if want_radius {
        let mut pr = [
            (k2c + dk_lin).max(l2 * R::from_f64(0.02)).min(l2),
            dr_lin.max(zero).min(rmax),
        ];
        match lm3(&mut pm, model, &mut w, &mut pr, rmax) {
            Ok(e) if e.sse <= vertex.sse => {
                fit = e;
                k2c = pr[0];
                radius = pr[1];
                object = FittedObject::Cylinder;
            }
            // The cylinder fit failed or is no better: keep the vertex, with the bias.
            _ => bias_k = bias_pot,
        }
    } else {
        bias_k = bias_pot;
    }

    let npar = if object == FittedObject::Cylinder {
        3
    } else {
        2
    };
    let s2 = s2_of(fit.sse, npar);
    let (var_k, var_r) = if object == FittedObject::Cylinder {
        match invert3(&fit.a) {
            Some(c) => (c[0][0] * s2, c[1][1] * s2),
            None => return Err(PathFitError::NotDetermined),
        }
    } else {
        match invert2(&[[fit.a[0][0], fit.a[0][2]], [fit.a[2][0], fit.a[2][2]]]) {
            Some(c) => (c[0][0] * s2, sigma_r_lin * sigma_r_lin / (l2 * l2)),
            None => return Err(PathFitError::NotDetermined),
        }
    };
    let infl = conv(cfg.sigma_inflation)?;
    let floor = conv(cfg.sigma_floor_m)?;
    let sig_stat = var_k.max(zero).sqrt() * l2 * infl;
    // Bias of an unseen radius: half its possible range as one σ.
    let sig_bias = bias_k * R::from_f64(0.5);
    let sigma_k2 = (sig_stat * sig_stat + sig_bias * sig_bias + floor * floor).sqrt();
    let sigma_r = var_r.max(zero).sqrt() * l2;
    let chi2 = s2_of(fit.sse, npar) / s2_bins;
    let chi2_raw = {
        let dof = (nb_r - from_count::<R>(npar)).max(R::one());
        fit.sse / dof / s2_bins
    };

    // Refusals.
    if !(k2c > l2 * R::from_f64(0.02)) {
        return Err(PathFitError::ProximalContact);
    }
    if k2c > l2 {
        return Err(PathFitError::PastTip);
    }
    if chi2_raw > conv(cfg.max_chi2)? {
        return Err(PathFitError::BadFit);
    }
    if sigma_k2 > l2 * conv(cfg.max_sigma_frac_l2)? {
        return Err(PathFitError::NotDetermined);
    }
    if fit.k2_last > l2 * (R::one() - conv(cfg.tip_margin_frac_l2)?) {
        return Err(PathFitError::PastTip);
    }
    let zero_c = pm.proximal_clearance(k2c, radius, zero, zero);
    let end_c = pm.proximal_clearance(k2c, radius, fit.last.0, fit.last.1);
    if zero_c.is_some_and(|c| c < zero) || end_c.is_some_and(|c| c < zero) {
        return Err(PathFitError::SecondContact);
    }
    let radius_observable = object == FittedObject::Cylinder
        && radius > zero
        && sigma_r < radius * conv(cfg.radius_rel_sigma)?;
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
        newton_iters: pm.newton_iters,
        closures: pm.closures,
        contact_config,
    })
}

fn bin_samples<R: Real, I: Iterator<Item = PathSample<R>> + Clone>(
    w: &mut Work<R>,
    cfg: &PathFitConfig,
    theta_a_c: R,
    samples: I,
) -> Result<(), PathFitError> {
    let conv = |v: f64| R::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
    let nbins = (cfg.bins as usize).clamp(MIN_BINS, MAX_BINS);
    let mut hi = theta_a_c;
    for s in samples.clone() {
        if !s.theta_a_rad.is_finite() || !s.torque_nm.is_finite() {
            return Err(PathFitError::Model(PtsError::NonFinite));
        }
        hi = hi.max(s.theta_a_rad);
    }
    let dead = conv(cfg.dead_band_rad)?;
    let travel = hi - theta_a_c - dead;
    if !(travel > conv(cfg.min_travel_rad)?) {
        return Err(PathFitError::NoMotion);
    }
    let lo = theta_a_c + dead + travel * conv(cfg.skip_fraction)?;
    let width = (hi - lo) / from_count::<R>(nbins as u32);
    // Half a bin of margin at the top so the final settled samples fall in the last bin.
    let mut sum_t = [R::zero(); MAX_BINS];
    let mut sum_th = [R::zero(); MAX_BINS];
    let mut cnt = [0u32; MAX_BINS];
    for s in samples.clone() {
        if s.theta_a_rad < lo {
            continue;
        }
        let mut edge = lo + width;
        let mut i = 0usize;
        while i + 1 < nbins && s.theta_a_rad >= edge {
            edge = edge + width;
            i += 1;
        }
        if let (Some(st), Some(sh), Some(c)) = (sum_t.get_mut(i), sum_th.get_mut(i), cnt.get_mut(i))
        {
            *st = *st + s.torque_nm;
            *sh = *sh + (s.theta_a_rad - theta_a_c);
            *c = c.saturating_add(1);
        }
    }
    // Means, then a second pass for the within-bin variance (about the bin mean).
    let mut nb = 0usize;
    let mut total = 0u32;
    let mut idx_map = [usize::MAX; MAX_BINS];
    for i in 0..nbins {
        let (Some(&c), Some(&st), Some(&sh)) = (cnt.get(i), sum_t.get(i), sum_th.get(i)) else {
            continue;
        };
        if c == 0 {
            continue;
        }
        let inv = R::one() / from_count::<R>(c);
        if let (Some(b), Some(m)) = (w.bins.get_mut(nb), idx_map.get_mut(i)) {
            *b = Bin {
                n: c,
                dta: sh * inv,
                t: st * inv,
                w: R::zero(),
            };
            *m = nb;
        }
        nb += 1;
        total = total.saturating_add(c);
    }
    if nb < MIN_BINS {
        return Err(PathFitError::TooFewSamples);
    }
    let mut ss = R::zero();
    for s in samples {
        if s.theta_a_rad < lo {
            continue;
        }
        let mut edge = lo + width;
        let mut i = 0usize;
        while i + 1 < nbins && s.theta_a_rad >= edge {
            edge = edge + width;
            i += 1;
        }
        if let Some(b) = idx_map.get(i).and_then(|&j| w.bins.get(j)) {
            // Remove the bin's trend: the local slope between neighbours is not known yet,
            // so use the deviation from the bin mean (over-estimates the noise a little).
            let d = (s.torque_nm - b.t) * w.ks;
            ss = ss + d * d;
        }
    }
    let n_r = from_count::<R>(total);
    let dof = from_count::<R>(total.saturating_sub(nb as u32).max(1));
    w.var_sample = ss / dof;
    w.inv_n = R::one() / n_r;
    for b in w.bins.iter_mut().take(nb) {
        b.w = from_count::<R>(b.n) * w.inv_n;
    }
    w.nb = nb;
    w.n_total = total;
    Ok(())
}

fn initial_k2<R: Real>(model: &Model<R>, cfg: &Config<R>, w: &Work<R>, l2: R) -> R {
    // Chord from the first bin to the middle bin.
    let first = w.bins.first();
    let mid = w.bins.get(w.nb / 2);
    let fallback = l2 * R::from_f64(0.5);
    let (Some(a), Some(b)) = (first, mid) else {
        return fallback;
    };
    let dth = b.dta - a.dta;
    if !(dth > R::from_f64(1e-6)) {
        return fallback;
    }
    let kc = (b.t - a.t) / dth;
    match model.invert(cfg, kc) {
        Ok(c) => match c.k2 {
            Some(k) => k.max(l2 * R::from_f64(0.05)).min(l2 * R::from_f64(0.95)),
            None => l2 * R::from_f64(0.1),
        },
        Err(PtsError::BeyondTip) => l2 * R::from_f64(0.9),
        Err(_) => fallback,
    }
}

/// Evaluates the path at every bin for (k2c, R) and accumulates the normal equations.
fn evaluate<R: Real>(
    pm: &mut PathModel<R>,
    model: &Model<R>,
    w: &mut Work<R>,
    k2c: R,
    radius: R,
) -> Result<Eval<R>, PathFail> {
    w.evals += 1;
    let l2 = pm.l2();
    let z = R::zero();
    let mut prev_pt: Option<(R, R, R, (R, R))> = None;
    let mut a = [[z; 3]; 3];
    let mut g = [z; 3];
    // First pass: residuals r = T_meas − T_path (T_f not yet removed) and the columns.
    let mut tf = z;
    let mut k_first = z;
    let mut k2_last = z;
    let mut last = (z, z);
    let mut res = [z; MAX_BINS];
    let mut jk = [z; MAX_BINS];
    let mut jr = [z; MAX_BINS];
    for (i, b) in w.bins.iter().take(w.nb).enumerate() {
        // Warm start: this bin's point of the previous hypothesis moved by its sensitivities,
        // else the previous bin's point moved along its tangent, else the tangent at contact.
        let guess = match (w.prev.get(i).copied().flatten(), prev_pt) {
            (Some(p), _) => {
                let (dk, dr) = (k2c - p.k2c, radius - p.radius);
                (
                    p.dphi + p.sens_k.0 * dk + p.sens_r.0 * dr,
                    p.d2 + p.sens_k.1 * dk + p.sens_r.1 * dr,
                )
            }
            (None, Some((dta0, dphi0, d20, t))) => {
                let step = b.dta - dta0;
                (dphi0 + t.0 * step, d20 + t.1 * step)
            }
            (None, None) => {
                let t = pm.tangent(model, k2c, radius, z, z)?;
                (t.0 * b.dta, t.1 * b.dta)
            }
        };
        let pt = pm.point(model, k2c, radius, b.dta, guess)?;
        prev_pt = Some((b.dta, pt.dphi, pt.d2, pt.tangent));
        if let Some(slot) = w.prev.get_mut(i) {
            *slot = Some(Prev {
                k2c,
                radius,
                dphi: pt.dphi,
                d2: pt.d2,
                sens_k: pt.sens_k,
                sens_r: pt.sens_r,
            });
        }
        if i == 0 {
            k_first = pt.stiffness;
        }
        k2_last = pt.k2;
        last = (pt.dphi, pt.d2);
        let r = b.t - pt.ta;
        tf = tf + b.w * r;
        if let (Some(x), Some(y), Some(q)) = (res.get_mut(i), jk.get_mut(i), jr.get_mut(i)) {
            *x = r;
            // Jacobian of the model T (residual Jacobian is its negative), per unit l2.
            *y = pt.dta_dk2c * l2;
            *q = pt.dta_dr * l2;
        }
    }
    // Optimal offset with the approach prior: (Σ w r + w_p T_f,prior)/(1 + w_p) (Σ w = 1).
    tf = (tf + w.w_prior * w.tf_prior) / (R::one() + w.w_prior);
    let ks = w.ks;
    let dp = (w.tf_prior - tf) * ks;
    let mut sse = w.w_prior * dp * dp;
    if let Some(row) = a.get_mut(2) {
        if let Some(x) = row.get_mut(2) {
            *x = *x + w.w_prior * ks * ks;
        }
    }
    if let Some(x) = g.get_mut(2) {
        *x = *x - w.w_prior * ks * dp;
    }
    for (i, b) in w.bins.iter().take(w.nb).enumerate() {
        let (Some(&r0), Some(&y), Some(&q)) = (res.get(i), jk.get(i), jr.get(i)) else {
            continue;
        };
        let r = (r0 - tf) * ks;
        sse = sse + b.w * r * r;
        let col = [y * ks, q * ks, ks];
        for (ri, ci) in a.iter_mut().zip(col.iter()) {
            for (aij, cj) in ri.iter_mut().zip(col.iter()) {
                *aij = *aij + b.w * *ci * *cj;
            }
        }
        // g = −Jᵀ W r with J = −col: the step solves A δ = Σ w col r.
        for (gi, ci) in g.iter_mut().zip(col.iter()) {
            *gi = *gi - b.w * *ci * r;
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

/// Levenberg–Marquardt on (k2c, T_f) with R = 0 (`p = [k2c, unused]`).
fn lm<R: Real>(
    pm: &mut PathModel<R>,
    model: &Model<R>,
    w: &mut Work<R>,
    p: &mut [R; 2],
) -> Result<Eval<R>, PathFitError> {
    let l2 = pm.l2();
    let z = R::zero();
    let lo = l2 * R::from_f64(0.01);
    let mut best = evaluate_or_shrink(pm, model, w, &mut p[0], z, lo, l2)?;
    let step_tol = R::from_f64(STEP_TOL);
    let mut mu = R::from_f64(1e-3);
    let mut iter = 0usize;
    while iter < 8 && w.evals < MAX_EVALS / 2 {
        iter += 1;
        // 2×2 on (k, T_f); T_f is eliminated in evaluate() but keep the coupling term.
        let a00 = best.a[0][0] * (R::one() + mu);
        let a02 = best.a[0][2];
        let a22 = best.a[2][2] * (R::one() + mu);
        let Some(c) = invert2(&[[a00, a02], [a02, a22]]) else {
            break;
        };
        let dk = -(c[0][0] * best.g[0] + c[0][1] * best.g[2]);
        // Converged: the Gauss–Newton step is below 2e-4 l2; do not pay for evaluating it.
        if dk.abs() < step_tol {
            break;
        }
        let trial = (p[0] + dk * l2).max(lo).min(l2);
        match evaluate(pm, model, w, trial, z) {
            Ok(e) if e.sse <= best.sse => {
                let moved = (trial - p[0]).abs();
                p[0] = trial;
                best = e;
                mu = (mu * R::from_f64(0.3)).max(R::from_f64(1e-6));
                if moved < l2 * R::from_f64(1e-6) {
                    break;
                }
            }
            _ => {
                mu = mu * R::from_f64(10.0);
                if mu > R::from_f64(1e4) {
                    break;
                }
            }
        }
    }
    Ok(best)
}

/// Evaluates at k2c; when the path fails (past the tip, say), moves k2c toward the middle.
fn evaluate_or_shrink<R: Real>(
    pm: &mut PathModel<R>,
    model: &Model<R>,
    w: &mut Work<R>,
    k2c: &mut R,
    radius: R,
    lo: R,
    hi: R,
) -> Result<Eval<R>, PathFitError> {
    let mut tries = 0;
    loop {
        match evaluate(pm, model, w, *k2c, radius) {
            Ok(e) => return Ok(e),
            Err(PathFail::Model(e)) => return Err(PathFitError::Model(e)),
            Err(PathFail::PastTip) => *k2c = (*k2c + lo) * R::from_f64(0.5),
            Err(_) => *k2c = (*k2c + hi) * R::from_f64(0.5),
        }
        tries += 1;
        if tries >= 4 {
            return Err(PathFitError::PastTip);
        }
    }
}

/// Levenberg–Marquardt on (k2c, R, T_f) (`p = [k2c, R]`), R clamped to [0, Rmax].
fn lm3<R: Real>(
    pm: &mut PathModel<R>,
    model: &Model<R>,
    w: &mut Work<R>,
    p: &mut [R; 2],
    rmax: R,
) -> Result<Eval<R>, PathFitError> {
    let l2 = pm.l2();
    let z = R::zero();
    let lo = l2 * R::from_f64(0.01);
    let mut best = match evaluate(pm, model, w, p[0], p[1]) {
        Ok(e) => e,
        Err(_) => {
            p[1] = z;
            evaluate_or_shrink(pm, model, w, &mut p[0], z, lo, l2)?
        }
    };
    let step_tol = R::from_f64(STEP_TOL);
    let mut mu = R::from_f64(1e-3);
    let mut iter = 0usize;
    while iter < 10 && w.evals < MAX_EVALS {
        iter += 1;
        let mut a = best.a;
        for (i, row) in a.iter_mut().enumerate() {
            if let Some(d) = row.get_mut(i) {
                *d = *d * (R::one() + mu);
            }
        }
        let Some(c) = invert3(&a) else { break };
        let g = best.g;
        let dk = -(c[0][0] * g[0] + c[0][1] * g[1] + c[0][2] * g[2]) * l2;
        let dr = -(c[1][0] * g[0] + c[1][1] * g[1] + c[1][2] * g[2]) * l2;
        if dk.abs() < step_tol * l2 && dr.abs() < step_tol * l2 {
            break;
        }
        let tk = (p[0] + dk).max(lo).min(l2);
        let tr = (p[1] + dr).max(z).min(rmax);
        match evaluate(pm, model, w, tk, tr) {
            Ok(e) if e.sse <= best.sse => {
                let moved = (tk - p[0]).abs() + (tr - p[1]).abs();
                p[0] = tk;
                p[1] = tr;
                best = e;
                mu = (mu * R::from_f64(0.3)).max(R::from_f64(1e-6));
                if moved < l2 * R::from_f64(1e-6) {
                    break;
                }
            }
            _ => {
                mu = mu * R::from_f64(10.0);
                if mu > R::from_f64(1e4) {
                    break;
                }
            }
        }
    }
    Ok(best)
}

/// Inverse of a symmetric positive 2×2 matrix, Jacobi-scaled (unit diagonal) first so that
/// fixed point neither overflows nor loses the determinant.
fn invert2<R: Real>(a: &[[R; 2]; 2]) -> Option<[[R; 2]; 2]> {
    if !(a[0][0] > R::zero() && a[1][1] > R::zero()) {
        return None;
    }
    let d = [R::one() / a[0][0].sqrt(), R::one() / a[1][1].sqrt()];
    let b01 = a[0][1] * d[0] * d[1];
    let det = R::one() - b01 * b01;
    if !(det > R::from_f64(1e-7)) || !det.is_finite() {
        return None;
    }
    let inv = R::one() / det;
    Some([
        [inv * d[0] * d[0], -b01 * inv * d[0] * d[1]],
        [-b01 * inv * d[0] * d[1], inv * d[1] * d[1]],
    ])
}

/// Inverse of a symmetric positive 3×3 matrix, Jacobi-scaled first (see [`invert2`]).
fn invert3<R: Real>(a: &[[R; 3]; 3]) -> Option<[[R; 3]; 3]> {
    if !(a[0][0] > R::zero() && a[1][1] > R::zero() && a[2][2] > R::zero()) {
        return None;
    }
    let d = [
        R::one() / a[0][0].sqrt(),
        R::one() / a[1][1].sqrt(),
        R::one() / a[2][2].sqrt(),
    ];
    let mut b = [[R::zero(); 3]; 3];
    for (i, row) in b.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = if i == j {
                R::one()
            } else {
                a[i][j] * d[i] * d[j]
            };
        }
    }
    let c00 = b[1][1] * b[2][2] - b[1][2] * b[2][1];
    let c01 = b[1][2] * b[2][0] - b[1][0] * b[2][2];
    let c02 = b[1][0] * b[2][1] - b[1][1] * b[2][0];
    let det = b[0][0] * c00 + b[0][1] * c01 + b[0][2] * c02;
    if !(det > R::from_f64(1e-7)) || !det.is_finite() {
        return None;
    }
    let inv = R::one() / det;
    let c10 = b[0][2] * b[2][1] - b[0][1] * b[2][2];
    let c11 = b[0][0] * b[2][2] - b[0][2] * b[2][0];
    let c12 = b[0][1] * b[2][0] - b[0][0] * b[2][1];
    let c20 = b[0][1] * b[1][2] - b[0][2] * b[1][1];
    let c21 = b[0][2] * b[1][0] - b[0][0] * b[1][2];
    let c22 = b[0][0] * b[1][1] - b[0][1] * b[1][0];
    let m = [[c00, c10, c20], [c01, c11, c21], [c02, c12, c22]];
    let mut out = [[R::zero(); 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = m[i][j] * inv * d[i] * d[j];
        }
    }
    Some(out)
}
