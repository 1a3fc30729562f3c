//! Offline segmentation of a recorded grasp: finds each contact in a time series
//! (t, θa, T_a) that our controller did not produce, and builds the same
//! [`EstimateRequest`] the controller builds, so that [`run_estimate`](crate::run_estimate)
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
//! from the detection to the end decimated into [`PATH_CAPACITY`] (`path`), the knee
//! (`contact`), the static points and the measured ΔT_a; block ticks are block indices + 1
//! and `dt_ns` the block length.
//!
//! No allocation (the caller provides the block scratch), no panics, typed [`OfflineError`]s.
//! Floating point (f64) is fine here: this runs on a host or in the low-priority task, never
//! in `tick()`.

// `!(x > y)` is the NaN guard: it is true for NaN, `x <= y` is not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use heapless::Vec;
use pts::{Model, PtsError};

use crate::config::{Estimator, HISTORY};
use crate::estimate::{to_micro as micro, EstimateRequest, Sample, PATH_CAPACITY};

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
    /// End point: largest θa speed of the settled (or quasi-statically creeping) end (rad/s).
    pub end_speed_rad_s: f64,
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
}

impl Default for OfflineConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why no request could be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
            OfflineError::Model(e) => e.kind(),
        }
    }
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

/// Averages the trace into blocks (into `scratch`); returns how many were written and the
/// block length used (s). Rows must be in non-decreasing time; equal times are fine.
pub fn make_blocks<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    rows: &[TraceSample],
    scratch: &mut [Block],
) -> Result<(usize, f64), OfflineError> {
    if !(cfg.block_s.is_finite() && cfg.block_s > 0.0) || scratch.is_empty() {
        return Err(OfflineError::BadConfig);
    }
    let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
        return Err(OfflineError::TooShort);
    };
    let mut prev = first.t_s;
    for (i, r) in rows.iter().enumerate() {
        if !(r.t_s.is_finite() && r.theta_a_rad.is_finite() && r.torque_nm.is_finite()) {
            return Err(OfflineError::NonFinite { row: i as u32 });
        }
        if r.t_s < prev {
            return Err(OfflineError::NonMonotoneTime { row: i as u32 });
        }
        prev = r.t_s;
    }
    for (i, w) in rows.windows(3).enumerate() {
        if let [a, b, c] = w {
            let (d1, d2) = (b.theta_a_rad - a.theta_a_rad, b.theta_a_rad - c.theta_a_rad);
            if d1.abs() > OUTLIER_RAD
                && d2.abs() > OUTLIER_RAD
                && d1.signum() == d2.signum()
                && (c.theta_a_rad - a.theta_a_rad).abs() < 0.25 * OUTLIER_RAD
            {
                return Err(OfflineError::Outlier { row: i as u32 + 1 });
            }
        }
    }
    let span = last.t_s - first.t_s;
    if rows.len() > 1 && span > 0.0 {
        let rate = (rows.len() - 1) as f64 / span;
        if rate < MIN_RATE_HZ * 0.98 {
            return Err(OfflineError::SampleRateTooLow {
                rate_hz: rate as u32,
            });
        }
    }
    let cap = scratch.len() as f64;
    let block = if span / cfg.block_s > cap - 1.0 {
        span / (cap - 1.0)
    } else {
        cfg.block_s
    };
    if !(block > 0.0) {
        return Err(OfflineError::TooShort);
    }
    let mut n = 0usize;
    let mut cur: Option<(u32, f64, f64, f64, u32, u32)> = None; // idx, Σt, Σθ, ΣT, count, first
    let mut flush = |c: (u32, f64, f64, f64, u32, u32), n: &mut usize| {
        let k = f64::from(c.4);
        let th = c.2 / k;
        let resid = model
            .free_from_theta_a(R::from_f64(th))
            .map(|f| c.3 / k - f.ta.to_f64())
            .unwrap_or(f64::NAN);
        if let Some(slot) = scratch.get_mut(*n) {
            *slot = Block {
                index: c.0,
                t_s: c.1 / k,
                theta_a_rad: th,
                torque_nm: c.3 / k,
                resid_nm: resid,
                first_row: c.5,
            };
            *n += 1;
        }
    };
    for (i, r) in rows.iter().enumerate() {
        let idx = ((r.t_s - first.t_s) / block) as u32;
        match cur {
            Some(ref mut c) if c.0 == idx => {
                c.1 += r.t_s;
                c.2 += r.theta_a_rad;
                c.3 += r.torque_nm;
                c.4 = c.4.saturating_add(1);
            }
            _ => {
                if let Some(c) = cur {
                    flush(c, &mut n);
                }
                cur = Some((idx, r.t_s, r.theta_a_rad, r.torque_nm, 1, i as u32));
            }
        }
    }
    if let Some(c) = cur {
        flush(c, &mut n);
    }
    Ok((n, block))
}

/// Median of up to 64 values (NaN ignored); `None` when empty.
fn median(vals: impl Iterator<Item = f64>) -> Option<f64> {
    let mut buf = [0.0f64; 64];
    let mut n = 0;
    for v in vals {
        if v.is_nan() {
            continue;
        }
        if let Some(s) = buf.get_mut(n) {
            *s = v;
            n += 1;
        }
    }
    let s = buf.get_mut(..n)?;
    s.sort_unstable_by(|a, b| a.partial_cmp(b).unwrap_or(core::cmp::Ordering::Equal));
    if n == 0 {
        return None;
    }
    let a = s.get((n - 1) / 2).copied()?;
    let b = s.get(n / 2).copied()?;
    Some(0.5 * (a + b))
}

/// A free-motion window: θa advanced by ≥ arm, residual flat. Returns (offset, σ).
fn free_window(cfg: &OfflineConfig, w: &[Block]) -> Option<(f64, f64)> {
    let (first, last) = (w.first()?, w.last()?);
    if w.iter().any(|b| b.resid_nm.is_nan()) {
        return None;
    }
    if !(last.theta_a_rad - first.theta_a_rad >= cfg.arm_rad) {
        return None;
    }
    // θa must advance through the window (no stall in the middle of it).
    let h = w.len() / 2;
    let (a, b) = w.split_at(h);
    let mid = b.first()?.theta_a_rad;
    let travel = last.theta_a_rad - first.theta_a_rad;
    if !(mid - first.theta_a_rad > 0.2 * travel && last.theta_a_rad - mid > 0.2 * travel) {
        return None;
    }
    let off = median(w.iter().map(|b| b.resid_nm))?;
    // σ from successive differences: a trend (a slow contact rise) must not pass for noise.
    let mad = median(w.windows(2).map(|p| match p {
        [x, y] => (y.resid_nm - x.resid_nm).abs(),
        _ => f64::NAN,
    }))?;
    let sigma = 1.4826 * mad / core::f64::consts::SQRT_2;
    let ma = median(a.iter().map(|b| b.resid_nm))?;
    let mb = median(b.iter().map(|b| b.resid_nm))?;
    // Flat: the residual's change between the halves is noise, or far less than a contact
    // adds per radian (≥ K_c,proximal − K_free ≈ 2 N·m/rad).
    let dth = mean(b, |x| x.theta_a_rad) - mean(a, |x| x.theta_a_rad);
    if !((mb - ma).abs() <= 2.0 * sigma + cfg.free_slope_nm_per_rad * dth.abs()) {
        return None;
    }
    Some((off, sigma))
}

/// Least-squares line θ = a + b·t over a window; returns (slope, max |residual|).
fn line_in_time(w: &[Block]) -> Option<(f64, f64)> {
    let n = w.len() as f64;
    if w.len() < 3 {
        return None;
    }
    let mt = w.iter().map(|b| b.t_s).sum::<f64>() / n;
    let mth = w.iter().map(|b| b.theta_a_rad).sum::<f64>() / n;
    let (stt, stth) = w.iter().fold((0.0, 0.0), |(a, c), b| {
        let dt = b.t_s - mt;
        (a + dt * dt, c + dt * (b.theta_a_rad - mth))
    });
    if !(stt > 0.0) {
        return None;
    }
    let slope = stth / stt;
    let dev = w
        .iter()
        .map(|b| (b.theta_a_rad - mth - slope * (b.t_s - mt)).abs())
        .fold(0.0, f64::max);
    Some((slope, dev))
}

fn range(w: &[Block], f: impl Fn(&Block) -> f64) -> f64 {
    let (lo, hi) = w
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), b| {
            (lo.min(f(b)), hi.max(f(b)))
        });
    hi - lo
}

fn mean(w: &[Block], f: impl Fn(&Block) -> f64) -> f64 {
    if w.is_empty() {
        return f64::NAN;
    }
    w.iter().map(f).sum::<f64>() / w.len() as f64
}

fn tick(b: &Block) -> u32 {
    b.index.saturating_add(1)
}

fn sample_of(b: &Block) -> Sample {
    Sample {
        tick: tick(b),
        theta_a_urad: micro(b.theta_a_rad),
        torque_unm: micro(b.torque_nm),
        torque_ref_unm: micro(b.torque_nm),
    }
}

/// Mean of a window as a sample stamped at its last block.
fn window_sample(w: &[Block]) -> Option<Sample> {
    let last = w.last()?;
    let th = mean(w, |b| b.theta_a_rad);
    let t = mean(w, |b| b.torque_nm);
    Some(Sample {
        tick: tick(last),
        theta_a_urad: micro(th),
        torque_unm: micro(t),
        torque_ref_unm: micro(t),
    })
}

/// Finds the next contact at or after block `from` and builds its request.
/// `block_s` is the block length [`make_blocks`] returned; `quantum_rad` the encoder step
/// (0 when unknown).
pub fn find_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    block_s: f64,
    quantum_rad: f64,
    from: usize,
) -> Result<Segment, OfflineError> {
    let wf = cfg.free_window.clamp(4, 64);
    let wq = cfg.static_window.clamp(4, 64);
    let conf = cfg.confirm.clamp(1, 64);
    let n = blocks.len();
    if n < from.saturating_add(wf + conf + wq) {
        return Err(if from == 0 {
            OfflineError::TooShort
        } else {
            OfflineError::NoContact
        });
    }
    let t_free = |th: f64| -> Option<f64> {
        model
            .free_from_theta_a(R::try_from_f64(th)?)
            .ok()
            .map(|c| c.ta.to_f64())
    };
    // 1-2. Arm on free motion, then detect the residual rise. The baseline of a detection is
    // the one armed a full window before the rise began (the latest ones see its start).
    let mut ring = [(0usize, 0.0f64, 0.0f64); 64];
    let mut armed: Option<(f64, f64)> = None;
    let mut ever_armed = false;
    let mut run = 0usize;
    let mut detect = None;
    let mut i = from + wf;
    while i < n {
        if run == 0 {
            if let Some(fw) = blocks.get(i - wf..i).and_then(|w| free_window(cfg, w)) {
                armed = Some(fw);
                ever_armed = true;
                if let Some(slot) = ring.get_mut(i % 64) {
                    *slot = (i, fw.0, fw.1);
                }
            }
        }
        if armed.is_none() {
            i += 1;
            continue;
        }
        // Compare with a baseline from a window at least half a window old (a slow rise
        // must not drag it along).
        let lag = wf / 2;
        let Some((off, sigma)) = ring
            .iter()
            .filter(|e| e.0 > from && e.0 + lag <= i)
            .max_by_key(|e| e.0)
            .map(|e| (e.1, e.2))
        else {
            i += 1;
            continue;
        };
        let thr = cfg.detect_excess_nm.max(8.0 * sigma);
        let r = blocks.get(i).map_or(f64::NAN, |b| b.resid_nm);
        if r - off > thr {
            run += 1;
            if run >= conf {
                let first = i + 1 - conf;
                // A stall in free motion (stiction) also raises the residual at constant θa:
                // a contact only if the finger, once it moves again, does not go back onto
                // the free-motion curve.
                if let Some(resume) = resumes_free(cfg, blocks, i, off, thr, wf) {
                    armed = None;
                    run = 0;
                    i = resume;
                    continue;
                }
                let early = ring
                    .iter()
                    .filter(|e| e.0 > from && e.0 + wf <= first)
                    .max_by_key(|e| e.0)
                    .map_or((off, sigma), |e| (e.1, e.2));
                detect = Some((first, i, early.0, early.1));
                break;
            }
        } else {
            run = 0;
        }
        i += 1;
    }
    let Some((first_above, det, offset, sigma)) = detect else {
        return Err(if ever_armed {
            OfflineError::NoContact
        } else {
            OfflineError::NoFreeMotion
        });
    };
    // The knee: the rise of the residual, extrapolated back to the shifted free-motion curve
    // (a line through the residual excess against θa while θa still advances).
    let thr = cfg.detect_excess_nm.max(8.0 * sigma);
    let low = (3.0 * sigma).max(0.25 * cfg.detect_excess_nm);
    let excess = |k: usize| blocks.get(k).map_or(f64::NAN, |b| b.resid_nm - offset);
    let mut k_lo = first_above.saturating_sub(1);
    while k_lo > from && !(excess(k_lo) <= low) {
        k_lo -= 1;
    }
    let th_lo = blocks.get(k_lo).map_or(f64::NAN, |b| b.theta_a_rad);
    let (mut sx, mut sy, mut sxx, mut sxy, mut cnt) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut th_prev = th_lo;
    let mut th_hi = th_lo;
    for k in k_lo + 1..n.min(det + 4 * conf + 1) {
        let Some(b) = blocks.get(k) else { break };
        let e = excess(k);
        if b.theta_a_rad < th_prev || e > 4.0 * thr {
            break;
        }
        th_prev = b.theta_a_rad;
        if e >= low {
            sx += b.theta_a_rad;
            sy += e;
            sxx += b.theta_a_rad * b.theta_a_rad;
            sxy += b.theta_a_rad * e;
            cnt += 1.0;
            th_hi = b.theta_a_rad;
        }
    }
    let mut theta_c = th_lo;
    if cnt >= 3.0 {
        let (mx, my) = (sx / cnt, sy / cnt);
        let vxx = sxx / cnt - mx * mx;
        let slope = (sxy / cnt - mx * my) / vxx;
        if vxx > 0.0 && slope > 0.0 {
            let z = mx - my / slope;
            if z.is_finite() {
                theta_c = z.clamp(th_lo - 5e-3, th_hi);
            }
        }
    }
    // The knee block: the last one at or below θa,c (its tick closes the free-motion data).
    // T_a,c on the free-motion curve shifted by the offset the estimator will measure: the
    // mean residual of the FIT_SAMPLES blocks up to the knee (so that its back-dating through
    // this point returns it).
    let knee_at = |theta_c: f64| -> Result<(usize, Block, f64), OfflineError> {
        let mut knee = k_lo;
        while knee > from && blocks.get(knee).is_some_and(|b| b.theta_a_rad > theta_c) {
            knee -= 1;
        }
        let kb = *blocks.get(knee).ok_or(OfflineError::TooShort)?;
        let lo = (knee + 1)
            .saturating_sub(crate::estimate::FIT_SAMPLES)
            .max(from);
        let est_off = blocks
            .get(lo..=knee)
            .map(|w| mean(w, |b| b.resid_nm))
            .filter(|v| v.is_finite())
            .unwrap_or(offset);
        let ta_c = t_free(theta_c).ok_or(OfflineError::Model(PtsError::OutOfRange))? + est_off;
        Ok((knee, kb, ta_c))
    };
    let (mut knee, mut kb, mut ta_c) = knee_at(theta_c)?;

    // 3. Segment end: the torque (median over a static window: no electrical spike counts)
    // falls well below its running maximum while the finger no longer advances.
    let thband = cfg.static_band_rad + 1.5 * quantum_rad.max(0.0);
    let half = wq / 2;
    let tmed = |j: usize| -> f64 {
        let lo = j.saturating_sub(half);
        let hi = (j + half + 1).min(n);
        blocks
            .get(lo..hi)
            .and_then(|w| median(w.iter().map(|b| b.torque_nm)))
            .unwrap_or(f64::NAN)
    };
    let theta_at = |j: usize| blocks.get(j.min(n - 1)).map_or(f64::NAN, |b| b.theta_a_rad);
    let mut tmax = f64::NEG_INFINITY;
    let mut next = n;
    for j in det..n {
        let t = tmed(j);
        if t > tmax {
            tmax = t;
        }
        let drop = cfg.unload_drop_nm.max(0.3 * (tmax - ta_c));
        if t < tmax - drop && !(theta_at(j + half) > theta_at(j) + thband) {
            next = j;
            break;
        }
    }

    // 4. End point: the last window before the segment end where the finger is static or
    // creeps quasi-statically (θa linear in time within the band, slow), with a torque that
    // moves only as the path allows (not a stiction plateau, not the start of an unload).
    let tband = cfg.torque_band_nm.max(6.0 * sigma);
    let end_ok = |w: &[Block]| -> bool {
        let Some((slope, dev)) = line_in_time(w) else {
            return false;
        };
        let dth = range(w, |b| b.theta_a_rad);
        dev <= thband
            && slope.abs() <= cfg.end_speed_rad_s
            && range(w, |b| b.torque_nm) <= tband + cfg.plateau_stiffness_nm_per_rad * dth
    };
    let mut end = None;
    let mut j = next;
    while j >= det + wq {
        if blocks.get(j - wq..j).is_some_and(end_ok) {
            end = Some((j - wq, j));
            break;
        }
        j -= 1;
    }
    let end = match end {
        Some(e) => e,
        None => {
            // Never static (an undamped oscillation): the late half of the steady-torque hold.
            let last = next.checked_sub(1).ok_or(OfflineError::NotSettled)?;
            let t_end = tmed(last);
            let mut s = last;
            while s > det && (tmed(s - 1) - t_end).abs() <= tband {
                s -= 1;
            }
            let len = last + 1 - s;
            if len < 2 * wq {
                return Err(OfflineError::NotSettled);
            }
            (s + len / 2, last + 1)
        }
    };
    let end_w = blocks.get(end.0..end.1).ok_or(OfflineError::NotSettled)?;
    let end_s = window_sample(end_w).ok_or(OfflineError::NotSettled)?;
    let t_end = f64::from(end_s.torque_unm) * 1e-6;
    let th_end = f64::from(end_s.theta_a_urad) * 1e-6;
    let dta = t_end - ta_c;
    if !(dta >= cfg.min_step_nm) {
        return Err(OfflineError::StepTooSmall {
            delta_ta_unm: micro(dta),
        });
    }

    // 5. Quasi-static windows on the path between the detection and the end window.
    let margin = (0.05 * dta).max(2e-3);
    let ta_c_knee = ta_c;
    let quasi = |w: &[Block]| -> Option<(f64, f64)> {
        let (slope, dev) = line_in_time(w)?;
        if dev > thband {
            return None;
        }
        let dtq = range(w, |b| b.torque_nm);
        let dth = slope * (w.last()?.t_s - w.first()?.t_s);
        let static_hold = dtq <= tband && dth.abs() <= thband;
        let on_path = dth > 0.0 && dtq <= cfg.plateau_stiffness_nm_per_rad * dth;
        if !(static_hold || on_path) {
            return None;
        }
        let t = mean(w, |b| b.torque_nm);
        (t > ta_c_knee - 0.1 && t < t_end - margin).then(|| (t, mean(w, |b| b.theta_a_rad)))
    };
    // With static (or quasi-static) points on the path — a controller that held the torque
    // after the contact, a slow ramp — back-date like the controller does: the parabola
    // θa(T_a) through the first one, the one nearest mid-step and the end meets the shifted
    // free-motion curve at the contact. This survives an impact that carries θa past the
    // contact (the residual's rise then starts late). Otherwise the seat is the knee itself
    // (δ_seat = 0, so the estimator's back-dating returns it) and the second point the
    // quasi-static window nearest mid-step, else the midpoint of the chord to the end.
    let quasi_from = |lo_t: f64, k0: usize| -> Option<(usize, f64, f64)> {
        let mut k = k0;
        while k + wq <= end.0 {
            if let Some(w) = blocks.get(k..k + wq) {
                if let Some((t, th)) = quasi(w) {
                    if t > lo_t {
                        return Some((k, t, th));
                    }
                }
            }
            k += 1;
        }
        None
    };
    let nearest = |want: f64, lo_t: f64, k0: usize| -> Option<(usize, f64, f64)> {
        let mut best: Option<(usize, f64, f64)> = None;
        let mut k = k0;
        while k + wq <= end.0 {
            if let Some((t, th)) = blocks.get(k..k + wq).and_then(&quasi) {
                if t > lo_t && best.is_none_or(|b| (t - want).abs() < (b.1 - want).abs()) {
                    best = Some((k, t, th));
                }
            }
            k += 1;
        }
        best
    };
    let mut static_seats: Option<(usize, usize)> = None;
    if let Some((k1, t1, th1)) = quasi_from(f64::NEG_INFINITY, det + 1) {
        if let Some((k2, tb, thb)) = nearest(0.5 * (t1 + t_end), t1 + margin, k1 + wq) {
            if let Some((th, t)) = back_date(&t_free, offset, (t1, th1), (tb, thb), (t_end, th_end))
            {
                if th >= th_lo - 0.03 {
                    theta_c = th;
                    let _ = t;
                    let k = knee_at(theta_c)?;
                    knee = k.0;
                    kb = k.1;
                    ta_c = k.2;
                    static_seats = Some((k1, k2));
                }
            }
        }
    }
    let dta = t_end - ta_c;
    if !(dta >= cfg.min_step_nm) {
        return Err(OfflineError::StepTooSmall {
            delta_ta_unm: micro(dta),
        });
    }
    let want = 0.5 * (ta_c + t_end);
    let contact = Sample {
        tick: tick(&kb),
        theta_a_urad: micro(theta_c),
        torque_unm: micro(ta_c),
        torque_ref_unm: micro(ta_c),
    };
    let mid = Sample {
        tick: contact.tick.saturating_add(1),
        theta_a_urad: micro(0.5 * (theta_c + th_end)),
        torque_unm: micro(want),
        torque_ref_unm: micro(want),
    };
    let (seat_s, seat2_s, static_pts) = match static_seats {
        Some((k1, k2)) => {
            let s1 = blocks.get(k1..k1 + wq).and_then(window_sample);
            let s2 = blocks.get(k2..k2 + wq).and_then(window_sample);
            match (s1, s2) {
                (Some(a), Some(b)) => (a, b, true),
                _ => (contact, mid, false),
            }
        }
        None => {
            let s2 = nearest(want, ta_c + margin, det + 1)
                .and_then(|(k2, _, _)| blocks.get(k2..k2 + wq))
                .and_then(window_sample);
            match s2 {
                Some(b) => (contact, b, false),
                None => (contact, mid, false),
            }
        }
    };

    // History up to the detection, the path after it.
    let mut pre: Vec<Sample, HISTORY> = Vec::new();
    let pre_lo = (det + 1).saturating_sub(HISTORY).max(from);
    for b in blocks.get(pre_lo..=det).unwrap_or(&[]) {
        let _ = pre.push(sample_of(b));
    }
    let path_blocks = blocks.get(det + 1..end.1).unwrap_or(&[]);
    let mut stride = 1usize;
    while path_blocks.len().div_ceil(stride) > PATH_CAPACITY {
        stride *= 2;
    }
    let mut path: Vec<Sample, PATH_CAPACITY> = Vec::new();
    for chunk in path_blocks.chunks(stride) {
        if let Some(s) = window_sample(chunk) {
            let _ = path.push(s);
        }
    }
    let dt_ns = (block_s * 1e9 + 0.5) as u32;
    let request = EstimateRequest {
        contact,
        seat: seat_s,
        seat2: seat2_s,
        end: end_s,
        pre,
        path,
        sample_ticks: 1,
        path_stride: stride as u32,
        delta_ta_cmd_unm: micro(dta),
        detect_k_unm_per_rad: micro(cfg.detect_stiffness_nm_per_rad),
        estimator: cfg.estimator,
        dt_ns: dt_ns.max(1),
    };
    Ok(Segment {
        knee,
        detect: det,
        end,
        next,
        contact_t_s: kb.t_s,
        theta_a_c_rad: theta_c,
        ta_c_nm: ta_c,
        offset_nm: offset,
        end_point: (th_end, t_end),
        static_path_points: static_pts,
        request,
    })
}

/// Where the parabola θa(T_a) through three points (T, θ) on the path meets the free-motion
/// curve shifted by `offset`: secant from the first point's torque downwards, as
/// `estimate::contact_point_model` does. (θa,c rad, T_a,c N·m), or `None` when implausible.
fn back_date(
    t_free: &dyn Fn(f64) -> Option<f64>,
    offset: f64,
    p1: (f64, f64),
    pb: (f64, f64),
    p2: (f64, f64),
) -> Option<(f64, f64)> {
    let ((t1, th1), (tb, thb), (t2, th2)) = (p1, pb, p2);
    if !(tb - t1 > 1e-4 && t2 - tb > 1e-4) {
        return None;
    }
    let s1b = (thb - th1) / (tb - t1);
    let sb2 = (th2 - thb) / (t2 - tb);
    let c2 = (sb2 - s1b) / (t2 - t1);
    let q = |t: f64| th1 + s1b * (t - t1) + c2 * (t - t1) * (t - tb);
    crate::estimate::meet_free_curve(&q, t_free, offset, (t1, th1), 16)
}

/// Every contact in the blocks, in order: calls `each` with each result (a contact's
/// [`Segment`], or the error that ended the search; the first `NoContact`/`NoFreeMotion`
/// after a contact is not reported). Returns the number of segments found.
pub fn for_each_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    block_s: f64,
    quantum_rad: f64,
    mut each: impl FnMut(Result<&Segment, OfflineError>),
) -> usize {
    let mut from = 0usize;
    let mut found = 0usize;
    while from < blocks.len() {
        match find_contact(model, cfg, blocks, block_s, quantum_rad, from) {
            Ok(seg) => {
                found += 1;
                each(Ok(&seg));
                from = seg.next.max(seg.end.1).max(from + 1);
            }
            Err(OfflineError::NoContact | OfflineError::NoFreeMotion | OfflineError::TooShort)
                if found > 0 =>
            {
                break;
            }
            Err(e) => {
                each(Err(e));
                // A refused contact: go on after its detection if there was one.
                match e {
                    OfflineError::StepTooSmall { .. } | OfflineError::NotSettled => {
                        // Skip past this contact's rise.
                        from = skip_contact(blocks, from).unwrap_or(blocks.len());
                    }
                    _ => break,
                }
            }
        }
    }
    found
}

/// After a rise of the residual detected at `at`: the block where the finger is back in free
/// motion (θa advancing with the residual within `thr` of `off`) before the torque falls,
/// if it is: then the rise was a stall, not a contact.
fn resumes_free(
    cfg: &OfflineConfig,
    blocks: &[Block],
    at: usize,
    off: f64,
    thr: f64,
    wf: usize,
) -> Option<usize> {
    let t_at = blocks.get(at)?.torque_nm;
    let mut j = at + wf;
    while let Some(w) = blocks.get(j - wf..j) {
        let last = w.last()?;
        if last.torque_nm < t_at - cfg.unload_drop_nm {
            return None;
        }
        if let Some((o, _)) = free_window(cfg, w) {
            if (o - off).abs() <= 0.5 * thr {
                return Some(j);
            }
        }
        j += 1;
        if j > at + 16 * wf {
            return None;
        }
    }
    None
}

/// After a refused contact: the first block after `from` where the torque is back below the
/// level it had at `from`'s free motion... approximated as the first block where θa decreases
/// for good (the finger opened). `None` when it never does.
fn skip_contact(blocks: &[Block], from: usize) -> Option<usize> {
    let mut peak = f64::NEG_INFINITY;
    let mut peak_i = from;
    for (i, b) in blocks.iter().enumerate().skip(from) {
        if b.theta_a_rad > peak {
            peak = b.theta_a_rad;
            peak_i = i;
        } else if peak - b.theta_a_rad > 0.01 {
            return Some(i.max(peak_i + 1));
        }
    }
    None
}

/// Prior knowledge of the drive (from the finger file) for [`identify_drive`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DrivePrior {
    /// Effective inertia the measured torque carries at the crank (kg·m²).
    pub inertia_kgm2: f64,
    /// σ of that prior (kg·m²); ≤ 0 or non-finite: no prior.
    pub sigma_inertia_kgm2: f64,
}

/// The drive's nuisance parameters identified from the free-motion approach of one contact:
/// there the model knows the statics (T_free(θa)), so the measured residual
/// T_a − T_free(θa) = offset + viscous·θ̇a + inertia·θ̈a + noise is linear in them.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct DriveId {
    /// Effective inertia at the crank (kg·m²), ≥ 0.
    pub inertia_kgm2: f64,
    /// Its σ (kg·m²), prior included.
    pub sigma_inertia_kgm2: f64,
    /// Viscous term (N·m·s/rad).
    pub viscous_nm_s_per_rad: f64,
    /// Sliding friction plus measurement offset (N·m) at zero speed: the residual's constant.
    pub offset_nm: f64,
    /// Robust σ of the residual about the model (N·m, per block).
    pub noise_nm: f64,
    /// Blocks used.
    pub blocks: u32,
    /// Range of θ̈a seen (rad/s²): 0 when the approach never accelerated.
    pub accel_span_rad_s2: f64,
}

/// Identifies [`DriveId`] on the approach blocks `lo..hi` (free motion, moving: blocks where
/// θa stands still are skipped, a stuck transmission's torque is anywhere in its stiction
/// band). Speed and acceleration from differences across ±2 blocks (quantisation noise on θ̈a
/// would otherwise bias the inertia low). Huber-weighted least squares, the inertia with its
/// prior and kept ≥ 0. `None` with fewer than 8 usable blocks.
pub fn identify_drive<R: pts::Real>(
    model: &Model<R>,
    blocks: &[Block],
    lo: usize,
    hi: usize,
    quantum_rad: f64,
    prior: &DrivePrior,
) -> Option<DriveId> {
    const S: usize = 2;
    let t_free = |th: f64| -> Option<f64> {
        model
            .free_from_theta_a(R::try_from_f64(th)?)
            .ok()
            .map(|c| c.ta.to_f64())
    };
    // (residual, ω, α) per usable block; at most 1024 of the latest.
    let mut pts: Vec<(f64, f64, f64), 1024> = Vec::new();
    let lo = lo.max(S);
    let hi = hi.min(blocks.len().saturating_sub(S));
    let start = hi.saturating_sub(1024).max(lo);
    let still = 0.5 * quantum_rad.max(1e-9);
    for k in start..hi {
        let (Some(a), Some(b), Some(c)) = (blocks.get(k - S), blocks.get(k), blocks.get(k + S))
        else {
            continue;
        };
        if (c.theta_a_rad - a.theta_a_rad).abs() <= still {
            continue;
        }
        let (d1, d2) = (b.t_s - a.t_s, c.t_s - b.t_s);
        if !(d1 > 0.0 && d2 > 0.0) {
            continue;
        }
        let (v1, v2) = (
            (b.theta_a_rad - a.theta_a_rad) / d1,
            (c.theta_a_rad - b.theta_a_rad) / d2,
        );
        let w = (c.theta_a_rad - a.theta_a_rad) / (d1 + d2);
        let acc = 2.0 * (v2 - v1) / (d1 + d2);
        let Some(tf) = t_free(b.theta_a_rad) else {
            continue;
        };
        let r = b.torque_nm - tf;
        if r.is_finite() && w.is_finite() && acc.is_finite() {
            let _ = pts.push((r, w, acc));
        }
    }
    if pts.len() < 8 {
        return None;
    }
    let (amin, amax) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| {
            (l.min(p.2), h.max(p.2))
        });
    let prior_on = prior.sigma_inertia_kgm2.is_finite() && prior.sigma_inertia_kgm2 > 0.0;
    // IRLS: Huber weights at 2 σ, σ from the MAD of the residuals.
    let mut x = [0.0f64; 3];
    let mut scale = f64::INFINITY;
    let mut cov_jj = f64::INFINITY;
    for _ in 0..6 {
        let mut a = [[0.0f64; 3]; 3];
        let mut g = [0.0f64; 3];
        for &(r, w, acc) in pts.iter() {
            let e = r - x[0] - x[1] * w - x[2] * acc;
            let wt = if scale.is_finite() && e.abs() > 2.0 * scale {
                2.0 * scale / e.abs()
            } else {
                1.0
            };
            let row = [1.0, w, acc];
            for i in 0..3 {
                g[i] += wt * row[i] * r;
                for j in 0..3 {
                    a[i][j] += wt * row[i] * row[j];
                }
            }
        }
        // Noise per block for the prior's weight (first pass: a guess of 2 mN·m).
        let s2 = if scale.is_finite() {
            scale * scale
        } else {
            4e-6
        };
        if prior_on {
            let wp = s2 / (prior.sigma_inertia_kgm2 * prior.sigma_inertia_kgm2);
            a[2][2] += wp;
            g[2] += wp * prior.inertia_kgm2;
        }
        // Tiny ridge on the viscous term: a constant-speed approach cannot separate it from
        // the offset.
        a[1][1] += 1e-9 * (a[0][0] + 1.0);
        let inv = inv3(&a)?;
        for i in 0..3 {
            x[i] = (0..3).map(|j| inv[i][j] * g[j]).sum();
        }
        if x[2] < 0.0 {
            // Inertia ≥ 0: refit the other two with it at zero.
            x[2] = 0.0;
            let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
            if !(det.abs() > 0.0) {
                return None;
            }
            x[0] = (a[1][1] * g[0] - a[0][1] * g[1]) / det;
            x[1] = (a[0][0] * g[1] - a[1][0] * g[0]) / det;
        }
        let res = pts
            .iter()
            .map(|&(r, w, acc)| r - x[0] - x[1] * w - x[2] * acc);
        scale = mad_sigma(res).max(1e-5);
        cov_jj = inv[2][2] * scale * scale;
    }
    Some(DriveId {
        inertia_kgm2: x[2],
        sigma_inertia_kgm2: <f64 as pts::Real>::sqrt(cov_jj.max(0.0)),
        viscous_nm_s_per_rad: x[1],
        offset_nm: x[0],
        noise_nm: scale,
        blocks: pts.len() as u32,
        accel_span_rad_s2: amax - amin,
    })
}

/// 1.4826 × the median absolute value (≈ σ for Gaussian noise); over up to 1024 values.
fn mad_sigma(vals: impl Iterator<Item = f64>) -> f64 {
    let mut buf: Vec<f64, 1024> = Vec::new();
    for v in vals {
        if v.is_finite() {
            let _ = buf.push(v.abs());
        }
    }
    if buf.is_empty() {
        return f64::NAN;
    }
    buf.sort_unstable_by(|a, b| a.partial_cmp(b).unwrap_or(core::cmp::Ordering::Equal));
    let n = buf.len();
    let m = 0.5
        * (buf.get((n - 1) / 2).copied().unwrap_or(0.0) + buf.get(n / 2).copied().unwrap_or(0.0));
    1.4826 * m
}

fn inv3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if !(det.abs() > 0.0) || !det.is_finite() {
        return None;
    }
    let c = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]
    };
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = c(j, i) / det;
        }
    }
    Some(m)
}

/// The contact point on the dynamics-corrected residual: with the drive identified
/// ([`identify_drive`]), e = T_a − T_free(θa) − offset − viscous·θ̇a − inertia·θ̈a is noise in
/// free motion and (K_c − K_free)(θa − θa,c) once the object is touched, whatever the crank's
/// speed, its ringing before or its bounce after the impact. θa,c is the hinge of that line
/// (least squares over a 0.1 mrad grid within 15 mrad before the detection), fitted on the
/// moving blocks from a free-motion window before the knee up to 8 mrad past it.
/// Returns (θa,c rad, T_a,c = T_free(θa,c) + offset N·m, trace time of θa,c s).
pub fn refine_contact<R: pts::Real>(
    model: &Model<R>,
    cfg: &OfflineConfig,
    blocks: &[Block],
    seg: &Segment,
    id: &DriveId,
    quantum_rad: f64,
) -> Option<(f64, f64, f64)> {
    const S: usize = 2;
    let t_free = |th: f64| -> Option<f64> {
        model
            .free_from_theta_a(R::try_from_f64(th)?)
            .ok()
            .map(|c| c.ta.to_f64())
    };
    let wf = cfg.free_window.clamp(4, 64);
    let lo = seg.knee.saturating_sub(2 * wf).max(S);
    let th_det = blocks.get(seg.detect)?.theta_a_rad;
    let th_top = th_det.max(seg.theta_a_c_rad) + 8e-3;
    let still = 0.5 * quantum_rad.max(1e-9);
    // (θ, e) per usable block.
    let mut pts: Vec<(f64, f64), 512> = Vec::new();
    let mut k = lo;
    while k + S < blocks.len() && pts.len() < 512 {
        let (a, b, c) = (blocks.get(k - S)?, blocks.get(k)?, blocks.get(k + S)?);
        k += 1;
        if k > seg.detect + 200 || b.theta_a_rad > th_top {
            if k > seg.detect {
                break;
            }
            continue;
        }
        if (c.theta_a_rad - a.theta_a_rad).abs() <= still {
            continue;
        }
        let (d1, d2) = (b.t_s - a.t_s, c.t_s - b.t_s);
        if !(d1 > 0.0 && d2 > 0.0) {
            continue;
        }
        let v1 = (b.theta_a_rad - a.theta_a_rad) / d1;
        let v2 = (c.theta_a_rad - b.theta_a_rad) / d2;
        let w = (c.theta_a_rad - a.theta_a_rad) / (d1 + d2);
        let acc = 2.0 * (v2 - v1) / (d1 + d2);
        let e = b.torque_nm
            - t_free(b.theta_a_rad)?
            - id.offset_nm
            - id.viscous_nm_s_per_rad * w
            - id.inertia_kgm2 * acc;
        if e.is_finite() {
            let _ = pts.push((b.theta_a_rad, e));
        }
    }
    if pts.len() < 8 {
        return None;
    }
    let scale = id.noise_nm.max(1e-4);
    // Hinge plus a step: past θa,c the residual is (K_c − K_free)(θa − θa,c) plus what the
    // transmission's stiction holds once the crank stops on the object (≥ 0); without the
    // step that excess right after the contact drags the hinge early.
    let sse_at = |thc: f64| -> f64 {
        let (mut seh, mut shh, mut seu, mut shu, mut suu) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(th, e) in pts.iter() {
            let h = (th - thc).max(0.0);
            let u = if th > thc { 1.0 } else { 0.0 };
            seh += e * h;
            shh += h * h;
            seu += e * u;
            shu += h * u;
            suu += u * u;
        }
        let det = shh * suu - shu * shu;
        let (mut sl, mut d) = if det > 1e-30 {
            ((seh * suu - seu * shu) / det, (seu * shh - seh * shu) / det)
        } else {
            (0.0, 0.0)
        };
        if d < 0.0 || sl < 0.0 {
            d = 0.0;
            sl = if shh > 0.0 { (seh / shh).max(0.0) } else { 0.0 };
        }
        // Huber loss at 3 σ: a lone spike must not move the hinge.
        pts.iter()
            .map(|&(th, e)| {
                let u = if th > thc { d } else { 0.0 };
                let r = (e - sl * (th - thc).max(0.0) - u).abs();
                if r <= 3.0 * scale {
                    r * r
                } else {
                    3.0 * scale * (2.0 * r - 3.0 * scale)
                }
            })
            .sum()
    };
    let hi = th_det;
    let mut best = (f64::INFINITY, hi);
    let mut thc = hi - 15e-3;
    while thc <= hi {
        let v = sse_at(thc);
        if v < best.0 {
            best = (v, thc);
        }
        thc += 1e-4;
    }
    let thc = best.1;
    let ta_c = t_free(thc)? + id.offset_nm;
    let t_c = blocks
        .iter()
        .skip(lo)
        .find(|b| b.theta_a_rad >= thc)
        .map_or(seg.contact_t_s, |b| b.t_s);
    Some((thc, ta_c, t_c))
}

/// The firmware's integer path fit on a segmented request with the contact point and the
/// path-fit configuration given by the caller (the host's per-recording identification),
/// instead of the controller's defaults and back-dating. `table` must be built for the
/// caller's configuration and the request's period; σ is graded against the table's l2 as the
/// controller's estimate does. Returns the result with σ(k2,c) (m) of a distal answer; a proximal path is reported as [`Located::Proximal`](crate::Located).
pub fn path_fit_with(
    table: &pathfit::q::PathTable,
    req: &EstimateRequest,
    theta_a_c_rad: f64,
    ta_c_nm: f64,
) -> Result<(crate::EstimateResult, Option<f64>), pathfit::PathFitError> {
    crate::estimate::path_fit_q_at(table, req, theta_a_c_rad, ta_c_nm)
}
