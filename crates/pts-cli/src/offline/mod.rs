//! Offline segmentation of a recorded grasp: finds each contact in a time series
//! (t, θa, T_a) that our controller did not produce, and builds the same
//! [`EstimateRequest`] the controller builds, so that [`grasp::run_estimate`]
//! (two-point or path fit) runs on it unchanged.
//!
//! A recorded grasp is free motion under a slowly rising torque, a first contact, a torque
//! step or ramp of ΔT_a and a hold (maybe an unload and more contacts after it), with Coulomb
//! friction and stiction, encoder quantization and current noise, at any sample rate.
//!
//! How a contact is found, all on block means (the trace is averaged into blocks of
//! [`OfflineConfig::block_s`], like the controller's samples), with windows and medians, never
//! a single sample:
//!
//! 1. **Free motion** (arming): a window of [`OfflineConfig::free_window`] blocks in which θa
//!    advanced by at least [`OfflineConfig::arm_rad`] while the *free-motion residual*
//!    r = T_a − T_free(θa) (T_free: the model's free-motion torque, `pts::Model::free_from_theta_a`)
//!    stayed flat. Its median is the friction/gain offset of the approach (Coulomb friction
//!    while closing, current-gain error), its MAD the noise. A stiction break-away at the start
//!    (torque rising, θa still) does not arm.
//! 2. **Contact**: r rises above the offset by more than the threshold for
//!    [`OfflineConfig::confirm`] blocks in a row (the stiffness seen at the actuator jumped from
//!    free motion, 0.55‥0.9 N·m/rad, to a contact's, ≥ 2.6). The **knee** is the last block
//!    where the residual's rise against θa, extrapolated back, meets the shifted free-motion
//!    curve (a threshold crossing would be late by the smooth start of the rise). A rise at
//!    constant θa that goes back onto the free-motion curve once the finger moves again is a
//!    stiction stall, not a contact.
//! 3. **Segment end**: the torque (median-filtered) falls well below its running maximum
//!    (unloading), or the trace ends.
//! 4. **End point**: the last window before the segment end where θa and T_a are both static
//!    (the settled hold after the step); with an undamped oscillation that never settles, the
//!    mean over the late half of the constant-torque hold.
//! 5. **Static points on the path** (the controller's `seat`/`seat2`): `seat` is the knee on
//!    the shifted free-motion curve (δ_seat = 0, so the estimator's back-dating returns it);
//!    `seat2` the quasi-static window nearest mid-step (θa linear in time within a band, and
//!    not a stiction plateau where T_a rises at constant θa), or without one (a step right
//!    at contact) the midpoint of the chord to the end point.
//!
//! The request then carries the free-motion history before the detection (`pre`), the blocks
//! from the detection to the end decimated into [`PATH_CAPACITY`] (`path`: each the mean over
//! the rows in which θa moved, by half an encoder count or faster than a settled crank, since
//! while the crank stands still the transmission's friction is anywhere in its stiction band
//! and a stuck contact's anywhere in its friction cone; blocks in which it never moved are left
//! out), the knee
//! (`contact`), the static points and the measured ΔT_a; block ticks are block indices + 1
//! and `dt_ns` the block length.
//!
//! The phases live in their own modules: [`blocks`] (averaging the trace), [`drive`] (the
//! drive's nuisance parameters on the approach), [`contact`] (arming, detection, the knee and
//! its back-dating), [`segment`] (segment end, end point, static points, the request) and
//! [`estimate`] (the firmware's path fit on a segmented request). Host only (f64); the
//! blocks live in the caller's scratch; no panics, typed [`OfflineError`]s.
//!
//! [`PATH_CAPACITY`]: grasp::estimate::PATH_CAPACITY

// `!(x > y)` is the NaN guard: it is true for NaN, `x <= y` is not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod blocks;
pub mod contact;
pub mod drive;
pub mod estimate;
pub mod segment;

pub use blocks::{block_length, make_blocks, median_spacing, BOUNDARY_TOL};
pub use contact::refine_contact;
pub use drive::{identify_drive, identify_drive_dynamics, DriveId, DrivePrior};
pub use estimate::path_fit_with;
pub use segment::{
    contact_inertia, find_contact, for_each_contact, loading_path, path_hysteresis,
    ContactDynamics, CONTACT_INERTIA_MIN_BLOCKS,
};

use grasp::estimate::EstimateRequest;
use grasp::Estimator;
use pts::PtsError;

/// One row of a recorded trace.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct TraceSample {
    /// Time (s), non-decreasing.
    pub t_s: f64,
    /// θa, absolute model angle (rad; −0.8503608 at rest).
    pub theta_a_rad: f64,
    /// T_a at the actuator (N·m).
    pub torque_nm: f64,
}

/// One block of the trace: means over [`OfflineConfig::block_s`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Block {
    /// Index of the block from the trace start (tick = index + 1).
    pub index: u32,
    /// Mean time (s).
    pub t_s: f64,
    /// Mean θa (rad).
    pub theta_a_rad: f64,
    /// Mean T_a (N·m).
    pub torque_nm: f64,
    /// Free-motion residual T_a − T_free(θa) (N·m); NaN where the model has no free pose.
    pub resid_nm: f64,
    /// Index of the first trace row in the block.
    pub first_row: u32,
    /// The block's rows in which the crank moved: θa changed from the row before by half an
    /// encoder count ([`OfflineConfig::encoder_count_rad`]) or more, or faster than
    /// [`OfflineConfig::end_speed_rad_s`] (rows).
    pub moving_rows: u32,
    /// Mean θa over the moving rows (rad); NaN when none moved.
    pub moving_theta_a_rad: f64,
    /// Mean T_a over the moving rows (N·m); NaN when none moved.
    pub moving_torque_nm: f64,
}

/// Tuning of the segmenter. SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OfflineConfig {
    /// Block length (s): the trace is averaged into blocks of this length (lengthened when
    /// the scratch is too short for the trace).
    pub block_s: f64,
    /// Free-motion window (blocks).
    pub free_window: usize,
    /// Least θa travel in the free-motion window to arm (rad).
    pub arm_rad: f64,
    /// Free motion: largest change of the residual per radian of θa across a free-motion
    /// window (N·m/rad); a contact adds at least K_c,proximal − K_free ≈ 2.
    pub free_slope_nm_per_rad: f64,
    /// End point: largest θa speed of the settled (or quasi-statically creeping) end (rad/s);
    /// a row slower than this, by less than half an encoder count, does not count as moving
    /// ([`Block::moving_rows`]).
    pub end_speed_rad_s: f64,
    /// The finger's encoder count at θa (rad, > 0): a row that changes θa by half of it or
    /// more moved, whatever the sample rate (a quantised recording shows every move as whole
    /// counts).
    pub encoder_count_rad: f64,
    /// Least rise of the free-motion residual above the approach offset that counts as a
    /// contact (N·m); the threshold is the larger of this and 8 σ of the residual.
    pub detect_excess_nm: f64,
    /// Consecutive blocks above the threshold (blocks).
    pub confirm: usize,
    /// Static / quasi-static window (blocks).
    pub static_window: usize,
    /// θa band of a static window (rad), on top of the encoder quantum.
    pub static_band_rad: f64,
    /// T_a band of a static hold (N·m); the larger of this and 6 σ of the residual.
    pub torque_band_nm: f64,
    /// A window whose dT_a/dθa exceeds this is a stiction plateau, not the path (N·m/rad).
    pub plateau_stiffness_nm_per_rad: f64,
    /// Unloading: the torque fell this far below its running maximum (N·m), or 30 % of the
    /// rise since contact if larger.
    pub unload_drop_nm: f64,
    /// Smallest accepted ΔT_a = T_a,end − T_a,c (N·m).
    pub min_step_nm: f64,
    /// Estimator named in the request.
    pub estimator: Estimator,
    /// Detection stiffness carried in the request (N·m/rad; informative).
    pub detect_stiffness_nm_per_rad: f64,
}

impl OfflineConfig {
    /// Defaults: 4 ms blocks (the controller's sample), 100 ms windows.
    pub const DEFAULT: OfflineConfig = OfflineConfig {
        block_s: 4e-3,
        free_window: 25,
        arm_rad: 5e-4,
        free_slope_nm_per_rad: 0.5,
        end_speed_rad_s: 0.015,
        // The paper prototype's drive.
        encoder_count_rad: grasp::DriveConfig::DEFAULT.rad_per_count(),
        detect_excess_nm: 0.012,
        confirm: 5,
        static_window: 25,
        static_band_rad: 6e-5,
        torque_band_nm: 0.004,
        plateau_stiffness_nm_per_rad: 60.0,
        unload_drop_nm: 0.03,
        min_step_nm: 0.03,
        estimator: Estimator::TwoPoint,
        detect_stiffness_nm_per_rad: 1.5,
    };

    /// The defaults with another estimator.
    pub const fn with_estimator(mut self, estimator: Estimator) -> Self {
        self.estimator = estimator;
        self
    }

    /// With another encoder count at θa (rad), e.g. a finger file's `rad_per_count()`.
    pub const fn with_encoder_count(mut self, count_rad: f64) -> Self {
        self.encoder_count_rad = count_rad;
        self
    }
}

impl Default for OfflineConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why no request could be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OfflineError {
    /// Too few rows or blocks for a free-motion window, a contact and a hold.
    TooShort,
    /// A value is NaN or infinite (row index).
    NonFinite {
        /// Row.
        row: u32,
    },
    /// Time goes backwards at this row (sort the rows first).
    NonMonotoneTime {
        /// Row.
        row: u32,
    },
    /// A configuration value is out of range.
    BadConfig,
    /// No free motion (θa advancing with a flat free-motion residual) before the end.
    NoFreeMotion,
    /// Free motion, but no contact after it.
    NoContact,
    /// The torque after the contact rose by less than the minimum (µN·m).
    StepTooSmall {
        /// T_a,end − T_a,c (µN·m).
        delta_ta_unm: i32,
    },
    /// No static (or steady-torque) hold after the contact.
    NotSettled,
    /// A lone θa sample far off both its neighbours (which agree): a corrupted row. The
    /// crank cannot leave and come back within two samples.
    Outlier {
        /// Row.
        row: u32,
    },
    /// Fewer than [`MIN_RATE_HZ`] rows per second: the impact and the contact knee cannot be
    /// told apart at this rate.
    SampleRateTooLow {
        /// Mean rate (Hz).
        rate_hz: u32,
    },
    /// The recording rests too far from the finger's free poses ([`check_rest_frame`]): its
    /// θa is not this finger's absolute model angle (an encoder zeroed at power-up, angles in
    /// degrees, another finger's file).
    AngleFrame {
        /// θa over the still rows the recording starts with (µrad).
        rest_urad: i32,
        /// θa of the finger's free pose at zero torque, its rest (µrad).
        model_urad: i32,
    },
    /// The torque over the start of the approach is not this finger's free-motion torque in
    /// N·m at the crank ([`check_torque_frame`]): negated, in mN·m, or the motor shaft's.
    TorqueFrame {
        /// Median recorded T_a over those rows (µN·m).
        recorded_unm: i64,
        /// Median free-motion torque the finger needs at their θa (µN·m).
        model_unm: i64,
    },
    /// The torque sensor's range was exceeded ([`check_saturation`]): a run of rows holds the
    /// recording's largest torque bit for bit, where elsewhere the torque varies from row to
    /// row; the step's top is not known.
    TorqueSaturated {
        /// The torque held (µN·m).
        level_unm: i64,
        /// Rows in the run.
        rows: u32,
        /// Trace time of its first and last row (ms).
        from_ms: i64,
        /// See `from_ms`.
        to_ms: i64,
        /// σ of the torque's change from row to row over the recording (µN·m).
        sigma_unm: i64,
    },
    /// The model failed.
    Model(PtsError),
}

/// Least mean sample rate [`make_blocks`] accepts (Hz).
pub const MIN_RATE_HZ: f64 = 250.0;

/// θa jump (rad) off both neighbours that marks a lone row as an outlier (while the
/// neighbours agree within a quarter of it): 20 mrad in one sample is 5 rad/s at 250 Hz,
/// beyond any crank speed of a grasp and far beyond a free-motion step.
pub const OUTLIER_RAD: f64 = 0.02;

impl OfflineError {
    /// A stable snake_case name.
    pub const fn kind(&self) -> &'static str {
        match self {
            OfflineError::TooShort => "trace_too_short",
            OfflineError::NonFinite { .. } => "non_finite",
            OfflineError::NonMonotoneTime { .. } => "non_monotone_time",
            OfflineError::BadConfig => "bad_config",
            OfflineError::NoFreeMotion => "no_free_motion",
            OfflineError::NoContact => "no_contact",
            OfflineError::StepTooSmall { .. } => "step_too_small",
            OfflineError::NotSettled => "not_settled",
            OfflineError::Outlier { .. } => "outlier_sample",
            OfflineError::SampleRateTooLow { .. } => "sample_rate_too_low",
            OfflineError::AngleFrame { .. } => "angle_frame",
            OfflineError::TorqueFrame { .. } => "torque_frame",
            OfflineError::TorqueSaturated { .. } => "torque_saturated",
            OfflineError::Model(e) => e.kind(),
        }
    }
}

impl core::fmt::Display for OfflineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            OfflineError::TooShort => {
                f.write_str("too few rows for a free-motion window, a contact and a hold")
            }
            OfflineError::NonFinite { row } => write!(f, "row {row} holds NaN or infinity"),
            OfflineError::NonMonotoneTime { row } => write!(f, "time goes backwards at row {row}"),
            OfflineError::BadConfig => f.write_str("a segmentation setting is out of range"),
            OfflineError::NoFreeMotion => {
                f.write_str("no free motion (θa advancing on the free-motion torque) before the end")
            }
            OfflineError::NoContact => f.write_str("free motion, but no contact after it"),
            OfflineError::StepTooSmall { delta_ta_unm } => write!(
                f,
                "the torque rose by {:.1} mN·m after the contact, below the step the estimate needs",
                f64::from(*delta_ta_unm) * 1e-3
            ),
            OfflineError::NotSettled => f.write_str("no static hold after the contact"),
            OfflineError::Outlier { row } => write!(
                f,
                "θa of row {row} lies more than {OUTLIER_RAD} rad off both its neighbours (a corrupted row)"
            ),
            OfflineError::SampleRateTooLow { rate_hz } => {
                write!(
                    f,
                    "recorded at {rate_hz} rows per second (of the median row spacing), below \
                     the {MIN_RATE_HZ} the contact detection needs"
                )?;
                // A row every millisecond written in milliseconds reads as 1 Hz.
                if *rate_hz <= 4 {
                    f.write_str("; t_s is in seconds: a time column in milliseconds reads so")?;
                }
                Ok(())
            }
            OfflineError::AngleFrame {
                rest_urad,
                model_urad,
            } => {
                let (rest, model) = (f64::from(*rest_urad) * 1e-6, f64::from(*model_urad) * 1e-6);
                write!(
                    f,
                    "the recording rests at θa = {rest:.4} rad, the finger file's rest is \
                     {model:.4} rad ({:+.4} rad apart; a finger rests within \
                     {REST_FRAME_TOL_RAD} rad of its free poses): θa is not this finger's \
                     absolute model angle in radians (an encoder zeroed at rest reads 0 there, \
                     and `--theta-a-offset {:.4}` adds the difference to every row), or the \
                     file is another finger's",
                    rest - model,
                    model - rest
                )?;
                // An encoder wired or signed the other way reads the rest angle negated;
                // an offset would bring the rest back but not the direction of closing.
                if (rest + model).abs() <= REST_FRAME_TOL_RAD {
                    f.write_str(
                        "; it lies near the rest angle negated: if the encoder counts the \
                         other way, negate θa (and T_a) rather than offset it",
                    )?;
                }
                if (rest.to_radians() - model).abs() <= REST_FRAME_TOL_RAD {
                    write!(
                        f,
                        "; read as degrees it is {:.4} rad, near the rest: θa is in degrees, \
                         and every row's must be converted to radians",
                        rest.to_radians()
                    )?;
                }
                Ok(())
            }
            OfflineError::TorqueFrame {
                recorded_unm,
                model_unm,
            } => {
                let (rec, need) = (*recorded_unm as f64 * 1e-6, *model_unm as f64 * 1e-6);
                write!(
                    f,
                    "over the first {TORQUE_FRAME_SPAN_RAD} rad the crank closes, T_a is a median \
                     {rec:.4} N·m where this finger's free motion needs {need:.4} N·m there \
                     ({:.3}×; a recording's approach reads {TORQUE_FRAME_MIN_RATIO}× to \
                     {TORQUE_FRAME_MAX_RATIO}× it, friction and acceleration included): ",
                    rec / need
                )?;
                f.write_str(if rec < 0.0 {
                    "T_a is negated (a sensor or a sign convention the other way): negate every \
                     row's torque"
                } else if rec > need {
                    "T_a is not in N·m (mN·m, or a current in mA, reads 1000×), or the file is \
                     another finger's"
                } else {
                    "T_a is not the torque at the crank (the motor shaft's reads the gearhead's \
                     ratio smaller: T_a is the motor torque referred to the base link), or the \
                     file is another finger's"
                })
            }
            OfflineError::TorqueSaturated {
                level_unm,
                rows,
                from_ms,
                to_ms,
                sigma_unm,
            } => write!(
                f,
                "T_a stays at exactly {:.4} N·m, the recording's largest, for {rows} rows \
                 (t = {:.3} … {:.3} s), where elsewhere it changes from row to row by σ {:.4} N·m: \
                 the torque sensor's range was exceeded there, so the step's top is not known \
                 (record with a wider range, or step by less)",
                *level_unm as f64 * 1e-6,
                *from_ms as f64 * 1e-3,
                *to_ms as f64 * 1e-3,
                *sigma_unm as f64 * 1e-6,
            ),
            OfflineError::Model(e) => write!(f, "the model: {e}"),
        }
    }
}

/// θa difference (rad) within which two block means are the same angle. Means of the same
/// encoder readings differ in their last bits (about 1e-16 rad) with how their sums round, and
/// a decision taken on that difference (the crank turned back, or moved on) would be a draw
/// of the rounding; this is far below any encoder's count and far above that rounding.
pub const SAME_ANGLE_RAD: f64 = 1e-9;

/// How block mean θa `a` lies against `b` (rad), equal within [`SAME_ANGLE_RAD`]; `None`
/// when either is NaN.
pub fn angle_order(a: f64, b: f64) -> Option<core::cmp::Ordering> {
    if (a - b).abs() <= SAME_ANGLE_RAD {
        Some(core::cmp::Ordering::Equal)
    } else {
        a.partial_cmp(&b)
    }
}

/// How far (rad) the θa a recording rests at may lie from the finger's free poses in
/// [`check_rest_frame`]. A built finger rests within its stiction band (static friction over
/// the free-motion stiffness, 0.55‥0.9 N·m/rad on the paper's finger) and a few degrees of
/// its file's rest-angle error, together below 0.15 rad; an encoder zeroed at rest is off by
/// the whole rest angle (0.85 rad on the paper's finger).
pub const REST_FRAME_TOL_RAD: f64 = 0.25;

/// Least stillness (s) at the start of a recording for [`check_rest_frame`] to read a rest
/// from it.
pub const REST_FRAME_MIN_S: f64 = 0.02;
/// Least still rows at the start of a recording for [`check_rest_frame`].
pub const REST_FRAME_MIN_ROWS: usize = 5;
/// θa change (rad) from the first row that ends the still rows at the start of a recording.
pub const REST_MOVED_RAD: f64 = 1e-3;

/// The first row whose θa lies more than [`REST_MOVED_RAD`] from the first row's: where the
/// crank first moved. `None` when it never does (or there are no rows).
pub fn first_moving_row(rows: &[TraceSample]) -> Option<usize> {
    let first = rows.first()?;
    rows.iter()
        .position(|r| !((r.theta_a_rad - first.theta_a_rad).abs() <= REST_MOVED_RAD))
}

/// The recording's angle frame against the finger's. Where the rows start still (for at
/// least [`REST_FRAME_MIN_S`]: the finger at rest before the approach), their median θa must
/// lie within [`REST_FRAME_TOL_RAD`] of the finger's free poses between zero torque and the
/// rows' median torque (which a current sensor's offset may carry as well as the springs).
/// `Ok(None)` when the recording starts moving or the model has no free pose at those torques
/// (nothing to compare); `Ok(Some((rest, model)))` (rad: the rest read and the finger's at
/// zero torque) when it was compared and passed.
pub fn check_rest_frame(
    model: &pts::Model<f64>,
    rows: &[TraceSample],
) -> Result<Option<(f64, f64)>, OfflineError> {
    let Some(first) = rows.first() else {
        return Ok(None);
    };
    let still = first_moving_row(rows).unwrap_or(rows.len());
    let rest_rows = &rows[..still];
    let span_s = rest_rows.last().map_or(0.0, |r| r.t_s - first.t_s);
    if rest_rows.len() < REST_FRAME_MIN_ROWS || !(span_s >= REST_FRAME_MIN_S) {
        return Ok(None);
    }
    let rest = upper_median(rest_rows.iter().map(|r| r.theta_a_rad).collect());
    let torque = upper_median(rest_rows.iter().map(|r| r.torque_nm).collect());
    let pose = |t: f64| model.free_from_torque(t).map(|c| c.theta_a).ok();
    let (Some(at_zero), Some(at_rest)) = (pose(0.0), pose(torque)) else {
        return Ok(None);
    };
    let (lo, hi) = (at_zero.min(at_rest), at_zero.max(at_rest));
    if rest >= lo - REST_FRAME_TOL_RAD && rest <= hi + REST_FRAME_TOL_RAD {
        return Ok(Some((rest, at_zero)));
    }
    Err(OfflineError::AngleFrame {
        rest_urad: grasp::estimate::to_micro(rest),
        model_urad: grasp::estimate::to_micro(at_zero),
    })
}

/// How far (rad) past the first moving row's θa [`check_torque_frame`] reads the approach:
/// the start of any grasp's free motion (the paper's finger closes 0.63 rad before a Table 2
/// contact).
pub const TORQUE_FRAME_SPAN_RAD: f64 = 0.1;
/// Least rows [`check_torque_frame`] reads.
pub const TORQUE_FRAME_MIN_ROWS: usize = 20;
/// Least ratio of the recorded to the free-motion torque over the start of an approach in
/// [`check_torque_frame`]: a drive cannot close the finger with less than its springs hold.
/// The motor shaft's torque is the crank's over the gearhead's ratio and efficiency (tens).
pub const TORQUE_FRAME_MIN_RATIO: f64 = 0.2;
/// Largest such ratio: a drive's friction and the torque that accelerates it add several times
/// the springs' torque at the start of an approach (up to 15× on a 0.1 kg·m² drive's 0.2 s
/// ramp); mN·m read 1000×.
pub const TORQUE_FRAME_MAX_RATIO: f64 = 100.0;

/// The recording's torque frame against the finger's: over the rows from where the crank first
/// moves to [`TORQUE_FRAME_SPAN_RAD`] further (free motion in any grasp), the median recorded
/// T_a must lie within [`TORQUE_FRAME_MIN_RATIO`]…[`TORQUE_FRAME_MAX_RATIO`] of the median
/// free-motion torque at their θa. `Ok(None)` where there is nothing to compare (fewer than
/// [`TORQUE_FRAME_MIN_ROWS`] such rows, or no free pose at their θa); `Ok(Some((recorded,
/// model)))` (N·m) when it passed. A sensor's offset moves the ratio too, so `pts estimate`
/// refuses by it only a recording in which no contact was found: it names why.
pub fn check_torque_frame(
    model: &pts::Model<f64>,
    rows: &[TraceSample],
) -> Result<Option<(f64, f64)>, OfflineError> {
    let Some(m) = first_moving_row(rows) else {
        return Ok(None);
    };
    let th0 = rows[m].theta_a_rad;
    let mut rec = std::vec::Vec::new();
    let mut need = std::vec::Vec::new();
    for r in rows[m..]
        .iter()
        .take_while(|r| r.theta_a_rad - th0 <= TORQUE_FRAME_SPAN_RAD)
    {
        if let Ok(c) = model.free_from_theta_a(r.theta_a_rad) {
            rec.push(r.torque_nm);
            need.push(c.ta);
        }
    }
    if rec.len() < TORQUE_FRAME_MIN_ROWS {
        return Ok(None);
    }
    let (rec, need) = (upper_median(rec), upper_median(need));
    // A finger whose springs hold nothing there gives no scale to compare with.
    if !(need > 1e-3) {
        return Ok(None);
    }
    let ratio = rec / need;
    if (TORQUE_FRAME_MIN_RATIO..=TORQUE_FRAME_MAX_RATIO).contains(&ratio) {
        return Ok(Some((rec, need)));
    }
    Err(OfflineError::TorqueFrame {
        recorded_unm: scaled(rec, 1e6),
        model_unm: scaled(need, 1e6),
    })
}

/// Least run of rows [`check_saturation`] reads as a sensor pinned at its range's end: a
/// sensor whose noise it resolves (σ at least [`SATURATION_MIN_NOISE_STEPS`] of its steps)
/// repeats a value ten times in a row with a chance below 1e-6.
pub const SATURATION_MIN_ROWS: usize = 10;
/// How many of the torque's resolution steps (its smallest change between rows) the row-to-row
/// σ must span before [`check_saturation`] judges a run: a coarse or noise-free sensor repeats
/// its values on any hold.
pub const SATURATION_MIN_NOISE_STEPS: f64 = 2.0;

/// Least row-to-row σ of the torque (N·m) [`check_saturation`] takes for a sensor's noise:
/// below it, the variation is a simulation's rounding, not a sensor's (a current sensor on a
/// small drive reads a few mN·m of noise).
pub const SATURATION_MIN_NOISE_NM: f64 = 5e-4;

/// A torque sensor pinned at the end of its range: [`SATURATION_MIN_ROWS`] or more consecutive
/// rows hold the recording's largest torque bit for bit, while over the recording the torque
/// varies from row to row (robustly, off the line through each row's neighbours, away from
/// that value) by a σ of at least [`SATURATION_MIN_NOISE_NM`] and
/// [`SATURATION_MIN_NOISE_STEPS`] of its resolution. A noise-free recording (a simulation's
/// hold) repeats its hold torque and passes; so does one whose noise the sensor does not
/// resolve. Read as recorded, a clipped step's top looks like a softer contact, or a proximal
/// one.
pub fn check_saturation(rows: &[TraceSample]) -> Result<(), OfflineError> {
    let step = rows
        .windows(2)
        .map(|w| (w[1].torque_nm - w[0].torque_nm).abs())
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    let top = rows
        .iter()
        .map(|r| r.torque_nm)
        .fold(f64::NEG_INFINITY, f64::max);
    // Each row against the line through its neighbours (at their times: rows stamped
    // unevenly on a ramp lie on it), away from the largest value (a clipped run may be most
    // of the recording). On evenly spaced rows that is half the second difference, whose σ
    // is √6 of the rows'.
    let off_line: std::vec::Vec<f64> = rows
        .windows(3)
        .filter(|w| w.iter().all(|r| r.torque_nm != top))
        .filter_map(|w| {
            let span = w[2].t_s - w[0].t_s;
            (span > 0.0).then(|| {
                let f = (w[1].t_s - w[0].t_s) / span;
                (w[1].torque_nm - (w[0].torque_nm + f * (w[2].torque_nm - w[0].torque_nm))).abs()
            })
        })
        .collect();
    let sigma = 1.4826 * upper_median(off_line) / 1.5f64.sqrt();
    if !(sigma >= SATURATION_MIN_NOISE_NM && sigma >= SATURATION_MIN_NOISE_STEPS * step) {
        return Ok(());
    }
    // The longest run of rows at `top`: (first row, length).
    let (mut best, mut run) = ((0usize, 0usize), (0usize, 0usize));
    for (i, r) in rows.iter().enumerate() {
        if r.torque_nm == top {
            run = if run.1 == 0 {
                (i, 1)
            } else {
                (run.0, run.1 + 1)
            };
            if run.1 > best.1 {
                best = run;
            }
        } else {
            run = (i, 0);
        }
    }
    if best.1 < SATURATION_MIN_ROWS {
        return Ok(());
    }
    Err(OfflineError::TorqueSaturated {
        level_unm: scaled(top, 1e6),
        rows: u32::try_from(best.1).unwrap_or(u32::MAX),
        from_ms: scaled(rows[best.0].t_s, 1e3),
        to_ms: scaled(rows[best.0 + best.1 - 1].t_s, 1e3),
        sigma_unm: scaled(sigma, 1e6),
    })
}

/// `x` × `per` (1e6: micro-units, 1e3: milli-units) rounded to the integer a refusal names,
/// saturated at the type's range (NaN: 0).
fn scaled(x: f64, per: f64) -> i64 {
    (x * per).round().clamp(i64::MIN as f64, i64::MAX as f64) as i64
}

/// The upper of the middle values of `v` (its median for an odd count); NaN when empty.
fn upper_median(mut v: std::vec::Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

impl From<PtsError> for OfflineError {
    fn from(e: PtsError) -> Self {
        OfflineError::Model(e)
    }
}

/// A contact found in the blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Block of the knee (last block on the shifted free-motion curve).
    pub knee: usize,
    /// Block of the detection (residual confirmed above the threshold).
    pub detect: usize,
    /// Static end window: blocks `end.0 .. end.1`.
    pub end: (usize, usize),
    /// First block after this contact's segment (unloading began, or the end).
    pub next: usize,
    /// Trace time of the knee (s).
    pub contact_t_s: f64,
    /// θa,c at the knee (rad).
    pub theta_a_c_rad: f64,
    /// T_a,c on the shifted free-motion curve at the knee (N·m).
    pub ta_c_nm: f64,
    /// Approach friction/gain offset: median of T_a − T_free(θa) in free motion (N·m).
    pub offset_nm: f64,
    /// θa, T_a of the end point (rad, N·m).
    pub end_point: (f64, f64),
    /// Whether `seat2` came from a quasi-static window of the trace (else the midpoint of
    /// the chord knee → end point).
    pub static_path_points: bool,
    /// The request, as the controller builds it.
    pub request: EstimateRequest,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each refusal reads in words and names its value, not the type's Debug form.
    #[test]
    fn refusals_read_in_words_with_their_values() {
        for (e, needle) in [
            (OfflineError::NonFinite { row: 57 }, "row 57"),
            (OfflineError::NonMonotoneTime { row: 58 }, "row 58"),
            (OfflineError::Outlier { row: 59 }, "row 59"),
            (
                OfflineError::SampleRateTooLow { rate_hz: 100 },
                "100 rows per second",
            ),
            (
                OfflineError::StepTooSmall {
                    delta_ta_unm: 12_300,
                },
                "12.3 mN·m",
            ),
            (OfflineError::TooShort, "too few rows"),
            (
                OfflineError::AngleFrame {
                    rest_urad: 0,
                    model_urad: -850_361,
                },
                "--theta-a-offset -0.8504",
            ),
            (
                OfflineError::AngleFrame {
                    rest_urad: 850_361,
                    model_urad: -850_361,
                },
                "negate θa",
            ),
            (
                OfflineError::AngleFrame {
                    rest_urad: -48_722_100,
                    model_urad: -850_361,
                },
                "θa is in degrees",
            ),
            (
                OfflineError::SampleRateTooLow { rate_hz: 1 },
                "milliseconds",
            ),
            (
                OfflineError::TorqueFrame {
                    recorded_unm: -150_000,
                    model_unm: 100_000,
                },
                "negate every row's torque",
            ),
            (
                OfflineError::TorqueFrame {
                    recorded_unm: 150_000_000,
                    model_unm: 100_000,
                },
                "not in N·m",
            ),
            (
                OfflineError::TorqueFrame {
                    recorded_unm: 80,
                    model_unm: 100_000,
                },
                "not the torque at the crank",
            ),
        ] {
            let text = e.to_string();
            assert!(text.contains(needle), "{e:?}: {text}");
            assert!(!text.contains('{'), "{e:?}: {text}");
        }
        // Zeroed at rest is an offset, not a negation nor degrees; 100 Hz is no time unit.
        let zeroed = OfflineError::AngleFrame {
            rest_urad: 0,
            model_urad: -850_361,
        };
        assert!(!zeroed.to_string().contains("negate"), "{zeroed}");
        assert!(!zeroed.to_string().contains("degrees"), "{zeroed}");
        let slow = OfflineError::SampleRateTooLow { rate_hz: 100 };
        assert!(!slow.to_string().contains("milliseconds"), "{slow}");
    }

    /// Block means within [`SAME_ANGLE_RAD`] are the same angle: the means of one encoder
    /// level summed in another order, or shifted by a last-bit change of the rows, compare
    /// equal; a tenth of a microradian apart they do not; NaN has no order.
    #[test]
    fn block_means_equal_but_for_rounding_are_the_same_angle() {
        use core::cmp::Ordering::{Equal, Greater, Less};
        let level = -0.223_771_185_f64;
        let rows = [level, level + 1e-16, level, level - 1e-16, level + 2e-16];
        let fwd: f64 = rows.iter().sum::<f64>() / 5.0;
        let back: f64 = rows.iter().rev().sum::<f64>() / 5.0;
        assert_eq!(angle_order(fwd, back), Some(Equal));
        assert_eq!(angle_order(level + 1e-12, level), Some(Equal));
        assert_eq!(angle_order(level + 1e-7, level), Some(Greater));
        assert_eq!(angle_order(level - 1e-7, level), Some(Less));
        assert_eq!(angle_order(f64::NAN, level), None);
    }

    /// 0.1 s at rest at `rest` rad and `torque` N·m, then an approach at 0.5 rad/s.
    fn rest_then_moving(rest: f64, torque: f64) -> std::vec::Vec<TraceSample> {
        (0..300)
            .map(|i| {
                let t = i as f64 * 1e-3;
                TraceSample {
                    t_s: t,
                    theta_a_rad: rest + 0.5 * (t - 0.1).max(0.0),
                    torque_nm: torque,
                }
            })
            .collect()
    }

    /// The rest a recording starts from is held to the finger's free poses (the paper's
    /// finger rests at θa = −0.8503608 rad, its free motion at 0.55‥0.9 N·m/rad): within
    /// 0.25 rad of the poses between zero torque and the rest's torque it is read, farther it
    /// is refused with both angles; a recording that starts moving is not judged.
    #[test]
    fn the_rest_a_recording_starts_from_is_held_to_the_finger_s() {
        let m = pts::Model::<f64>::paper().unwrap();
        let rest = m.free_from_torque(0.0).unwrap().theta_a;
        assert!((rest - -0.850_360_8).abs() < 1e-6, "{rest}");
        let check = |r: f64, t: f64| check_rest_frame(&m, &rest_then_moving(r, t));
        let read = check(rest, 0.0).unwrap().unwrap();
        assert!((read.0 - rest).abs() < 1e-12 && (read.1 - rest).abs() < 1e-12);
        for off in [-0.24, -0.1, 0.1, 0.24] {
            assert!(check(rest + off, 0.0).unwrap().is_some(), "{off}");
        }
        for off in [-0.26, 0.26, -rest] {
            let e = check(rest + off, 0.0).unwrap_err();
            assert_eq!(e.kind(), "angle_frame");
            let OfflineError::AngleFrame {
                rest_urad,
                model_urad,
            } = e
            else {
                panic!("{e:?}");
            };
            assert_eq!(rest_urad, ((rest + off) * 1e6).round() as i32);
            assert_eq!(model_urad, (rest * 1e6).round() as i32);
        }
        // A current sensor's offset of 0.2 N·m at rest: the free pose at that torque lies
        // 0.2–0.4 rad above the rest; a rest at either is read, 0.3 rad below neither.
        let at = m.free_from_torque(0.2).unwrap().theta_a;
        assert!(at - rest > 0.2, "{at}");
        assert!(check(rest, 0.2).unwrap().is_some());
        assert!(check(at + 0.2, 0.2).unwrap().is_some());
        assert!(check(rest - 0.3, 0.2).is_err());
        // Degrees instead of radians: refused.
        assert!(check(rest.to_degrees(), 0.0).is_err());
        // Moving from the first row, or still for less than 20 ms: nothing to judge.
        let moving: std::vec::Vec<TraceSample> = rest_then_moving(0.0, 0.0)[100..].to_vec();
        assert_eq!(check_rest_frame(&m, &moving), Ok(None));
        let brief: std::vec::Vec<TraceSample> = rest_then_moving(0.0, 0.0)[85..].to_vec();
        assert_eq!(check_rest_frame(&m, &brief), Ok(None));
        assert_eq!(check_rest_frame(&m, &[]), Ok(None));
    }

    /// An approach from rest at 0.5 rad/s whose torque is `scale` × (the finger's free-motion
    /// torque at each row's θa + 0.02 N·m of friction).
    fn approach_at(scale: f64) -> std::vec::Vec<TraceSample> {
        let m = pts::Model::<f64>::paper().unwrap();
        let rest = m.free_from_torque(0.0).unwrap().theta_a;
        (0..500)
            .map(|i| {
                let t = i as f64 * 1e-3;
                let th = rest + 0.5 * (t - 0.1).max(0.0);
                let free = m.free_from_theta_a(th).unwrap().ta;
                TraceSample {
                    t_s: t,
                    theta_a_rad: th,
                    torque_nm: scale * (free + 0.02),
                }
            })
            .collect()
    }

    /// The torque a recording closes the finger with is held to the finger's free motion
    /// (its springs' torque, computed here from the model the check uses, plus a drive's
    /// friction): in N·m at the crank it is read; negated, in mN·m or at the motor shaft
    /// (÷ the prototype's 3072 · 0.6175) it is refused with both torques and what to change;
    /// with fewer than 20 rows over the first 0.1 rad of closing nothing is judged.
    #[test]
    fn the_torque_a_recording_closes_with_is_held_to_the_finger_s() {
        let m = pts::Model::<f64>::paper().unwrap();
        let (rec, need) = check_torque_frame(&m, &approach_at(1.0)).unwrap().unwrap();
        assert!(rec > need && rec < need + 0.03, "{rec} vs {need}");
        // The springs' torque rises from zero at rest: 0.028 N·m halfway through the span.
        assert!(need > 0.01 && need < 0.06, "{need}");
        for (scale, needle) in [
            (-1.0, "negate every row's torque"),
            (1000.0, "not in N·m"),
            (1.0 / (3072.0 * 0.6175), "not the torque at the crank"),
        ] {
            let e = check_torque_frame(&m, &approach_at(scale)).unwrap_err();
            assert_eq!(e.kind(), "torque_frame");
            let OfflineError::TorqueFrame {
                recorded_unm,
                model_unm,
            } = e
            else {
                panic!("{e:?}");
            };
            assert!(
                (recorded_unm as f64 * 1e-6 - scale * rec).abs() <= 1e-6 * scale.abs().max(1.0),
                "{scale}: {recorded_unm}"
            );
            assert_eq!(model_unm, (need * 1e6).round() as i64);
            assert!(e.to_string().contains(needle), "{scale}: {e}");
        }
        // At the bounds of the ratio: 0.2× and 100× read, just outside them refused.
        for (scale, ok) in [(0.21, true), (0.19, false), (99.0, true), (101.0, false)] {
            let rows: std::vec::Vec<TraceSample> = approach_at(1.0)
                .into_iter()
                .map(|r| TraceSample {
                    torque_nm: scale * need,
                    ..r
                })
                .collect();
            assert_eq!(check_torque_frame(&m, &rows).is_ok(), ok, "{scale}");
        }
        // Still throughout, or 19 rows of closing: nothing to judge.
        let still: std::vec::Vec<TraceSample> = approach_at(1.0)[..100].to_vec();
        assert_eq!(check_torque_frame(&m, &still), Ok(None));
        let brief: std::vec::Vec<TraceSample> = approach_at(-1.0)[..121].to_vec();
        assert_eq!(check_torque_frame(&m, &brief), Ok(None));
        assert_eq!(check_torque_frame(&m, &[]), Ok(None));
    }

    /// A ramp to a hold with torque noise of σ 4 mN·m from a fixed generator, sampled at
    /// 1 kHz, its torque rounded to `step` N·m (0: not rounded) and clipped at `clip` N·m.
    fn noisy_hold(sigma: f64, step: f64, clip: f64) -> std::vec::Vec<TraceSample> {
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..1000)
            .map(|i| {
                let t = i as f64 * 1e-3;
                let (u, v) = (uniform(), uniform());
                let noise = (-2.0 * u.ln()).sqrt() * (2.0 * core::f64::consts::PI * v).cos();
                let mut torque = (0.3 + t).min(0.8) + sigma * noise;
                if step > 0.0 {
                    torque = (torque / step).round() * step;
                }
                TraceSample {
                    t_s: t,
                    theta_a_rad: -0.85 + 0.5 * t,
                    torque_nm: torque.min(clip),
                }
            })
            .collect()
    }

    /// A noisy torque held at its largest value for a run of rows is a sensor at its range's
    /// end: refused, naming the level, the run and the noise. The same recording unclipped,
    /// noise-free (a simulation's hold repeats its torque), or on a sensor too coarse to
    /// resolve its noise, passes; so does a run of nine rows.
    #[test]
    fn a_torque_pinned_at_its_largest_value_is_a_saturated_sensor() {
        let e = check_saturation(&noisy_hold(4e-3, 0.0, 0.7)).unwrap_err();
        assert_eq!(e.kind(), "torque_saturated");
        let OfflineError::TorqueSaturated {
            level_unm,
            rows,
            from_ms,
            to_ms,
            sigma_unm,
        } = e
        else {
            panic!("{e:?}");
        };
        assert_eq!(level_unm, 700_000);
        // The clean ramp crosses 0.7 N·m at 0.4 s; the noise moves the run's start.
        assert!((380..=460).contains(&from_ms), "{from_ms}");
        assert_eq!(to_ms, 999);
        assert!(
            rows >= 500 && i64::from(rows) <= to_ms - from_ms + 1,
            "{rows}"
        );
        assert!((3_000..=5_000).contains(&sigma_unm), "{sigma_unm}");
        for needle in ["0.7000 N·m", "exceeded"] {
            assert!(e.to_string().contains(needle), "{e}");
        }
        assert_eq!(check_saturation(&noisy_hold(4e-3, 0.0, 10.0)), Ok(()));
        assert_eq!(check_saturation(&noisy_hold(0.0, 0.0, 0.7)), Ok(()));
        assert_eq!(check_saturation(&noisy_hold(4e-3, 0.01, 0.7)), Ok(()));
        // Nine rows at the largest value are a draw, not a sensor at its end.
        let mut nine = noisy_hold(4e-3, 0.0, 10.0);
        for r in nine.iter_mut().skip(500).take(9) {
            r.torque_nm = 1.0;
        }
        assert_eq!(check_saturation(&nine), Ok(()));
        nine[509].torque_nm = 1.0;
        assert_eq!(
            check_saturation(&nine).map_err(|e| e.kind()),
            Err("torque_saturated")
        );
        assert_eq!(check_saturation(&[]), Ok(()));
    }
}
