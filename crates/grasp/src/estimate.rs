//! The estimate: runs in a low-priority task, outside `tick()`.
//!
//! [`run_estimate`] takes the [`EstimateRequest`] handed out after the step settled,
//! back-dates the contact point, applies the paper's two-point method (Eq. 1: K̂c = ΔT_a/Δθa,
//! inverted at the contact configuration) or the whole-path fit, classifies the phalanx and
//! returns an integer [`EstimateResult`] for [`Controller::deliver`](crate::Controller::deliver).
//!
//! The firmware's entries, [`two_point_fw`] and [`path_fit_fw`], run in Q32.32 and integers
//! from request to result (tables built once at init), so host and target compute the same
//! bits; the generic [`two_point`] and [`path_fit`] on [`pts::Model`] with f64 glue are their
//! references.
//!
//! The request keeps the samples from contact to settle (bounded, [`PATH_CAPACITY`]) so
//! that a whole-path estimator can be selected later without touching the tick path.

// `!(x > y)` is the NaN guard: it is true for NaN, `x <= y` is not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use heapless::Vec;
use pathfit::q::{fit_path_q, PathTable, RawSample};
use pathfit::{fit_path, PathFit, PathFitError, PathSample};
use pts::fixed::Fx32;
use pts::table::{FreeTable, TableReal};
use pts::{Estimate, Finger, Model, Phalanx, PtsError, Real};

use crate::config::{DriveConfig, Estimator, HISTORY};

/// The numeric back end of the estimator on the target. One place to switch
/// (`pts::FirmwareReal`, I32F32 fixed point; f32 or f64 work too).
pub type EstReal = pts::FirmwareReal;

/// Capacity of the contact-to-settle path (samples; the stride doubles when it fills).
pub const PATH_CAPACITY: usize = 128;

/// Relative band above K_c,proximal in which a "distal" reading is reported as
/// [`Located::ProximalOrNearO2`]: a proximal contact measured with a finite ΔT_a reads
/// slightly above K_c,proximal (MODEL.md, traps).
pub const O2_AMBIGUITY_BAND: f64 = 0.15;

/// Δθa (rad) below which the estimate is flagged [`Quality::LowSignal`].
pub const MIN_GOOD_DTHETA_RAD: f64 = 2e-3;

/// σ(k2,c) above this fraction of l2 grades a path-fit answer [`Quality::LowSignal`].
pub const LOW_SIGNAL_SIGMA_FRAC_L2: f64 = 0.05;

/// The quality of a distal path-fit answer from its σ(k2,c) (m) on a distal phalanx of
/// length `l2_m` (m): [`Quality::LowSignal`] above [`LOW_SIGNAL_SIGMA_FRAC_L2`] of l2.
pub fn path_fit_quality<R: EstNum>(sigma_m: R, l2_m: R) -> Quality {
    if sigma_m > l2_m * R::from_f64(LOW_SIGNAL_SIGMA_FRAC_L2) {
        Quality::LowSignal
    } else {
        Quality::Good
    }
}

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
    /// The contact as the tick saw it: `tick` = end of the free-motion data (before the
    /// impact), θa at detection, T_a,c on the free-motion line there.
    pub contact: Sample,
    /// First static point after contact, pressed at T_a,c + δ_seat: means over the settle
    /// window (θa, T_a).
    pub seat: Sample,
    /// Second static point, at T_a,c + max(2δ_seat, ΔT_a/2).
    pub seat2: Sample,
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
    /// Which estimator to run.
    pub estimator: Estimator,
    /// Control period (ns): sample ticks → time.
    pub dt_ns: u32,
}

impl EstimateRequest {
    /// No samples, every field zero (all zero bits: a static slot of it lands in `.bss`):
    /// what [`Supervisor::take_request_into`](crate::Supervisor::take_request_into) fills.
    pub const EMPTY: EstimateRequest = EstimateRequest {
        contact: Sample::ZERO,
        seat: Sample::ZERO,
        seat2: Sample::ZERO,
        end: Sample::ZERO,
        pre: Vec::new(),
        path: Vec::new(),
        sample_ticks: 0,
        path_stride: 0,
        delta_ta_cmd_unm: 0,
        detect_k_unm_per_rad: 0,
        estimator: Estimator::TwoPoint,
        dt_ns: 0,
    };
}

/// Why the estimator refused the measurement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimateError {
    /// The two-point method (or the model under it) refused.
    Model(PtsError),
    /// The path fit refused.
    PathFit(PathFitError),
}

impl EstimateError {
    /// A stable snake_case name for logs.
    pub const fn kind(&self) -> &'static str {
        match self {
            EstimateError::Model(e) => e.kind(),
            EstimateError::PathFit(e) => e.kind(),
        }
    }
}

impl core::fmt::Display for EstimateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EstimateError::Model(e) => write!(f, "{e}"),
            EstimateError::PathFit(e) => write!(f, "{e}"),
        }
    }
}

impl From<PtsError> for EstimateError {
    fn from(e: PtsError) -> Self {
        EstimateError::Model(e)
    }
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
    /// Δθa spans enough encoder resolution and the inversion is well inside its range; a
    /// path fit's σ(k2,c) is at most [`LOW_SIGNAL_SIGMA_FRAC_L2`] of l2.
    Good,
    /// Δθa below [`MIN_GOOD_DTHETA_RAD`] (noise- and friction-dominated), or a path fit's
    /// σ(k2,c) above [`LOW_SIGNAL_SIGMA_FRAC_L2`] of l2.
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
    /// One standard deviation of `k2_um` (µm), when the estimator gives one (the path fit).
    pub k2_sigma_um: Option<i32>,
    /// Radius of the object at the contact (µm), when the path determines it (the path fit
    /// of a rolling contact).
    pub radius_um: Option<i32>,
    /// The paper's two-point k2 (µm) for reference, when the caller computed it beside another
    /// estimator (the estimators themselves leave it `None`).
    pub two_point_k2_um: Option<i32>,
    /// K̂c = ΔT_a/Δθa (µN·m/rad); 0 where the estimator fits none (the path fit's proximal
    /// answer).
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

/// A back end the estimate's glue runs on: the request's integer µ-units in and out, with
/// no floating point for the fixed-point type (the firmware's [`EstReal`]).
pub trait EstNum: Real {
    /// v·10⁻⁶: µrad → rad, µN·m → N·m.
    fn from_micro(v: i32) -> Self;
    /// A sample count n as a value.
    fn from_count(n: u32) -> Self;
    /// self/n for a sample count n ≥ 1 (a mean).
    fn per_count(self, n: u32) -> Self {
        self / Self::from_count(n)
    }
    /// round(self·10⁶) (rad → µrad, N·m → µN·m), saturated to the i32 range; 0 for a
    /// non-finite value.
    fn micro(self) -> i32;
}

impl EstNum for f64 {
    fn from_micro(v: i32) -> Self {
        f64::from(v) * 1e-6
    }
    fn from_count(n: u32) -> Self {
        f64::from(n)
    }
    fn micro(self) -> i32 {
        to_micro(self)
    }
}

impl EstNum for f32 {
    fn from_micro(v: i32) -> Self {
        (f64::from(v) * 1e-6) as f32
    }
    fn from_count(n: u32) -> Self {
        n as f32
    }
    fn micro(self) -> i32 {
        to_micro(f64::from(self))
    }
}

impl EstNum for Fx32 {
    #[inline]
    fn from_micro(v: i32) -> Self {
        // v·2^32/10^6 = v·4294 + v·0.967296…; the fraction as ⌊0.967296·2^32⌉, rounded:
        // within one unit of 2^-32 for every i32 (|v·4154504686| < 2^63).
        let v = i64::from(v);
        Fx32::from_bits(v * 4294 + ((v * 4_154_504_686 + (1 << 31)) >> 32))
    }
    #[inline]
    fn from_count(n: u32) -> Self {
        Fx32::from_bits(i64::from(n) << 32)
    }
    #[inline]
    fn per_count(self, n: u32) -> Self {
        // Up to FIT_SAMPLES: a product with ⌊2^32/n⌉ (relative error < 2^-31) instead of a
        // division.
        const RECIP: [i64; FIT_SAMPLES + 1] = {
            let mut r = [0i64; FIT_SAMPLES + 1];
            let mut n = 1;
            while n <= FIT_SAMPLES {
                r[n] = ((1i64 << 32) + n as i64 / 2) / n as i64;
                n += 1;
            }
            r
        };
        match RECIP.get(n as usize) {
            Some(&r) if r > 0 => self * Fx32::from_bits(r),
            _ => self / Self::from_count(n),
        }
    }
    #[inline]
    fn micro(self) -> i32 {
        // Integer word ×10^6 plus the fraction ×10^6 rounded (two 32×32 products), saturated.
        let b = self.to_bits();
        let frac = ((b & 0xFFFF_FFFF) * 1_000_000 + (1 << 31)) >> 32;
        ((b >> 32) * 1_000_000 + frac).clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
    }
}

/// Finite and not at a fixed-point limit.
fn usable<R: Real>(x: R) -> bool {
    x.is_finite() && !x.is_saturated()
}

/// Runs the estimator the request names for `finger` as the firmware does: the two-point
/// method on the free-motion table ([`two_point_fw`]), the path fit on the integer kernel
/// ([`path_fit_fw`]), both built here for `finger` (the path fit's with `drive`'s measurement
/// model) and the request's control period.
pub fn run_estimate(
    finger: &Finger,
    drive: &DriveConfig,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    match req.estimator {
        Estimator::TwoPoint => two_point_fw(&two_point_table(finger)?, req),
        Estimator::PathFit => path_fit_fw(&path_table(finger, drive, req.dt_ns)?, req),
    }
}

/// [`run_estimate`], and for a path-fit request the paper's two-point k2 beside the answer
/// ([`EstimateResult::two_point_k2_um`]) for reference: what the host tools report. A
/// two-point refusal leaves the reference empty; it never fails the fit's answer.
pub fn run_estimate_with_reference(
    finger: &Finger,
    drive: &DriveConfig,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    let mut r = run_estimate(finger, drive, req)?;
    if req.estimator == Estimator::PathFit {
        let two_point = EstimateRequest {
            estimator: Estimator::TwoPoint,
            ..req.clone()
        };
        r.two_point_k2_um = run_estimate(finger, drive, &two_point)
            .ok()
            .and_then(|t| t.k2_um);
    }
    Ok(r)
}

/// Runs the estimator the request names with a given model (any back end; the contact
/// point from the model's Newton solves in f64) and `drive`'s measurement model: the generic
/// reference of the firmware's estimate.
pub fn run_estimate_with<R: EstNum>(
    model: &Model<R>,
    drive: &DriveConfig,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    match req.estimator {
        Estimator::TwoPoint => two_point(model, req).map_err(EstimateError::Model),
        Estimator::PathFit => path_fit(model, drive, req).map_err(EstimateError::PathFit),
    }
}

/// The table the firmware's path fit runs on for a finger, its drive and the control period
/// (ns): the default path-fit configuration with the drive's measurement model
/// ([`DriveConfig::path_fit_config`]: its inertia and encoder lead; `drive.dt_s` is not read,
/// the period is `dt_ns`). Built once, at build time for the board, at init on the simulated
/// board (f64 arithmetic; see [`pathfit::q::PathTable`]).
/// Refused ([`PtsError::OutOfRange`]) for a negative or non-finite inertia or backlash, and
/// wherever [`PathTable::new`] refuses.
pub fn path_table(finger: &Finger, drive: &DriveConfig, dt_ns: u32) -> Result<PathTable, PtsError> {
    // `!(x >= 0)` is true for NaN too.
    if !(drive.backlash_rad >= 0.0 && drive.backlash_rad.is_finite()) {
        return Err(PtsError::OutOfRange);
    }
    PathTable::new(finger, &drive.path_fit_config(), f64::from(dt_ns) * 1e-9)
}

/// The free-motion table the firmware's two-point estimate runs on (Q32.32).
pub type TwoPointTable = FreeTable<EstReal>;

/// The firmware's two-point table for a finger: built once, at init on the board (f64
/// arithmetic, about 100 free-motion solves).
pub fn two_point_table(finger: &Finger) -> Result<TwoPointTable, PtsError> {
    FreeTable::new(finger)
}

/// The estimate the firmware computes for a request, for any finger (host tools): the same
/// as [`run_estimate`]. `_model` is not used (the firmware's estimate needs only the
/// finger's tables).
pub fn run_estimate_fw(
    finger: &Finger,
    drive: &DriveConfig,
    _model: &Model<EstReal>,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    run_estimate(finger, drive, req)
}

/// The firmware's two-point estimate: the estimate task's whole work in a two-point build,
/// request → result, in Q32.32 (no floating point on the target). The contact point from
/// the table's free-motion torque ([`contact_point_with`], falling back to
/// [`contact_point`]), then the paper's two-point method with the contact configuration
/// from the table. Out of line: `cargo xtask bench` counts this very function.
#[inline(never)]
pub fn two_point_fw(
    table: &TwoPointTable,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    two_point_table_est(table, req).map_err(EstimateError::Model)
}

/// [`two_point_fw`] on any back end the table supports. Inside the table only (its torque
/// range, [`pts::table::TABLE_TA_MIN_NM`] to [`pts::table::TABLE_TA_MAX_NM`]): a contact
/// outside it is refused with [`PtsError::OutOfRange`].
pub fn two_point_table_est<R: EstNum + TableReal>(
    table: &FreeTable<R>,
    req: &EstimateRequest,
) -> Result<EstimateResult, PtsError> {
    let (theta_c, ta_c) = contact_point_with(req, |th: R| table.free_torque_in_table(th).ok())
        .unwrap_or_else(|| contact_point(req));
    let th2 = R::from_micro(req.end.theta_a_urad);
    let t2 = R::from_micro(req.end.torque_unm);
    let est = table.estimate_two_point_in_table(theta_c, ta_c, th2, t2)?;
    two_point_result(&est, theta_c, ta_c)
}

/// The firmware's path fit: the estimate task's whole work in a path-fit build, request →
/// result, integer and Q32.32 only. `table` must be built for the request's control period
/// ([`path_table`]). Out of line: `cargo xtask bench` counts this very function.
#[inline(never)]
pub fn path_fit_fw(
    table: &PathTable,
    req: &EstimateRequest,
) -> Result<EstimateResult, EstimateError> {
    path_fit_q(table, req).map_err(EstimateError::PathFit)
}

/// The samples of a request that the path fit takes: from the detection to the settle.
fn path_samples(req: &EstimateRequest) -> impl DoubleEndedIterator<Item = &Sample> + Clone {
    let kt = req.contact.tick;
    req.pre
        .iter()
        .filter(move |s| s.tick > kt)
        .chain(req.path.iter())
}

/// The whole-path estimate (`pathfit`, generic back end) from the samples after the
/// detection.
pub fn path_fit<R: EstNum>(
    model: &Model<R>,
    drive: &DriveConfig,
    req: &EstimateRequest,
) -> Result<EstimateResult, PathFitError> {
    let (theta_c, ta_c) = contact_point_model(model, req).unwrap_or_else(|| contact_point(req));
    let conv = |v: f64| R::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
    let dt_s = f64::from(req.dt_ns) * 1e-9;
    let samples = path_samples(req).map(move |s| PathSample {
        time_s: R::from_f64(f64::from(s.tick) * dt_s),
        theta_a_rad: R::from_f64(f64::from(s.theta_a_urad) * 1e-6),
        torque_nm: R::from_f64(f64::from(s.torque_unm) * 1e-6),
    });
    let (theta_c, ta_c) = (conv(theta_c)?, conv(ta_c)?);
    let fit = fit_path(
        model,
        &drive.path_fit_config(),
        theta_c,
        Some(ta_c),
        samples,
    );
    path_fit_result(model.l2(), req, theta_c, ta_c, fit).map(|(r, _)| r)
}

/// The whole-path estimate on the firmware's integer kernel (`pathfit::q`): the
/// controller's samples as they are (ticks, µrad, µN·m), the contact point from the table's
/// free-motion torque. `table` must be built for the request's control period
/// ([`path_table`]).
pub fn path_fit_q(
    table: &PathTable,
    req: &EstimateRequest,
) -> Result<EstimateResult, PathFitError> {
    if table.tick_ns() != req.dt_ns {
        return Err(PathFitError::Model(PtsError::OutOfRange));
    }
    let (theta_c, ta_c) = contact_point_q(table, req);
    path_fit_q_fx(table, req, theta_c, ta_c).map(|(r, _)| r)
}

/// The contact point (θa,c rad, T_a,c N·m) on the path fit's table: its free-motion torque
/// ([`contact_point_with`]), else the static points ([`contact_point`]). One copy for the
/// fit and the two-point method beside it.
#[inline(never)]
fn contact_point_q(table: &PathTable, req: &EstimateRequest) -> (Fx32, Fx32) {
    contact_point_with(req, |th: Fx32| table.free_torque(th).ok())
        .unwrap_or_else(|| contact_point(req))
}

/// The firmware's integer path fit with the contact point given (θa,c in rad, T_a,c in N·m),
/// e.g. by a recording's own contact detection: the result, and σ(k2,c) in m when the answer is
/// distal.
pub fn path_fit_q_at(
    table: &PathTable,
    req: &EstimateRequest,
    theta_c: f64,
    ta_c: f64,
) -> Result<(EstimateResult, Option<f64>), PathFitError> {
    let conv = |v: f64| EstReal::try_from_f64(v).ok_or(PathFitError::Model(PtsError::OutOfRange));
    path_fit_q_fx(table, req, conv(theta_c)?, conv(ta_c)?)
        .map(|(r, sigma)| (r, sigma.map(|s| s.to_f64())))
}

/// [`path_fit_q_at`] in Q32.32: σ(k2,c) (m) of a distal answer.
fn path_fit_q_fx(
    table: &PathTable,
    req: &EstimateRequest,
    theta_c: Fx32,
    ta_c: Fx32,
) -> Result<(EstimateResult, Option<Fx32>), PathFitError> {
    let samples = path_samples(req).map(|s| RawSample {
        tick: s.tick,
        theta_a_urad: s.theta_a_urad,
        torque_unm: s.torque_unm,
    });
    let fit = fit_path_q(table, theta_c, Some(ta_c), samples);
    path_fit_result(table.model().l2(), req, theta_c, ta_c, fit)
}

/// The request's result from a path fit (either back end), with σ(k2,c) (m) of a distal answer;
/// `l2_m` grades σ (m).
fn path_fit_result<R: EstNum>(
    l2_m: R,
    req: &EstimateRequest,
    theta_c: R,
    ta_c: R,
    fit: Result<PathFit<R>, PathFitError>,
) -> Result<(EstimateResult, Option<R>), PathFitError> {
    let dta = R::from_micro(req.end.torque_unm) - ta_c;
    let dth = R::from_micro(req.end.theta_a_urad) - theta_c;
    let base = EstimateResult {
        located: Located::Proximal,
        k2_um: None,
        k2_sigma_um: None,
        radius_um: None,
        two_point_k2_um: None,
        kc_hat_unm_per_rad: 0,
        kc_proximal_unm_per_rad: 0,
        kc_tip_unm_per_rad: 0,
        delta_ta_unm: dta.micro(),
        delta_theta_a_urad: dth.micro(),
        theta_a_c_urad: theta_c.micro(),
        ta_c_unm: ta_c.micro(),
        quality: Quality::Good,
    };
    let fit = match fit {
        Ok(f) => f,
        Err(PathFitError::ProximalContact) => {
            return Ok((
                EstimateResult {
                    quality: Quality::Ambiguous,
                    ..base
                },
                None,
            ))
        }
        Err(e) => return Err(e),
    };
    let sigma = fit.sigma_k2_m;
    let r = EstimateResult {
        located: Located::Distal,
        k2_um: Some(fit.k2_contact_m.micro()),
        k2_sigma_um: Some(sigma.micro()),
        radius_um: if fit.radius_observable {
            Some(fit.radius_m.micro())
        } else {
            None
        },
        kc_hat_unm_per_rad: fit.kc_contact.micro(),
        theta_a_c_urad: fit.theta_a_c_rad.micro(),
        quality: path_fit_quality(sigma, l2_m),
        ..base
    };
    Ok((r, Some(sigma)))
}

/// The paper's two-point estimate from the request on the model's Newton solves (the
/// contact point from them in f64): the reference the firmware's [`two_point_fw`] is
/// tested against.
pub fn two_point<R: EstNum>(
    model: &Model<R>,
    req: &EstimateRequest,
) -> Result<EstimateResult, PtsError> {
    let conv = |v: f64| R::try_from_f64(v).ok_or(PtsError::OutOfRange);
    let th2 = R::from_micro(req.end.theta_a_urad);
    let t2 = R::from_micro(req.end.torque_unm);
    let (theta_c, ta_c) = contact_point_model(model, req).unwrap_or_else(|| contact_point(req));
    let (theta_c, ta_c) = (conv(theta_c)?, conv(ta_c)?);
    let est = model.estimate_two_point(theta_c, ta_c, th2, t2)?;
    two_point_result(&est, theta_c, ta_c)
}

/// The paper's two-point estimate on the path fit's table (`pathfit::q`): the contact point
/// as the path fit finds it (the table's free-motion torque), the contact configuration from
/// the table, the inversion on the table's model. What a path-fit firmware reports beside the
/// fit, without a model solve (or its trigonometry) of its own.
pub fn two_point_q(table: &PathTable, req: &EstimateRequest) -> Result<EstimateResult, PtsError> {
    let (theta_c, ta_c) = contact_point_q(table, req);
    let th2 = Fx32::from_micro(req.end.theta_a_urad);
    let t2 = Fx32::from_micro(req.end.torque_unm);
    let est = table
        .model()
        .estimate_two_point_shared(theta_c, ta_c, th2, t2, |t| table.free_config(t))?;
    two_point_result(&est, theta_c, ta_c)
}

/// The request's result from a two-point estimate at the contact point (θa,c rad, T_a,c N·m):
/// the phalanx, the ambiguity near O2 and the quality, in µ-units.
fn two_point_result<R: EstNum>(
    est: &Estimate<R>,
    theta_c: R,
    ta_c: R,
) -> Result<EstimateResult, PtsError> {
    let c = est.contact;
    let kc = est.kc_hat;
    let (located, k2) = match c.phalanx {
        Phalanx::None => return Err(PtsError::StiffnessBelowFree),
        Phalanx::Proximal => (Located::Proximal, None),
        Phalanx::Distal if kc <= c.kc_proximal * R::from_f64(1.0 + O2_AMBIGUITY_BAND) => {
            (Located::ProximalOrNearO2, c.k2.map(R::micro))
        }
        Phalanx::Distal => (Located::Distal, c.k2.map(R::micro)),
    };
    let quality = if located == Located::ProximalOrNearO2 {
        Quality::Ambiguous
    } else if est.dtheta_a < R::from_f64(MIN_GOOD_DTHETA_RAD) {
        Quality::LowSignal
    } else {
        Quality::Good
    };
    Ok(EstimateResult {
        located,
        k2_um: k2,
        k2_sigma_um: None,
        radius_um: None,
        two_point_k2_um: None,
        kc_hat_unm_per_rad: kc.micro(),
        kc_proximal_unm_per_rad: c.kc_proximal.micro(),
        kc_tip_unm_per_rad: c.kc_tip.micro(),
        delta_ta_unm: est.dta.micro(),
        delta_theta_a_urad: est.dtheta_a.micro(),
        theta_a_c_urad: theta_c.micro(),
        ta_c_unm: ta_c.micro(),
        quality,
    })
}

/// Static points closer than this in torque (N·m) give no slope for the back-dating.
pub const MIN_STATIC_GAP_NM: f64 = 1e-4;
/// A back-dated contact may lie at most this far above the seated torque (N·m) and
/// [`PAST_SEAT_RAD`] past the seated angle: rounding, not a contact after the seated point.
pub const PAST_SEAT_NM: f64 = 1e-3;
/// See [`PAST_SEAT_NM`] (rad).
pub const PAST_SEAT_RAD: f64 = 1e-4;
/// A back-dated contact lies at most this far below the seated torque (N·m): the seated
/// point is T_a,c + δ_seat, reached from the contact by a small ramp.
pub const MAX_BELOW_SEAT_NM: f64 = 0.2;
/// The straight-line back-dating's contact lies at most this far before the seated angle (rad).
pub const MAX_BEFORE_SEAT_RAD: f64 = 0.05;
/// The secant onto the free-motion curve stops once |h| is below this (N·m) and accepts its
/// point only below [`SECANT_ACCEPT_NM`].
pub const SECANT_STOP_NM: f64 = 1e-7;
/// See [`SECANT_STOP_NM`] (N·m).
pub const SECANT_ACCEPT_NM: f64 = 1e-5;

/// The last [`FIT_SAMPLES`] samples of the approach, up to the contact detection (half a
/// sample period of guard): the free motion before the impact. `pre` is in tick order, so
/// they are the slice before the last sample within the guard.
fn approach_samples(req: &EstimateRequest) -> impl Iterator<Item = &Sample> + Clone {
    let guard = u64::from(req.sample_ticks.max(1));
    let limit = u64::from(req.contact.tick) + guard / 2;
    let end = req
        .pre
        .iter()
        .rposition(|s| u64::from(s.tick) <= limit)
        .map_or(0, |i| i + 1);
    let start = end.saturating_sub(FIT_SAMPLES);
    req.pre.get(start..end).unwrap_or(&[]).iter()
}

/// Free-motion samples used before the impact (samples).
pub const FIT_SAMPLES: usize = 12;

/// The free-motion line θa = a + b·T_a (rad, N·m) before the impact: the last
/// [`FIT_SAMPLES`] samples up to `contact.tick` (the approach runs at a limited, constant
/// speed there, so the measured torque is the static one).
pub fn free_line<R: EstNum>(req: &EstimateRequest) -> Option<(R, R)> {
    fit(approach_samples(req))
}

/// Where the line through the seated point with slope dθa/dT_a = `b` (rad/(N·m)) meets the
/// free-motion line: (θa,c rad, T_a,c N·m). `None` when implausible (parallel, or not
/// just before the seated point).
pub fn back_date<R: EstNum>(req: &EstimateRequest, free: (R, R), b: R) -> Option<(R, R)> {
    let (af, bf) = free;
    let t1 = R::from_micro(req.seat.torque_unm);
    let th1 = R::from_micro(req.seat.theta_a_urad);
    let ac = th1 - b * t1;
    let db = b - bf;
    if !(db.abs() > R::from_f64(1e-12)) {
        return None;
    }
    let t = (af - ac) / db;
    let th = af + bf * t;
    if !(usable(th) && usable(t))
        || th > th1 + R::from_f64(PAST_SEAT_RAD)
        || th < th1 - R::from_f64(MAX_BEFORE_SEAT_RAD)
        || t > t1 + R::from_f64(PAST_SEAT_NM)
    {
        return None;
    }
    Some((th, t))
}

/// A static point of the request as (T_a N·m, θa rad).
fn static_point<R: EstNum>(s: &Sample) -> (R, R) {
    (R::from_micro(s.torque_unm), R::from_micro(s.theta_a_urad))
}

/// The parabola θa(T_a) (rad, N·m) through the three static points after contact
/// (seated, seated again, settled), as a closure; `None` when they are not ordered in T_a.
fn path_parabola<R: EstNum>(req: &EstimateRequest) -> Option<impl Fn(R) -> R> {
    let (t1, th1) = static_point::<R>(&req.seat);
    let (tb, thb) = static_point::<R>(&req.seat2);
    let (t2, th2) = static_point::<R>(&req.end);
    let gap = R::from_f64(MIN_STATIC_GAP_NM);
    if !(tb - t1 > gap && t2 - tb > gap) {
        return None;
    }
    let s1b = (thb - th1) / (tb - t1);
    let sb2 = (th2 - thb) / (t2 - tb);
    let c2 = (sb2 - s1b) / (t2 - t1);
    Some(move |t: R| th1 + (t - t1) * (s1b + c2 * (t - tb)))
}

/// The contact point (θa,c rad, T_a,c N·m) from the model's free-motion curve, in f64 (the
/// reference of the firmware's table-based [`contact_point_with`]).
///
/// The measured free motion before the impact gives the offset between the measured torque
/// and the model's free-motion torque at the same θa (transmission friction while moving,
/// current-gain error); the contact is where the path after contact, extrapolated back by
/// the parabola through the three static points, meets that shifted free-motion curve.
/// `None` when a solve fails (the caller falls back to [`contact_point`]).
///
/// Every query lies near the contact: the approach's last samples and the secant's iterates
/// below the seated angle, a few mrad apart, where T_free(θa) is smooth. A quadratic through
/// three of the model's Newton solves spanning the samples and the seated angle answers the
/// queries inside that span; a query outside it takes its own solve.
pub fn contact_point_model<R: Real>(model: &Model<R>, req: &EstimateRequest) -> Option<(f64, f64)> {
    let exact = |th: f64| -> Option<f64> {
        let c = model.free_from_theta_a(R::try_from_f64(th)?).ok()?;
        Some(c.ta.to_f64())
    };
    let span = query_span(req);
    let quad = span.and_then(|(lo, hi)| FreeQuadratic::through(&exact, lo, hi));
    contact_point_with(req, |th: f64| match &quad {
        Some(q) if th >= q.lo && th <= q.hi => Some(q.at(th)),
        _ => exact(th),
    })
}

/// The θa span (rad) [`contact_point_with`] queries T_free on for `req`, with a margin: from
/// the earliest approach sample it averages to the seated angle. `None` when the span is
/// empty or not finite.
fn query_span(req: &EstimateRequest) -> Option<(f64, f64)> {
    const MARGIN_RAD: f64 = 1e-3;
    let (lo, hi) = approach_samples(req).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
        let th = f64::from(s.theta_a_urad) * 1e-6;
        (lo.min(th), hi.max(th))
    });
    let hi = hi.max(f64::from(req.seat.theta_a_urad) * 1e-6);
    (lo.is_finite() && hi.is_finite() && hi - lo < 0.1)
        .then_some((lo - MARGIN_RAD, hi + MARGIN_RAD))
}

/// T_free(θa) on [lo, hi] as the quadratic through its values at both ends and the middle.
struct FreeQuadratic {
    lo: f64,
    hi: f64,
    /// Values at lo, the middle and hi (N·m).
    f: [f64; 3],
}

impl FreeQuadratic {
    fn through(exact: &dyn Fn(f64) -> Option<f64>, lo: f64, hi: f64) -> Option<Self> {
        let f = [exact(lo)?, exact(0.5 * (lo + hi))?, exact(hi)?];
        Some(FreeQuadratic { lo, hi, f })
    }

    /// Lagrange form in u = (θ − lo)/(hi − lo) ∈ [0, 1], nodes 0, ½, 1.
    fn at(&self, th: f64) -> f64 {
        let u = (th - self.lo) / (self.hi - self.lo);
        let [f0, fm, f1] = self.f;
        f0 * (2.0 * u - 1.0) * (u - 1.0) + fm * 4.0 * u * (1.0 - u) + f1 * u * (2.0 * u - 1.0)
    }
}

/// The contact point (θa,c rad, T_a,c N·m) from the free-motion torque T_free(θa) (θa rad →
/// N·m): the model's Newton solve ([`contact_point_model`]), or a table's lookup (the
/// firmware: [`FreeTable::free_torque`], `PathTable::free_torque`; no trigonometry).
/// See [`contact_point_model`] for the method; `None` when a query fails.
pub fn contact_point_with<R: EstNum>(
    req: &EstimateRequest,
    t_free: impl Fn(R) -> Option<R>,
) -> Option<(R, R)> {
    let offset = friction_offset(req, &t_free)?;
    let q = path_parabola::<R>(req)?;
    let (t1, th1) = static_point::<R>(&req.seat);
    meet_free_curve(&q, &t_free, offset, (t1, th1), 12)
}

/// The mean of measured minus free-motion torque (N·m) over the approach's last samples:
/// the transmission friction while moving and the current-gain error. T_free is taken at the
/// samples' mean angle: over the approach's few mrad it is linear to within ½·T_free″·var(θa),
/// far below a µN·m. `None` with fewer than three samples or a failed query.
fn friction_offset<R: EstNum>(
    req: &EstimateRequest,
    t_free: &impl Fn(R) -> Option<R>,
) -> Option<R> {
    let (mut sum_t, mut sum_th) = (R::zero(), R::zero());
    let mut n = 0u32;
    for s in approach_samples(req) {
        sum_t = sum_t + R::from_micro(s.torque_unm);
        sum_th = sum_th + R::from_micro(s.theta_a_urad);
        n += 1;
    }
    if n < 3 {
        return None;
    }
    Some(sum_t.per_count(n) - t_free(sum_th.per_count(n))?)
}

/// Where the path θa = q(T) meets the free-motion curve shifted by the friction `offset`:
/// solves h(T) = T − offset − T_free(q(T)) = 0 by secant from the seated point `(t1, θ1)`
/// downwards, at most `iters` steps. `Some((θa,c rad, T_a,c N·m))` only when it converged to
/// a plausible point: within 0.2 N·m below the seated torque and not past the seated angle.
pub fn meet_free_curve<R: EstNum>(
    q: &dyn Fn(R) -> R,
    t_free: &dyn Fn(R) -> Option<R>,
    offset: R,
    (t1, th1): (R, R),
    iters: usize,
) -> Option<(R, R)> {
    let h = |t: R| -> Option<R> { Some(t - offset - t_free(q(t))?) };
    // The second point one unit-slope step below the seated point: h′ = 1 − T_free′·q′ is
    // near 1 where the contact is much stiffer than free motion (a fixed 0.01 N·m when h(t1)
    // is not a plausible step).
    let a = t1;
    let ha = h(a)?;
    let first = if ha > R::zero() && ha < R::from_f64(MAX_BELOW_SEAT_NM) {
        ha
    } else {
        R::from_f64(0.01)
    };
    let b = t1 - first;
    let hb = h(b)?;
    let (mut a, mut b, mut ha, mut hb) = (a, b, ha, hb);
    for _ in 0..iters {
        let d = hb - ha;
        if !(d.abs() > R::from_f64(1e-15)) {
            break;
        }
        // (b − a)/d first: the inverse slope is O(1), the product with h(b) keeps its digits
        // in fixed point.
        let c = b - hb * ((b - a) / d);
        a = b;
        ha = hb;
        b = c;
        hb = h(b)?;
        if hb.abs() < R::from_f64(SECANT_STOP_NM) {
            break;
        }
    }
    let th = q(b);
    (usable(b)
        && usable(th)
        && hb.abs() < R::from_f64(SECANT_ACCEPT_NM)
        && b <= t1 + R::from_f64(PAST_SEAT_NM)
        && b > t1 - R::from_f64(MAX_BELOW_SEAT_NM)
        && th <= th1 + R::from_f64(PAST_SEAT_RAD))
    .then_some((th, b))
}

/// The contact point (θa,c rad, T_a,c N·m) without the model: the fallback of
/// [`contact_point_with`].
///
/// The impact at contact (the drive's reflected inertia, J·N² ≈ 0.066 kg·m²) makes the
/// samples right after it useless, so the contact is rebuilt from quasi-static data only:
/// the free-motion line before the impact meets the path after contact, extrapolated back
/// from the three static points (seated at T_a,c + δ, at T_a,c + max(2δ, ΔT_a/2), settled after
/// ΔT_a) by the parabola θa(T_a) through them. Falls back to the straight line through the
/// two seated points, then to the chord seated → end, then to the seated point.
pub fn contact_point<R: EstNum>(req: &EstimateRequest) -> (R, R) {
    let (t1, th1) = static_point::<R>(&req.seat);
    let (tb, thb) = static_point::<R>(&req.seat2);
    let (t2, th2) = static_point::<R>(&req.end);
    let fallback = (th1, t1);
    let Some(free) = free_line::<R>(req) else {
        return fallback;
    };
    let slope = |ta: R, tha: R, tb: R, thb: R| {
        if tb - ta > R::from_f64(MIN_STATIC_GAP_NM) {
            Some((thb - tha) / (tb - ta))
        } else {
            None
        }
    };
    if let (Some(s1b), Some(sb2)) = (slope(t1, th1, tb, thb), slope(tb, thb, t2, th2)) {
        if let Some(p) = parabola_meets_line(free, (t1, th1), tb, s1b, (sb2 - s1b) / (t2 - t1)) {
            return p;
        }
    }
    if let Some(p) = slope(t1, th1, tb, thb).and_then(|b| back_date(req, free, b)) {
        return p;
    }
    slope(t1, th1, t2, th2)
        .and_then(|b| back_date(req, free, b))
        .unwrap_or(fallback)
}

/// Where the parabola θ(T) = θ1 + s1b (T − t1) + c2 (T − t1)(T − tb) (Newton form, through the
/// seated point `(t1, θ1)`) meets the free-motion line θ = af + bf T: eight Newton steps from
/// t1; `None` when the point is implausible (as in [`meet_free_curve`]).
fn parabola_meets_line<R: EstNum>(
    (af, bf): (R, R),
    (t1, th1): (R, R),
    tb: R,
    s1b: R,
    c2: R,
) -> Option<(R, R)> {
    let two = R::from_f64(2.0);
    let mut t = t1;
    for _ in 0..8 {
        let g = th1 + s1b * (t - t1) + c2 * (t - t1) * (t - tb) - (af + bf * t);
        let dg = s1b + c2 * (two * t - t1 - tb) - bf;
        if !(dg.abs() > R::from_f64(1e-12)) {
            break;
        }
        t = t - g / dg;
    }
    let th = af + bf * t;
    (usable(t)
        && usable(th)
        && t <= t1 + R::from_f64(PAST_SEAT_NM)
        && t > t1 - R::from_f64(MAX_BELOW_SEAT_NM)
        && th <= th1 + R::from_f64(PAST_SEAT_RAD))
    .then_some((th, t))
}

/// Least-squares line θ = a + b·T (rad, N·m) through the samples; `None` with fewer
/// than three samples or no torque spread.
fn fit<'a, R: EstNum>(samples: impl Iterator<Item = &'a Sample> + Clone) -> Option<(R, R)> {
    let n = samples.clone().count();
    if n < 3 {
        return None;
    }
    let nf = R::from_count(n as u32);
    let (st, sth) = samples.clone().fold((R::zero(), R::zero()), |(a, b), s| {
        (
            a + R::from_micro(s.torque_unm),
            b + R::from_micro(s.theta_a_urad),
        )
    });
    let (mt, mth) = (st / nf, sth / nf);
    let (stt, stth) = samples.fold((R::zero(), R::zero()), |(a, b), s| {
        let dt = R::from_micro(s.torque_unm) - mt;
        let dth = R::from_micro(s.theta_a_urad) - mth;
        (a + dt * dt, b + dt * dth)
    });
    if !(stt > R::from_f64(1e-12) * nf) {
        return None;
    }
    let b = stth / stt;
    Some((mth - b * mt, b))
}

/// A value in SI units as the request's integer micro-units (rounded half away from zero;
/// 0 for a non-finite value).
pub fn to_micro(v: f64) -> i32 {
    let x = v * 1e6;
    if !x.is_finite() {
        return 0;
    }
    let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    r as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An estimator's refusal reads as its model's or its fit's words, not a Debug form.
    #[test]
    fn refusals_display_in_words() {
        use core::fmt::Write as _;
        let mut text: heapless::String<128> = heapless::String::new();
        for (e, words) in [
            (
                EstimateError::PathFit(PathFitError::NotDetermined),
                "k2 is not determined by this path",
            ),
            (
                EstimateError::Model(PtsError::BeyondTip),
                "stiffness above that of a contact at the distal tip",
            ),
        ] {
            text.clear();
            write!(text, "{e}").unwrap();
            assert_eq!(text.as_str(), words, "{e:?}");
        }
    }

    /// The Q32.32 conversions against f64 over the request's ranges (µrad, µN·m, counts).
    #[test]
    fn fixed_point_micro_conversions_match_f64() {
        let ulp = 1.0 / 4294967296.0;
        let mut v: i64 = -2_147_483_648;
        while v <= 2_147_483_647 {
            let m = v as i32;
            let x = Fx32::from_micro(m).to_f64();
            let want = f64::from(m) * 1e-6;
            assert!((x - want).abs() <= 1.5 * ulp, "{m}: {x} vs {want}");
            assert!(
                (Fx32::from_micro(m).micro() - m).abs() <= 1,
                "{m} round trip"
            );
            v += 9_973_421;
        }
        for x in [
            0.0,
            1e-7,
            0.4999e-6,
            -0.5001e-6,
            0.425_269,
            -1.234_567_8,
            1e4,
            -2e3,
        ] {
            assert_eq!(Fx32::from_f64(x).micro(), to_micro(x), "{x}");
        }
        // Beyond the i32 range: saturated, never wrapped.
        assert_eq!(Fx32::from_f64(5e3).micro(), i32::MAX);
        assert_eq!(Fx32::from_f64(-5e3).micro(), i32::MIN);
        for n in 1..=20u32 {
            let s = Fx32::from_f64(3.217_5);
            let got = s.per_count(n).to_f64();
            assert!(
                (got - 3.217_5 / f64::from(n)).abs() < 4.0 * ulp,
                "mean of {n}"
            );
        }
    }

    /// The secant on a known curve: the path θ = q(T) = 0.1·T and the free-motion torque
    /// T_free(θ) = 2·θ² + 0.3 (offset 0) meet where T = 0.02·T² + 0.3, T* = (1 − √(1 − 0.024))/0.04.
    #[test]
    fn meet_free_curve_finds_the_crossing_in_both_back_ends() {
        let exact = (1.0 - (1.0f64 - 0.024).sqrt()) / 0.04;
        let (th, t) = meet_free_curve(
            &|t: f64| 0.1 * t,
            &|th: f64| Some(2.0 * th * th + 0.3),
            0.0,
            (0.35, 0.035),
            12,
        )
        .unwrap();
        assert!(
            (th - 0.1 * exact).abs() < 1e-9 && (t - exact).abs() < 1e-9,
            "{t} {th}"
        );
        let c = |v: f64| Fx32::from_f64(v);
        let (th, t) = meet_free_curve(
            &|t: Fx32| t * c(0.1),
            &|th: Fx32| Some(c(2.0) * th * th + c(0.3)),
            Fx32::zero(),
            (c(0.35), c(0.035)),
            12,
        )
        .unwrap();
        assert!((th.to_f64() - 0.1 * exact).abs() < 1e-7 && (t.to_f64() - exact).abs() < 1e-7);
        // A crossing above the seated torque is not a contact before the seat: refused.
        assert!(meet_free_curve(
            &|t: f64| 0.1 * t,
            &|th: f64| Some(2.0 * th * th + 0.3),
            0.0,
            (0.2, 0.02),
            12
        )
        .is_none());
    }
}
