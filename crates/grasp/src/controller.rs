//! The grasp state machine ([`Supervisor`], one step per finished sample) and the
//! [`Controller`] that ticks it together with the [`ControlLoop`] for host runs. Integer
//! arithmetic only.
//!
//! Calibrate (bridge off, current offset) → Approach (torque reference ramps up, the finger
//! closes quasi-statically) → contact detected (the stiffness ΔT_ref/Δθa over a window rises
//! above a threshold) → Seating (the impact comes to rest; the reference rises until the
//! drive slides forward again, then two static loading points) → Step (reference raised to
//! T_a,c + ΔT_a, step or ramp) → Settling (θa still) → Estimating (an [`EstimateRequest`] waits for [`run_estimate`](crate::run_estimate)) →
//! Holding or Releasing → Done. Any fault → [`State::Fault`] with the bridge off.
//!
//! Why the static points come after a forward slide: the transmission's friction holds the
//! finger wherever the impact leaves it, with any friction torque inside its stiction band, so
//! the impact's rest point is not a static point of the model. Points reached by sliding
//! forward carry the sliding friction the approach carried too; with loading points only, the
//! Coulomb term is the same at the contact (back-dated onto the approach's shifted free-motion
//! curve) and at the end point, and cancels in ΔT_a.
#![deny(clippy::float_arithmetic)]

use heapless::{Deque, Vec};
use pathfit::PathFitError;
use pts::PtsError;

use crate::config::{AfterEstimate, ConfigError, ControllerConfig, FingerRest, Params, HISTORY};
use crate::control_loop::{ControlLoop, Input, Link, Reference, SampleSums, Setpoint, TorqueQ16};
use crate::estimate::{EstimateError, EstimateRequest, EstimateResult, Sample, PATH_CAPACITY};
use crate::sensors::sat_i32;
use crate::state::{Event, FaultReason, State};
use crate::{Hardware, DUTY_MAX};

/// Events queued for logging (oldest dropped first is NOT done: new events are dropped
/// and counted when the queue is full, so the first fault is never lost).
pub const EVENT_CAPACITY: usize = 16;

/// A settled step's torque may miss its reference by ΔT_a over this (the loop's tracking at
/// rest is far tighter; a drive that cannot follow misses by a large share of ΔT_a).
const DELIVERED_SHARE: i32 = 20;
/// ... and by at least this much (µN·m): a few ADC codes of torque.
const DELIVERED_MIN_UNM: i64 = 5_000;

/// What one tick did (for telemetry and the application).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickOutput {
    /// State after the tick.
    pub state: State,
    /// θa (µrad), absolute model angle.
    pub theta_a_urad: i32,
    /// Measured T_a (µN·m), one sample.
    pub torque_unm: i32,
    /// Torque reference (µN·m).
    pub torque_ref_unm: i32,
    /// Duty applied (±DUTY_MAX), 0 with the bridge off.
    pub duty: i16,
    /// True on the tick the estimate request became available ([`Controller::take_request`]).
    pub estimate_ready: bool,
}

/// A fixed-capacity ring of the most recent samples.
#[derive(Clone, Debug)]
struct Ring {
    buf: [Sample; HISTORY],
    head: usize,
    len: usize,
}

impl Ring {
    const fn new() -> Self {
        Self {
            buf: [Sample::ZERO; HISTORY],
            head: 0,
            len: 0,
        }
    }
    fn push(&mut self, s: Sample) {
        if let Some(slot) = self.buf.get_mut(self.head) {
            *slot = s;
        }
        self.head = (self.head + 1) % HISTORY;
        self.len = (self.len + 1).min(HISTORY);
    }
    /// `back(0)` is the newest.
    fn back(&self, i: usize) -> Option<Sample> {
        if i >= self.len {
            return None;
        }
        let idx = (self.head + HISTORY - 1 - i) % HISTORY;
        self.buf.get(idx).copied()
    }
}

/// The grasp controller for single-threaded use (host runs, tests, the tool): the
/// [`ControlLoop`] and the [`Supervisor`] joined by their [`Link`], ticked together.
///
/// [`Controller::tick`] runs the loop, then the supervisor on whatever the loop handed
/// over; the supervisor's setpoint takes effect from the next tick — exactly what the
/// firmware does with the two halves in two tasks ([`Controller::into_parts`]), so host and
/// target give the same numbers. (One exception: a fault or the end of a release switches
/// the bridge off in the same tick here, one period earlier than on the target.) Holds no floating-point state; see the crate docs.
#[derive(Clone, Debug)]
pub struct Controller {
    lp: ControlLoop,
    link: Link,
    sup: Supervisor,
}

impl Controller {
    /// Builds a controller; the configuration is checked and converted once here
    /// (the only floating-point work of the crate outside the estimator).
    pub fn new(cfg: ControllerConfig) -> Result<Self, ConfigError> {
        let p = cfg.params()?;
        Ok(Self::from_params(p))
    }

    /// [`Controller::new`] with the finger's part of the check already done
    /// ([`ControllerConfig::params_for`]).
    pub fn new_for(cfg: ControllerConfig, rest: &FingerRest) -> Result<Self, ConfigError> {
        let p = cfg.params_for(rest)?;
        Ok(Self::from_params(p))
    }

    /// Builds a controller from already converted parameters (no float at all).
    pub fn from_params(p: Params) -> Self {
        Self {
            lp: ControlLoop::new(&p),
            link: Link::new(),
            sup: Supervisor::new(&p),
        }
    }

    /// The two halves and their mailbox, for running them in two tasks: the loop at the
    /// sampling rate, the supervisor (and [`Supervisor::take_request`] /
    /// [`Supervisor::deliver`]) below it.
    pub fn into_parts(self) -> (ControlLoop, Link, Supervisor) {
        (self.lp, self.link, self.sup)
    }

    /// The integer parameters in use.
    pub fn params(&self) -> &Params {
        &self.sup.p
    }

    /// Current state.
    pub fn state(&self) -> State {
        self.sup.state()
    }

    /// Ticks since start.
    pub fn ticks(&self) -> u32 {
        self.lp.ticks()
    }

    /// What the rest check found ([`ControlLoop::rest_report`]).
    pub fn rest_report(&self) -> Option<crate::rest::RestReport> {
        self.lp.rest_report()
    }

    /// The delivered estimate, once there is one.
    pub fn result(&self) -> Option<&EstimateResult> {
        self.sup.result()
    }

    /// Next queued event, oldest first.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.sup.poll_event()
    }

    /// Events dropped because the queue was full.
    pub fn events_dropped(&self) -> u32 {
        self.sup.events_dropped()
    }

    /// Torque reference (µN·m).
    pub fn torque_ref_unm(&self) -> i32 {
        self.lp.torque_ref_unm()
    }

    /// Forces the safe state from outside (e.g. an application watchdog), with a reason:
    /// bridge off now.
    pub fn abort<H: Hardware + ?Sized>(&mut self, hw: &mut H, reason: FaultReason) {
        self.sup.abort(reason);
        self.sup.publish(&mut self.link);
        self.lp.stop(hw);
    }

    /// Lets go of a held object ([`Supervisor::release`]); returns whether it started.
    pub fn release(&mut self) -> bool {
        let started = self.sup.release();
        self.sup.publish(&mut self.link);
        started
    }

    /// Moves the estimate request out, once, after a tick reported `estimate_ready`.
    /// Hand it to [`run_estimate`](crate::run_estimate) in a low-priority task.
    pub fn take_request(&mut self) -> Option<EstimateRequest> {
        self.sup.take_request()
    }

    /// Gives the estimate back. A refused estimate puts the controller in the safe state
    /// (bridge off now); ignored unless the controller is waiting for it.
    pub fn deliver<H: Hardware + ?Sized>(
        &mut self,
        hw: &mut H,
        outcome: Result<EstimateResult, EstimateError>,
    ) {
        self.sup.deliver(outcome);
        self.sup.publish(&mut self.link);
        if !self.link.setpoint.enable {
            self.lp.stop(hw);
        }
    }

    /// One control period: the loop's tick, then the supervisor on what it handed over.
    pub fn tick<H: Hardware + ?Sized>(&mut self, hw: &mut H) -> TickOutput {
        let mut o = self.lp.tick(hw, &mut self.link);
        let estimate_ready = self.sup.service(&mut self.link);
        if !self.link.setpoint.enable && self.lp.driving() {
            // A fault or the end found by the state machine: bridge off within this tick
            // (on the target the loop applies it at its next tick, ≤ one period later).
            self.lp.stop(hw);
            o.duty = 0;
            o.torque_ref_unm = 0;
        }
        TickOutput {
            state: self.sup.state(),
            theta_a_urad: o.theta_a_urad,
            torque_unm: o.torque_unm,
            torque_ref_unm: o.torque_ref_unm,
            duty: o.duty,
            estimate_ready,
        }
    }
}

/// The contact as the detection found it; every state after it carries it.
#[derive(Clone, Copy, Debug)]
struct Contact {
    /// T_a,c on the free-motion line at the θa of the detection (see [`knee`]): the base of
    /// the seating targets, of the step and of the loss-of-contact check.
    knee: Sample,
    /// Tick of the detection (the settle timeout runs from it).
    tick: u32,
}

/// The two loading points, with the contact they were loaded from: what the step, the
/// settling, the estimate and the hold need.
#[derive(Clone, Copy, Debug)]
struct Loaded {
    contact: Contact,
    /// First loading point, after the forward slide.
    seat: Sample,
    /// Second loading point, halfway from the first to T_a,c + ΔT_a.
    seat2: Sample,
    /// Without seating, the step's settled end once it has settled (`seat` until then): with
    /// `seat` the one pair of static points such a step has, which the loss-of-contact check
    /// reads. Unused when seating.
    settled: Sample,
}

impl Loaded {
    /// Stiffness (µN·m/rad) of the second half of the step, seated again → `end`. A second
    /// contact shows there.
    fn kc_late_unm_per_rad(&self, end: &Sample) -> i32 {
        stiffness(&self.seat2, end)
    }
}

/// Where seating is (the `stage` of [`Event::Seated`]).
#[derive(Clone, Copy, Debug)]
enum Seat {
    /// Stage 0: held at T_a,c + δ_seat while the impact dies out.
    Impact,
    /// Stage 1: ramping from `rest`, where the impact came to rest (held by stiction anywhere
    /// in its band: not used by the estimate, only as the reference for the forward slide),
    /// until the drive slides forward (`slid`); then held for the first loading point.
    Slide { rest: Sample, slid: bool },
    /// Stage 2: the first loading point taken; held halfway to the step's target.
    Second { seat: Sample },
}

impl Seat {
    const fn stage(&self) -> u8 {
        match self {
            Seat::Impact => 0,
            Seat::Slide { .. } => 1,
            Seat::Second { .. } => 2,
        }
    }
}

/// The state machine's state with what that state alone needs; [`Phase::state`] is what the
/// outside sees.
#[derive(Clone, Copy, Debug)]
enum Phase {
    Init,
    Calibrating,
    Approach {
        /// Free motion has been seen: from now on a stiff window means contact.
        armed: bool,
        /// Stiff windows in a row.
        stiff_count: u32,
    },
    Seating {
        contact: Contact,
        seat: Seat,
        /// Where the reference goes (µN·m).
        target_unm: i32,
        /// Start of this stage's wait (tick).
        since: u32,
    },
    Step {
        loaded: Loaded,
        /// T_a,c + ΔT_a (µN·m).
        target_unm: i32,
    },
    Settling {
        loaded: Loaded,
        /// Tick the reference reached its target.
        since: u32,
    },
    Estimating {
        loaded: Loaded,
        /// The settled end point.
        end: Sample,
        /// Tick of the settling (the estimate timeout runs from it).
        since: u32,
        /// The request is ready and not yet taken.
        request_ready: bool,
    },
    Holding {
        loaded: Loaded,
    },
    /// Without seating, after an estimate that refused or did not locate a distal contact:
    /// the reference rises a further half step from the settled end (then to a whole step if
    /// the finger did not move at all), to tell a finger locked by a second contact (which
    /// barely moves) from a path the fit could not read or a proximal contact. The answer, if
    /// any, is reported only once the probe has decided.
    Probing {
        loaded: Loaded,
        /// The settled end point of the step.
        end: Sample,
        /// Where the reference goes (µN·m).
        target_unm: i32,
        /// Tick the reference reached the target (settling since), `None` while ramping.
        reached: Option<u32>,
    },
    Releasing,
    Opening {
        /// Tick the opening started.
        since: u32,
    },
    Done,
    Fault(FaultReason),
}

impl Phase {
    const fn state(&self) -> State {
        match self {
            Phase::Init => State::Init,
            Phase::Calibrating => State::Calibrating,
            Phase::Approach { .. } => State::Approach,
            Phase::Seating { .. } => State::Seating,
            Phase::Step { .. } => State::Step,
            Phase::Settling { .. } => State::Settling,
            Phase::Estimating { .. } => State::Estimating,
            Phase::Holding { .. } => State::Holding,
            Phase::Probing { reached: None, .. } => State::Step,
            Phase::Probing { .. } => State::Settling,
            Phase::Releasing => State::Releasing,
            Phase::Opening { .. } => State::Opening,
            Phase::Done => State::Done,
            Phase::Fault(r) => State::Fault(*r),
        }
    }

    /// The bridge drives in these states.
    const fn drives(&self) -> bool {
        matches!(
            self,
            Phase::Approach { .. }
                | Phase::Seating { .. }
                | Phase::Step { .. }
                | Phase::Settling { .. }
                | Phase::Estimating { .. }
                | Phase::Holding { .. }
                | Phase::Probing { .. }
                | Phase::Releasing
                | Phase::Opening { .. }
        )
    }
}

/// The path samples from contact to the end point for the estimator: every `stride`-th
/// sample; when full, every other one is dropped and the stride doubles, so the whole span
/// fits.
#[derive(Clone, Debug)]
struct PathRecord {
    samples: Vec<Sample, PATH_CAPACITY>,
    stride: u32,
    /// Samples still to skip before the next one is kept.
    skip: u32,
}

impl PathRecord {
    const fn new() -> Self {
        Self {
            samples: Vec::new(),
            stride: 1,
            skip: 0,
        }
    }

    fn clear(&mut self) {
        *self = Self::new();
    }

    fn push(&mut self, s: Sample) {
        if self.skip > 0 {
            self.skip -= 1;
            return;
        }
        if self.samples.is_full() {
            let mut j = 0;
            for i in (0..self.samples.len()).step_by(2) {
                if let Some(v) = self.samples.get(i).copied() {
                    if let Some(slot) = self.samples.get_mut(j) {
                        *slot = v;
                    }
                    j += 1;
                }
            }
            self.samples.truncate(j);
            self.stride = self.stride.saturating_mul(2);
        }
        let _ = self.samples.push(s);
        self.skip = self.stride.saturating_sub(1);
    }
}

/// The encoder's plausibility check against the motor's back-EMF, once per sample.
#[derive(Clone, Copy, Debug)]
struct EmfCheck {
    /// Encoder count at the end of the previous sample.
    last_counts: i32,
    /// Mismatched samples in a row.
    bad: u32,
}

impl EmfCheck {
    /// The fault once the back-EMF from the bridge voltage (mean `duty`) and the mean current
    /// `ua` (µA) has disagreed with the encoder's speed for too many samples in a row.
    fn check(&mut self, p: &Params, counts: i32, duty: i64, ua: i64) -> Option<FaultReason> {
        let dcounts = i64::from(counts) - i64::from(self.last_counts);
        self.last_counts = counts;
        let v_uv = duty
            .saturating_mul(p.bus_uv)
            .checked_div(i64::from(DUTY_MAX))
            .unwrap_or(0);
        let ri_uv = ua.saturating_mul(p.r_mohm) / 1000;
        let emf_uv = v_uv.saturating_sub(ri_uv);
        let enc_uv = dcounts.saturating_mul(p.emf_uv_per_count_q16) >> 16;
        if emf_uv.saturating_sub(enc_uv).saturating_abs() > p.emf_mismatch_uv {
            self.bad = self.bad.saturating_add(1);
        } else {
            self.bad = 0;
        }
        if self.bad >= p.emf_mismatch_samples {
            Some(FaultReason::EncoderMismatch {
                emf_mv: sat_i32(emf_uv / 1000),
                encoder_emf_mv: sat_i32(enc_uv / 1000),
            })
        } else {
            None
        }
    }
}

/// The grasp state machine: the slow half of the controller, one step per finished
/// sample (every `sample_ticks` ticks), fed through the [`Link`] by the [`ControlLoop`] and
/// answering with a [`Setpoint`]. On the target it runs in a task below the sampling task.
#[derive(Clone, Debug)]
pub struct Supervisor {
    p: Params,
    phase: Phase,
    /// Tick of the newest input (the loop's tick count).
    tick: u32,
    /// Torque reference at the end of the newest sample (µN·m).
    t_ref_unm: i32,
    /// A jump of the reference the loop applies until the next sample (µN·m ×2¹⁶).
    jump_q16: Option<i64>,
    /// Actuator speed estimate, µrad per sample (over the last two samples).
    vel: i32,
    /// θa of the last two samples (µrad), newest first.
    theta_prev: [Option<i32>; 2],
    /// Damping term for the loop (µN·m).
    damp_unm: i32,
    hist: Ring,
    /// The history before the contact, oldest first, for the estimator.
    pre: Vec<Sample, HISTORY>,
    path: PathRecord,
    emf: EmfCheck,
    result: Option<EstimateResult>,
    /// The estimate's outcome while [`Phase::Probing`] decides whether it stands (kept out of
    /// the phase, which every state carries).
    probed: Option<Result<EstimateResult, EstimateError>>,
    events: Deque<Event, EVENT_CAPACITY>,
    events_dropped: u32,
    /// A fault found inside a sample step; applied at its end.
    pending: Option<FaultReason>,
}

/// Secant stiffness between two static points, (T_b − T_a)/(θ_b − θ_a) (µN·m/rad),
/// saturating; `i32::MAX` when θa did not advance.
fn stiffness(a: &Sample, b: &Sample) -> i32 {
    let dt = i64::from(b.torque_unm) - i64::from(a.torque_unm);
    let dth = i64::from(b.theta_a_urad) - i64::from(a.theta_a_urad);
    if dth <= 0 {
        return i32::MAX;
    }
    sat_i32(
        dt.saturating_mul(1_000_000)
            .checked_div(dth)
            .unwrap_or(i64::MAX),
    )
}

/// Secant from `a` to `b` (µN·m) scaled onto the θa travel `ext` (µrad) as a fraction of
/// `dth_ab`: the line's torque rise over `ext`.
fn line_rise(dt_ab: i64, dth_ab: i64, ext: i64) -> i64 {
    dt_ab.saturating_mul(ext).checked_div(dth_ab).unwrap_or(0)
}

/// The contact point the seating and the step are based on, at the detection of sample `s`
/// with window `w`: the finger's inertia carries it past the contact point before the
/// stiffness shows, so T_a,c is taken on the free-motion line (the samples 3w and up to 7w
/// back, well before the window) at the θa of the detection, clamped between that line's
/// start and the measured torque: the bias is K_free × the overshoot (a few mN·m). The
/// estimator back-dates precisely from static points (`estimate::contact_point`).
fn knee(hist: &Ring, s: Sample, w: usize) -> Sample {
    let w3 = 3 * w;
    let a = hist.back(w3).unwrap_or(s);
    let b = hist
        .back(hist.len.saturating_sub(1).min(w3 + 4 * w))
        .unwrap_or(a);
    let dth_ab = i64::from(a.theta_a_urad) - i64::from(b.theta_a_urad);
    let dt_ab = i64::from(a.torque_unm) - i64::from(b.torque_unm);
    let ext = (i64::from(s.theta_a_urad) - i64::from(a.theta_a_urad)).max(0);
    let rise_max = i64::from(s.torque_unm.saturating_sub(a.torque_unm)).max(0);
    let tc = i64::from(a.torque_unm) + line_rise(dt_ab, dth_ab, ext).clamp(0, rise_max);
    Sample {
        tick: a.tick,
        theta_a_urad: s.theta_a_urad,
        torque_unm: sat_i32(tc),
        torque_ref_unm: s.torque_ref_unm,
    }
}

/// The free motion before a contact: the parabola in time through three samples `h` ticks
/// apart (`a` newest), θ(t) = θa + (c1·τ·h + c2·τ²)/(2h²), τ = t − t_a (ticks; sample labels).
#[derive(Clone, Copy, Debug)]
struct FreeParabola {
    ta: i64,
    tha: i64,
    h: i64,
    c1: i64,
    c2: i64,
}

impl FreeParabola {
    /// Through `a`, `m`, `b`, newest first; `None` unless they are equally spaced in time.
    fn through(a: &Sample, m: &Sample, b: &Sample) -> Option<Self> {
        let (ta, tm, tb) = (i64::from(a.tick), i64::from(m.tick), i64::from(b.tick));
        let h = ta - tm;
        if h <= 0 || tm - tb != h {
            return None;
        }
        let (tha, thm, thb) = (
            i64::from(a.theta_a_urad),
            i64::from(m.theta_a_urad),
            i64::from(b.theta_a_urad),
        );
        Some(Self {
            ta,
            tha,
            h,
            c1: 3 * tha - 4 * thm + thb,
            c2: tha - 2 * thm + thb,
        })
    }

    /// θa on the parabola at tick `t` (µrad).
    fn at(&self, t: i64) -> i64 {
        let tau = t - self.ta;
        self.tha.saturating_add(
            self.c1
                .saturating_mul(tau)
                .saturating_mul(self.h)
                .saturating_add(self.c2.saturating_mul(tau).saturating_mul(tau))
                .checked_div(2 * self.h * self.h)
                .unwrap_or(0),
        )
    }

    /// How far `s` lags behind the free motion (µrad).
    fn deficit(&self, s: &Sample) -> i64 {
        self.at(i64::from(s.tick)) - i64::from(s.theta_a_urad)
    }
}

/// The tick (sample labels, interpolated) at which the deficit behind `free` last rose
/// through `level`, searching the newest `span` samples; `None` when it did not within them.
fn deficit_crossing(hist: &Ring, free: &FreeParabola, level: i64, span: usize) -> Option<i64> {
    let mut hi = hist.back(0)?;
    let mut i = 0usize;
    loop {
        if i + 1 >= span {
            return None;
        }
        let lo = hist.back(i + 1)?;
        let dl = free.deficit(&lo);
        if dl < level {
            let dh = free.deficit(&hi);
            let (tl, th) = (i64::from(lo.tick), i64::from(hi.tick));
            return Some(
                tl + (level - dl)
                    .saturating_mul(th - tl)
                    .checked_div(dh - dl)
                    .unwrap_or(0),
            );
        }
        hi = lo;
        i += 1;
    }
}

/// The contact instant, from the impact's signature: after the contact the finger
/// decelerates on the contact stiffness, so θa falls behind its free-motion trajectory
/// by a deficit that grows as (t − t_c)³ at first (J θ̈ = −K v (t − t_c)). The free
/// motion is the parabola in time through the samples 2w, 3w and 4w back (before any
/// contact the detection can see: its delay is below 2w samples; the approach speed
/// still creeps, so a line would not do). With d_n the deficit of the newest sample
/// (t_n) and t_1 the time it crossed d_n/8, t_c = 2·t_1 − t_n. θa,c on the free-motion
/// parabola and T_a,c (measured, friction included) on the line through the 2w and 4w
/// samples, at t_c. `None` when the deficit is too small to time (< 4 encoder counts and
/// < 8 µrad). Sample ticks label the end of their `sample_ticks`-long interval.
fn contact_instant(
    hist: &Ring,
    w: usize,
    sample_ticks: u32,
    urad_per_count_q16: i32,
) -> Option<Sample> {
    let half = i64::from(sample_ticks / 2);
    let newest = hist.back(0)?;
    let a = hist.back(2 * w)?;
    let b = hist.back(4 * w)?;
    let free = FreeParabola::through(&a, &hist.back(3 * w)?, &b)?;
    let dn = free.deficit(&newest);
    let min = (i64::from(urad_per_count_q16) * 4) >> 16;
    if dn < min.max(8) {
        return None;
    }
    let t1 = deficit_crossing(hist, &free, dn / 8, 2 * w)?;
    // Sample labels are the interval's end: the averages sit `half` earlier.
    let (ta, tb, tn) = (i64::from(a.tick), i64::from(b.tick), i64::from(newest.tick));
    // (max/min, not clamp: clamp asserts its bounds are ordered.)
    let tc = (2 * t1 - tn - half).max(ta - half).min(tn);
    let label = tc + half;
    let (qa, qb) = (i64::from(a.torque_unm), i64::from(b.torque_unm));
    let tq = qa.saturating_add(
        (qa - qb)
            .saturating_mul(label - ta)
            .checked_div(ta - tb)
            .unwrap_or(0),
    );
    Some(Sample {
        tick: u32::try_from(tc).ok()?,
        theta_a_urad: sat_i32(free.at(label)),
        torque_unm: sat_i32(tq),
        torque_ref_unm: newest.torque_ref_unm,
    })
}

/// Mean (θa, T_a) (µrad, µN·m) of the newest `window` samples when θa stayed within
/// `band_urad` over them and every one is labelled at or after `since`.
fn still_mean(hist: &Ring, since: u32, window: usize, band_urad: i32) -> Option<(i32, i32)> {
    let mut lo = i32::MAX;
    let mut hi = i32::MIN;
    let mut st = 0i64;
    let mut sth = 0i64;
    for i in 0..window {
        let s = hist.back(i)?;
        if s.tick < since {
            return None;
        }
        lo = lo.min(s.theta_a_urad);
        hi = hi.max(s.theta_a_urad);
        st += i64::from(s.torque_unm);
        sth += i64::from(s.theta_a_urad);
    }
    if i64::from(hi) - i64::from(lo) > i64::from(band_urad) {
        return None;
    }
    let n = window as i64;
    Some((
        sat_i32(sth.checked_div(n).unwrap_or(0)),
        sat_i32(st.checked_div(n).unwrap_or(0)),
    ))
}

impl Supervisor {
    /// A state machine before the loop has started.
    pub fn new(p: &Params) -> Self {
        Self {
            p: *p,
            phase: Phase::Init,
            tick: 0,
            t_ref_unm: 0,
            jump_q16: None,
            vel: 0,
            theta_prev: [None, None],
            damp_unm: 0,
            hist: Ring::new(),
            pre: Vec::new(),
            path: PathRecord::new(),
            emf: EmfCheck {
                last_counts: 0,
                bad: 0,
            },
            result: None,
            probed: None,
            events: Deque::new(),
            events_dropped: 0,
            pending: None,
        }
    }

    /// Current state.
    pub fn state(&self) -> State {
        self.phase.state()
    }

    /// The delivered estimate, once there is one.
    pub fn result(&self) -> Option<&EstimateResult> {
        self.result.as_ref()
    }

    /// Next queued event, oldest first.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// Events dropped because the queue was full.
    pub fn events_dropped(&self) -> u32 {
        self.events_dropped
    }

    fn emit(&mut self, e: Event) {
        if self.events.push_back(e).is_err() {
            self.events_dropped = self.events_dropped.saturating_add(1);
        }
    }

    fn fault(&mut self, reason: FaultReason) {
        if !matches!(self.phase, Phase::Fault(_)) {
            self.phase = Phase::Fault(reason);
            let tick = self.tick;
            self.emit(Event::Fault { tick, reason });
        }
    }

    /// Forces the safe state (the loop switches the bridge off once the setpoint reaches it).
    pub fn abort(&mut self, reason: FaultReason) {
        self.fault(reason);
    }

    /// What the loop should do until the next sample.
    pub fn setpoint(&self) -> Setpoint {
        let p = &self.p;
        let reference = match self.phase {
            // The ramp pauses while the actuator is at its approach speed limit; it stops
            // just above the ceiling, where the approach gives up (NoContact).
            Phase::Approach { .. } if self.vel < p.approach_vmax_urad => Reference::Ramp {
                target: TorqueQ16::from_unm(p.approach_max_unm.saturating_add(1)),
                rate: TorqueQ16::new(p.approach_ramp_q16),
            },
            // Stage 1 always ramps: the slide must be seen before the reference stops.
            Phase::Seating {
                seat: Seat::Slide { .. },
                target_unm,
                ..
            } => self.toward(target_unm, p.seat_ramp_q16),
            Phase::Seating { target_unm, .. }
            | Phase::Step { target_unm, .. }
            | Phase::Probing { target_unm, .. } => self.toward(target_unm, p.step_ramp_q16),
            Phase::Releasing => Reference::Ramp {
                target: TorqueQ16::new(0),
                rate: TorqueQ16::new(p.release_ramp_q16),
            },
            Phase::Opening { .. } => Reference::Ramp {
                target: TorqueQ16::from_unm(-p.open_unm),
                rate: TorqueQ16::new(p.release_ramp_q16),
            },
            _ => Reference::Hold,
        };
        if !self.phase.drives() {
            return Setpoint::OFF;
        }
        Setpoint {
            enable: true,
            reference,
            damp_unm: self.damp_unm,
        }
    }

    /// The reference toward `target_unm` (µN·m) at `rate_q16` (a step when not positive),
    /// unless a jump is pending.
    fn toward(&self, target_unm: i32, rate_q16: i64) -> Reference {
        if let Some(v) = self.jump_q16 {
            return Reference::Set(TorqueQ16::new(v));
        }
        let target = TorqueQ16::from_unm(target_unm);
        if rate_q16 <= 0 {
            Reference::Set(target)
        } else {
            Reference::Ramp {
                target,
                rate: TorqueQ16::new(rate_q16),
            }
        }
    }

    /// Writes the setpoint and the state into the link, stamped with the newest loop tick
    /// this supervisor has acted on (its heartbeat: the loop refuses an old setpoint).
    pub fn publish(&self, link: &mut Link) {
        link.setpoint = self.setpoint();
        link.state = self.state();
        link.stamp(self.tick);
    }

    /// Handles everything the loop left in the link and publishes the answer. Returns true
    /// when the estimate request became ready ([`Supervisor::take_request`]).
    pub fn service(&mut self, link: &mut Link) -> bool {
        let mut ready = false;
        while let Some(input) = link.next_input() {
            ready |= self.handle(input);
        }
        self.publish(link);
        ready
    }

    /// One input from the loop. Returns true when the estimate request became ready.
    pub fn handle(&mut self, input: Input) -> bool {
        match input {
            Input::Started => {
                if matches!(self.phase, Phase::Init) {
                    self.phase = Phase::Calibrating;
                }
                false
            }
            Input::Calibrated { tick, offset_q8 } => {
                self.tick = tick;
                if matches!(self.phase, Phase::Init | Phase::Calibrating) {
                    self.phase = Phase::Approach {
                        armed: false,
                        stiff_count: 0,
                    };
                    self.emit(Event::Calibrated { tick, offset_q8 });
                }
                false
            }
            Input::LoopFault { tick, reason } => {
                self.tick = tick;
                self.fault(reason);
                false
            }
            Input::Sample(m) => self.on_sums(m),
        }
    }

    /// One finished sample: averages, encoder plausibility, the state machine, and the
    /// supervision that used to run every tick (loss of contact, limits, timeouts).
    fn on_sums(&mut self, m: SampleSums) -> bool {
        if matches!(
            self.phase,
            Phase::Init | Phase::Calibrating | Phase::Done | Phase::Fault(_)
        ) {
            return false;
        }
        self.tick = m.tick;
        self.jump_q16 = None;
        let Some(s) = self.average(&m) else {
            return false;
        };
        self.on_sample(s);
        if let Some(f) = self.pending.take() {
            self.fault(f);
        }
        if let Phase::Fault(_) = self.phase {
            return false;
        }
        let ready = matches!(
            self.phase,
            Phase::Estimating { since, request_ready: true, .. } if since == self.tick
        );
        self.check_contact_held(s.theta_a_urad, s.torque_ref_unm);
        self.check_limits(s.theta_a_urad, s.torque_ref_unm);
        ready && matches!(self.phase, Phase::Estimating { .. })
    }

    /// The sample's means, after the encoder's back-EMF check (`None`: it faulted); updates
    /// the speed estimate and the damping term.
    fn average(&mut self, m: &SampleSums) -> Option<Sample> {
        // 1..=64 (the loop never sums more): no division by zero or overflow.
        let n = m.n.clamp(1, 64) as i32;
        // Encoder plausibility: the back-EMF the bridge voltage and the current imply
        // must match the speed the encoder reports (a stuck or slipping encoder).
        let (duty, ua) = (i64::from(m.duty / n), i64::from(m.ua / n));
        if let Some(f) = self.emf.check(&self.p, m.counts, duty, ua) {
            self.fault(f);
            return None;
        }
        let s = Sample {
            tick: m.tick,
            theta_a_urad: m.theta_urad / n,
            torque_unm: m.torque_unm / n,
            torque_ref_unm: m.torque_ref_unm,
        };
        self.t_ref_unm = m.torque_ref_unm;
        if let Some(old) = self.theta_prev[1] {
            let v = (i64::from(s.theta_a_urad) - i64::from(old)) / 2;
            self.vel = sat_i32(v);
            self.damp_unm = sat_i32(v.saturating_mul(self.p.damping_q16) >> 16);
        }
        self.theta_prev = [Some(s.theta_a_urad), self.theta_prev[0]];
        Some(s)
    }

    /// Loss of contact, in every state that presses on the object: too fast, or θa beyond
    /// what the contact allows ([`Supervisor::lost`]).
    fn check_contact_held(&mut self, theta: i32, t_ref: i32) {
        let (contact, loading) = match self.phase {
            Phase::Seating { contact, .. } => (contact, None),
            Phase::Step { loaded, .. }
            | Phase::Settling { loaded, .. }
            | Phase::Estimating { loaded, .. }
            | Phase::Probing { loaded, .. }
            | Phase::Holding { loaded } => (loaded.contact, Some(loaded)),
            _ => return,
        };
        let fast = self.vel.saturating_abs() > self.p.loss_speed_urad;
        if fast
            || self
                .lost(theta, t_ref, &contact, loading.as_ref())
                .is_some()
        {
            let d = sat_i32(i64::from(theta) - i64::from(contact.knee.theta_a_urad));
            self.fault(FaultReason::LossOfContact { dtheta_a_urad: d });
        }
    }

    /// The approach's ceiling and range, the settle and estimate timeouts, and the end of a
    /// release.
    fn check_limits(&mut self, theta: i32, t_ref: i32) {
        let p = &self.p;
        match self.phase {
            Phase::Approach { .. }
                if t_ref >= p.approach_max_unm || theta > p.approach_theta_max_urad =>
            {
                self.fault(FaultReason::NoContact);
            }
            Phase::Seating { contact, .. }
            | Phase::Step {
                loaded: Loaded { contact, .. },
                ..
            }
            | Phase::Settling {
                loaded: Loaded { contact, .. },
                ..
            }
            | Phase::Probing {
                loaded: Loaded { contact, .. },
                ..
            } if self.tick.wrapping_sub(contact.tick) > p.settle_timeout_ticks => {
                self.fault(FaultReason::SettleTimeout);
            }
            Phase::Estimating { since, .. }
                if self.tick.wrapping_sub(since) > p.estimate_timeout_ticks =>
            {
                self.fault(FaultReason::EstimateTimeout);
            }
            Phase::Releasing if t_ref <= 0 && p.open_unm > 0 => {
                self.phase = Phase::Opening { since: self.tick };
            }
            Phase::Releasing if t_ref <= 0 => self.released(),
            Phase::Opening { since }
                if i64::from(theta)
                    <= i64::from(p.theta_a_rest_urad) + i64::from(p.open_end_urad)
                    || self.tick.wrapping_sub(since) > p.open_timeout_ticks =>
            {
                self.released()
            }
            _ => {}
        }
    }

    /// Released: bridge off.
    fn released(&mut self) {
        self.phase = Phase::Done;
        let tick = self.tick;
        self.emit(Event::Released { tick });
    }

    /// Lets go of a held object: the torque ramps down, then the opening torque takes the
    /// finger back toward rest, then the bridge goes off ([`State::Done`]). Only from
    /// [`State::Holding`]; returns whether the release started. Publish the setpoint
    /// afterwards ([`Supervisor::publish`]).
    pub fn release(&mut self) -> bool {
        if !matches!(self.phase, Phase::Holding { .. }) {
            return false;
        }
        self.phase = Phase::Releasing;
        let tick = self.tick;
        self.emit(Event::Releasing { tick });
        true
    }

    /// Moves the estimate request out, once, after the step reported it ready.
    /// Hand it to [`run_estimate`](crate::run_estimate) in a low-priority task.
    pub fn take_request(&mut self) -> Option<EstimateRequest> {
        let mut req = EstimateRequest::EMPTY;
        self.take_request_into(&mut req).then_some(req)
    }

    /// [`take_request`](Self::take_request) into a slot the caller keeps (the estimate task's
    /// static one): the samples are copied once, as many as were taken, where returning the
    /// request by value moves its whole capacity (3 KiB) several times. `false`, and `out`
    /// untouched, unless a request is ready.
    pub fn take_request_into(&mut self, out: &mut EstimateRequest) -> bool {
        let Phase::Estimating {
            loaded,
            end,
            since,
            request_ready: true,
        } = self.phase
        else {
            return false;
        };
        self.phase = Phase::Estimating {
            loaded,
            end,
            since,
            request_ready: false,
        };
        out.pre.clear();
        out.path.clear();
        // Same capacities on both sides: these cannot fail.
        let _ = out.pre.extend_from_slice(&self.pre);
        let _ = out.path.extend_from_slice(&self.path.samples);
        self.pre.clear();
        self.path.samples.clear();
        out.contact = loaded.contact.knee;
        out.seat = loaded.seat;
        out.seat2 = loaded.seat2;
        out.end = end;
        out.sample_ticks = self.p.sample_ticks;
        out.path_stride = self.path.stride;
        out.delta_ta_cmd_unm = self.p.delta_ta_unm;
        out.estimator = self.p.estimator;
        out.dt_ns = self.p.dt_ns;
        out.detect_k_unm_per_rad = sat_i32(self.p.detect_k_unm_per_rad);
        true
    }

    /// Gives the estimate back (from the low-priority task). A refused estimate puts the
    /// state machine in the safe state. Ignored unless it is waiting for one. Publish the
    /// setpoint afterwards ([`Supervisor::publish`]) so the loop acts on it at once.
    ///
    /// Without seating no static point lies inside the step, so a refusal or an answer that
    /// does not locate a distal contact is first probed (the probing phase): a finger locked
    /// by a second contact is named as one, as the seated controller's late-half check does.
    pub fn deliver(&mut self, outcome: Result<EstimateResult, EstimateError>) {
        let Phase::Estimating { loaded, end, .. } = self.phase else {
            return;
        };
        let kc_unm_per_rad = loaded.kc_late_unm_per_rad(&end);
        match outcome {
            // Far stiffer than any single contact on the distal phalanx: the finger is
            // blocked at two points.
            Err(EstimateError::Model(PtsError::BeyondTip))
                if i64::from(kc_unm_per_rad) > self.p.second_k_unm_per_rad =>
            {
                self.fault(FaultReason::SecondContact { kc_unm_per_rad });
                return;
            }
            Err(EstimateError::PathFit(PathFitError::SecondContact)) => {
                self.fault(FaultReason::SecondContact { kc_unm_per_rad });
                return;
            }
            _ => {}
        }
        let located_distal =
            matches!(&outcome, Ok(r) if r.located == crate::estimate::Located::Distal);
        if !self.p.seating && !located_distal {
            if let Some(target_unm) = self.probe_target(&end) {
                self.probed = Some(outcome);
                self.phase = Phase::Probing {
                    loaded,
                    end,
                    target_unm,
                    reached: None,
                };
                return;
            }
        }
        self.conclude(outcome, loaded);
    }

    /// The estimate's outcome taken: an answer is held (or released), a refusal is the safe
    /// state.
    fn conclude(&mut self, outcome: Result<EstimateResult, EstimateError>, loaded: Loaded) {
        let tick = self.tick;
        match outcome {
            Ok(r) => {
                self.result = Some(r);
                self.emit(Event::Estimated { tick, result: r });
                match self.p.after_estimate {
                    AfterEstimate::Hold => {
                        self.phase = Phase::Holding { loaded };
                        self.emit(Event::Holding { tick });
                    }
                    AfterEstimate::Release => {
                        self.phase = Phase::Releasing;
                        self.emit(Event::Releasing { tick });
                    }
                }
            }
            Err(error) => self.fault(FaultReason::EstimateOutOfRange { error }),
        }
    }

    /// Where the probe after an unseated estimate takes the reference: half a step above the
    /// settled end, no higher than [`Params::probe_max_unm`]; `None` when that leaves less
    /// than a quarter step.
    fn probe_target(&self, end: &Sample) -> Option<i32> {
        let from = end.torque_ref_unm;
        let to = from
            .saturating_add(self.p.delta_ta_unm / 2)
            .min(self.p.probe_max_unm);
        (i64::from(to) - i64::from(from) >= i64::from(self.p.delta_ta_unm / 4)).then_some(to)
    }

    /// The probe's end: once θa is still at the raised reference, its stiffness from the
    /// step's end decides. Far stiffer than any single contact, or than the whole step, is a
    /// second contact; anything else (a finger the drive's stiction still holds a whole step
    /// above the end included) leaves the estimator's outcome as it was.
    fn check_probe(&mut self, loaded: Loaded, end: Sample, since: u32) {
        let Some(now) = self.settled(since) else {
            return;
        };
        let dth = i64::from(now.theta_a_urad) - i64::from(end.theta_a_urad);
        // Not moved at all: the gear's friction, which grows with the load it carries, may
        // hold it; the probe goes on once, to a whole step above the end, before it decides.
        let full = end
            .torque_ref_unm
            .saturating_add(self.p.delta_ta_unm)
            .min(self.p.probe_max_unm);
        if dth < i64::from(self.p.min_motion_urad) && now.torque_ref_unm < full {
            self.phase = Phase::Probing {
                loaded,
                end,
                target_unm: full,
                reached: None,
            };
            return;
        }
        // Always set on entering the probe; a refusal is the safe default.
        let outcome = self
            .probed
            .take()
            .unwrap_or(Err(EstimateError::PathFit(PathFitError::NotDetermined)));
        let late = i64::from(stiffness(&end, &now));
        let step = i64::from(stiffness(&loaded.seat, &end));
        if dth >= i64::from(self.p.min_motion_urad)
            && (late > self.p.second_k_unm_per_rad
                || late > step.saturating_mul(i64::from(self.p.second_ratio)))
        {
            self.fault(FaultReason::SecondContact {
                kc_unm_per_rad: sat_i32(late),
            });
        } else {
            self.conclude(outcome, loaded);
        }
    }

    /// Loss of contact: θa beyond what the contact allows. Before two static points on the
    /// path: a stiffness ≥ K_detect from the contact point. After them: 1.5× the
    /// displacement their stiffness predicts from the later one (the path only stiffens) —
    /// seated: the two seats; unseated, once the step settled: the contact instant and the
    /// settled end. (An unseated step's halfway sample is no static point: on a slow drive its
    /// torque leads the motion, and a stiffness read there is far too high.)
    fn lost(
        &self,
        theta: i32,
        t_ref: i32,
        contact: &Contact,
        loaded: Option<&Loaded>,
    ) -> Option<i32> {
        // Before an unseated step settles, `settled` is `seat`: no stiffness, the fallback.
        let statics = loaded.map(|l| {
            let from = if self.p.seating { l.seat2 } else { l.settled };
            (from, stiffness(&l.seat, &from))
        });
        let (from, k, num, den) = match statics {
            Some((from, k)) if k > 0 && k < i32::MAX => (from, i64::from(k), 3, 2),
            _ => (contact.knee, self.p.detect_k_unm_per_rad, 1, 1),
        };
        let dth = i64::from(theta) - i64::from(from.theta_a_urad);
        let dt = (i64::from(t_ref) - i64::from(from.torque_unm)).max(0);
        let excess = dth - i64::from(self.p.loss_margin_urad);
        if excess <= 0 {
            return None;
        }
        // excess·K·den > ΔT·1e6·num  ⇔  moved more than (num/den)·ΔT/K + margin.
        if excess.saturating_mul(k).saturating_mul(den)
            > dt.saturating_mul(1_000_000).saturating_mul(num)
        {
            Some(sat_i32(dth))
        } else {
            None
        }
    }

    /// The state machine's step on one sample.
    fn on_sample(&mut self, s: Sample) {
        match self.phase {
            Phase::Approach { .. } => {
                self.hist.push(s);
                self.detect(s);
            }
            Phase::Seating { .. } => {
                self.path.push(s);
                self.hist.push(s);
                self.seating(s);
            }
            Phase::Step { loaded, target_unm } => {
                self.path.push(s);
                self.hist.push(s);
                if s.torque_ref_unm == target_unm {
                    self.phase = Phase::Settling {
                        loaded,
                        since: self.tick,
                    };
                    let tick = self.tick;
                    self.emit(Event::StepDone { tick });
                }
            }
            Phase::Settling { loaded, since } => {
                self.path.push(s);
                self.hist.push(s);
                if self.tick.wrapping_sub(since) >= self.p.settle_min_ticks {
                    self.check_settled(loaded, since);
                }
            }
            Phase::Probing {
                loaded,
                end,
                target_unm,
                reached,
            } => {
                self.hist.push(s);
                match reached {
                    None if s.torque_ref_unm == target_unm => {
                        self.phase = Phase::Probing {
                            loaded,
                            end,
                            target_unm,
                            reached: Some(self.tick),
                        };
                    }
                    Some(since) if self.tick.wrapping_sub(since) >= self.p.settle_min_ticks => {
                        self.check_probe(loaded, end, since);
                    }
                    _ => {}
                }
            }
            _ => {}
        }
    }

    /// Measured ΔT_a and Δθa over the last `w` samples.
    fn window(&self, w: usize) -> Option<(i64, i64)> {
        let b = self.hist.back(0)?;
        let a = self.hist.back(w)?;
        Some((
            i64::from(b.torque_unm) - i64::from(a.torque_unm),
            i64::from(b.theta_a_urad) - i64::from(a.theta_a_urad),
        ))
    }

    /// The approach's contact detection on sample `s`: ΔT_a/Δθa over the window at or above
    /// K_detect (and ΔT_a above a minimum rise) `detect_confirm` times in a row, once free
    /// motion has been seen.
    fn detect(&mut self, s: Sample) {
        let Phase::Approach {
            mut armed,
            mut stiff_count,
        } = self.phase
        else {
            return;
        };
        let w = self.p.detect_window;
        let Some((dt, dth)) = self.window(w) else {
            return;
        };
        let k = self.p.detect_k_unm_per_rad;
        let stiff = dt >= i64::from(self.p.detect_min_rise_unm)
            && dt.saturating_mul(1_000_000) >= k.saturating_mul(dth);
        if !stiff {
            // Free motion seen: from now on a stiff window means contact.
            if dth >= i64::from(self.p.detect_arm_urad)
                && dt.saturating_mul(1_000_000) < k.saturating_mul(dth)
            {
                armed = true;
            }
            stiff_count = 0;
        } else if armed {
            stiff_count = stiff_count.saturating_add(1);
        }
        self.phase = Phase::Approach { armed, stiff_count };
        if stiff && armed && stiff_count >= self.p.detect_confirm {
            let knee = knee(&self.hist, s, w);
            // The event reports the contact instant itself, timed from the impact's signature.
            let at = contact_instant(
                &self.hist,
                w,
                self.p.sample_ticks,
                self.p.urad_per_count_q16,
            )
            .unwrap_or(knee);
            self.enter_seating(knee, at);
        }
    }

    /// Contact: keeps the history before it for the estimator, starts the path, and presses
    /// gently (T_a,c + δ_seat) while the impact dies out, for the first static point; without
    /// seating, the step from T_a,c at once.
    fn enter_seating(&mut self, knee: Sample, at: Sample) {
        self.pre.clear();
        let mut i = self.hist.len;
        while i > 0 {
            i -= 1;
            if let Some(h) = self.hist.back(i) {
                let _ = self.pre.push(h);
            }
        }
        self.path.clear();
        let contact = Contact {
            knee,
            tick: self.tick,
        };
        if self.p.seating {
            let seat = knee.torque_unm.saturating_add(self.p.seat_above_unm);
            self.jump_q16 = Some(i64::from(seat) << 16);
            self.phase = Phase::Seating {
                contact,
                seat: Seat::Impact,
                target_unm: seat,
                since: self.tick,
            };
        } else {
            // No static point will locate the contact again: the first stays at the impact's
            // signature (the contact instant, which the detection's knee trails), the second
            // is taken once the step has settled.
            self.jump_q16 = Some(i64::from(knee.torque_unm) << 16);
            self.phase = Phase::Step {
                loaded: Loaded {
                    contact,
                    seat: at,
                    seat2: at,
                    settled: at,
                },
                target_unm: knee.torque_unm.saturating_add(self.p.delta_ta_unm),
            };
        }
        let tick = self.tick;
        self.emit(Event::ContactDetected {
            tick,
            contact_tick: at.tick,
            theta_a_urad: at.theta_a_urad,
            torque_unm: at.torque_unm,
            target_unm: knee.torque_unm.saturating_add(self.p.delta_ta_unm),
        });
    }

    /// Seating on sample `s`: watches for the forward slide in stage 1, and takes a static
    /// point once the reference has reached its target and θa stays still.
    fn seating(&mut self, s: Sample) {
        let Phase::Seating {
            contact,
            mut seat,
            mut target_unm,
            mut since,
        } = self.phase
        else {
            return;
        };
        let top = contact.knee.torque_unm.saturating_add(self.p.delta_ta_unm);
        if let Seat::Slide { rest, slid: false } = seat {
            let moved = i64::from(s.theta_a_urad) - i64::from(rest.theta_a_urad);
            if moved >= i64::from(self.p.slide_min_urad) {
                // Sliding forward: a little more, then hold for the first loading point.
                seat = Seat::Slide { rest, slid: true };
                target_unm = s
                    .torque_ref_unm
                    .saturating_add(self.p.slide_extra_unm)
                    .min(top);
                since = self.tick;
            }
        }
        self.phase = Phase::Seating {
            contact,
            seat,
            target_unm,
            since,
        };
        let waited = self.tick.wrapping_sub(since) >= self.p.settle_min_ticks;
        if s.torque_ref_unm != target_unm || !waited {
            return;
        }
        let Some(point) = self.settled(since) else {
            return;
        };
        let tick = self.tick;
        self.emit(Event::Seated {
            tick,
            stage: seat.stage(),
            theta_a_urad: point.theta_a_urad,
            torque_unm: point.torque_unm,
        });
        self.next_seat(contact, seat, target_unm, top, point);
    }

    /// After the static `point` of a seating stage: the next stage, the step, or `NoMotion`.
    fn next_seat(
        &mut self,
        contact: Contact,
        seat: Seat,
        target_unm: i32,
        top: i32,
        point: Sample,
    ) {
        let since = self.tick;
        let no_motion = |rest: Sample| FaultReason::NoMotion {
            dtheta_a_urad: sat_i32(i64::from(point.theta_a_urad) - i64::from(rest.theta_a_urad)),
        };
        match seat {
            Seat::Impact => {
                // The impact is over; ramp until the drive slides forward.
                self.phase = Phase::Seating {
                    contact,
                    seat: Seat::Slide {
                        rest: point,
                        slid: false,
                    },
                    target_unm: top,
                    since,
                };
            }
            // T_a,c + ΔT_a reached without the drive sliding: ΔT_a is inside the stiction
            // band, nothing to measure.
            Seat::Slide { rest, slid: false } => self.pending = Some(no_motion(rest)),
            Seat::Slide { rest, slid: true } => {
                // The estimator extrapolates the path through the loading points back to
                // the contact: it needs them to span at least the distance back (else the
                // step is mostly stiction band).
                let back = i64::from(target_unm) - i64::from(contact.knee.torque_unm);
                let span = i64::from(top) - i64::from(target_unm);
                if span < back || span < i64::from(self.p.seat_above_unm) {
                    self.pending = Some(no_motion(rest));
                } else {
                    let mid = (i64::from(target_unm) + i64::from(top)) / 2;
                    self.phase = Phase::Seating {
                        contact,
                        seat: Seat::Second { seat: point },
                        target_unm: sat_i32(mid),
                        since,
                    };
                }
            }
            Seat::Second { seat } => {
                self.phase = Phase::Step {
                    loaded: Loaded {
                        contact,
                        seat,
                        seat2: point,
                        settled: point,
                    },
                    target_unm: top,
                };
            }
        }
    }

    /// Without seating, the static points the checks and the contact's back-dating read: the
    /// contact instant (`seat`, on the free-motion curve: the back-dating returns it) and the
    /// path sample where θa first passed halfway from there to the end (`seat2`; halfway in θa,
    /// not in torque: at a fast step's start the current leads the motion while it
    /// accelerates the drive). The no-motion check reads halfway → end; the second-contact
    /// check only the whole step (`check_settled`).
    fn unseated_points(&self, loaded: Loaded, end: &Sample) -> Loaded {
        let at = loaded.seat;
        let half = (i64::from(at.theta_a_urad) + i64::from(end.theta_a_urad)) / 2;
        let seat2 = self
            .path
            .samples
            .iter()
            .find(|p| i64::from(p.theta_a_urad) >= half)
            .copied()
            .unwrap_or(at);
        Loaded {
            contact: loaded.contact,
            seat: at,
            seat2,
            settled: *end,
        }
    }

    /// Mean (θa, T_a) over the settle window when θa stayed within the settle band and every
    /// sample of the window is newer than `since`.
    fn settled(&self, since: u32) -> Option<Sample> {
        let (theta_a_urad, torque_unm) = still_mean(
            &self.hist,
            since,
            self.p.settle_window,
            self.p.settle_band_urad,
        )?;
        Some(Sample {
            tick: self.tick,
            theta_a_urad,
            torque_unm,
            torque_ref_unm: self.t_ref_unm,
        })
    }

    /// Settling: once θa is still, the end point; refused as `NoMotion` or `SecondContact`
    /// when the late half of the step cannot come from one contact, else the request is out.
    fn check_settled(&mut self, loaded: Loaded, since: u32) {
        let Some(end) = self.settled(since) else {
            return;
        };
        // A step is measured only once the drive has delivered it: a finger held still by a
        // drive that cannot reach the reference (duty at its limit) is not a settled step but
        // a stall, which the loop trips on. The seating stages' slow ramps used to hide this;
        // a fast step settles before the stall's persistence runs out.
        let miss = (i64::from(end.torque_unm) - i64::from(self.t_ref_unm)).abs();
        if miss > i64::from(self.p.delta_ta_unm / DELIVERED_SHARE).max(DELIVERED_MIN_UNM) {
            return;
        }
        let loaded = if self.p.seating {
            loaded
        } else {
            self.unseated_points(loaded, &end)
        };
        // The finger did not move over the late half: held by transmission stiction (ΔT_a
        // below the friction band) or locked; the step cannot measure a stiffness.
        let dth_late = i64::from(end.theta_a_urad) - i64::from(loaded.seat2.theta_a_urad);
        if dth_late < i64::from(self.p.min_motion_urad) {
            self.pending = Some(FaultReason::NoMotion {
                dtheta_a_urad: sat_i32(dth_late),
            });
            return;
        }
        // A second contact locks the finger: the late half of the step is far stiffer than
        // any single contact, or far stiffer than the early half (a proximal first contact,
        // K ≈ K_c,prox, then the distal phalanx touching too). Without seating no static
        // point lies between the contact and the end: the halfway sample is in the step's
        // dynamics (the reference drops to T_a,c at the detection while the impact
        // decelerates the drive, so the torque there can be below T_a,c), and only the whole
        // step's secant is checked; the path fit judges the path's shape.
        let (late, early) = if self.p.seating {
            (
                i64::from(loaded.kc_late_unm_per_rad(&end)),
                i64::from(stiffness(&loaded.seat, &loaded.seat2)),
            )
        } else {
            (i64::from(stiffness(&loaded.seat, &end)), i64::MAX)
        };
        if late > self.p.second_k_unm_per_rad
            || late > early.saturating_mul(i64::from(self.p.second_ratio))
        {
            self.pending = Some(FaultReason::SecondContact {
                kc_unm_per_rad: sat_i32(late),
            });
            return;
        }
        self.phase = Phase::Estimating {
            loaded,
            end,
            since: self.tick,
            request_ready: true,
        };
        let tick = self.tick;
        self.emit(Event::Settled {
            tick,
            theta_a_urad: end.theta_a_urad,
            torque_unm: end.torque_unm,
            path_len: self.path.samples.len() as u16,
        });
    }
}

#[cfg(test)]
#[allow(clippy::float_arithmetic)]
mod tests {
    //! Contact detection, settling and the contact back-dating against synthetic samples whose
    //! contact instant, free-motion line and still window are known by construction.

    use super::*;
    use crate::ControllerConfig;

    /// Ticks per sample in these tests (the controller's default: 4 ms at 10 kHz).
    const ST: u32 = 40;

    fn sample(tick: u32, theta_a_urad: i32, torque_unm: i32) -> Sample {
        Sample {
            tick,
            theta_a_urad,
            torque_unm,
            torque_ref_unm: torque_unm,
        }
    }

    /// A ring of samples labelled ST, 2·ST, … whose θa and T_a are the means over each
    /// sample's ticks of `theta(t)` and `torque(t)` (t in ticks), as the loop sums them.
    fn ring_of(n: u32, theta: impl Fn(f64) -> f64, torque: impl Fn(f64) -> f64) -> Ring {
        let mut r = Ring::new();
        for k in 1..=n {
            let label = k * ST;
            let ticks = (label - ST + 1)..=label;
            let mean = |f: &dyn Fn(f64) -> f64| {
                ticks.clone().map(|t| f(f64::from(t))).sum::<f64>() / f64::from(ST)
            };
            r.push(sample(
                label,
                mean(&theta).round() as i32,
                mean(&torque).round() as i32,
            ));
        }
        r
    }

    fn cube(x: f64) -> f64 {
        x * x * x
    }

    /// Free motion: θa creeping up at 20 µrad/tick, slightly accelerating (the approach's
    /// ramp); T_a rising linearly in time.
    fn free_theta(t: f64) -> f64 {
        -400_000.0 + 20.0 * t + 0.5 * 2e-4 * t * t
    }
    fn free_torque(t: f64) -> f64 {
        300_000.0 + 15.0 * t
    }

    #[test]
    fn contact_instant_finds_the_start_of_a_cubic_deficit() {
        // After the contact at tc the finger decelerates on the contact stiffness:
        // θa = free − c·(t − tc)³ (J θ̈ = −K v (t − tc), c = K v / 6J).
        let tc = 1913.0;
        let c = 1e-5;
        let theta = |t: f64| free_theta(t) - if t > tc { c * cube(t - tc) } else { 0.0 };
        // The newest sample is 12 samples after the contact: within the 2w = 20 the search
        // may look back, and the free-motion samples 2w..4w back are all before it.
        let hist = ring_of(60, theta, free_torque);
        let got = contact_instant(&hist, 10, ST, 2_094_395).expect("a deficit of ~1 mrad");
        // A quarter of a sample: the crossing is interpolated linearly between samples.
        assert!(
            (f64::from(got.tick) - tc).abs() <= f64::from(ST) / 4.0,
            "contact at {} ticks, built at {tc}",
            got.tick
        );
        // θa,c on the free motion and T_a,c on the free torque line, at the instant found,
        // within one tick of travel on either (20 µrad, 15 µN·m): a sample's mean sits half
        // a tick off the middle of its interval as the labels count it.
        let at = f64::from(got.tick);
        assert!((f64::from(got.theta_a_urad) - free_theta(at)).abs() <= 20.0);
        assert!((f64::from(got.torque_unm) - free_torque(at)).abs() <= 15.0);
    }

    #[test]
    fn contact_instant_needs_a_deficit_of_four_counts() {
        // Pure free motion: nothing to time.
        let hist = ring_of(60, free_theta, free_torque);
        assert_eq!(contact_instant(&hist, 10, ST, 2_094_395), None);
        // A deficit of 100 µrad at the newest sample is below 4 counts (4 × 31.96 µrad).
        let tc = 2000.0;
        let c = 100.0 / cube(2400.0 - 20.0 - tc);
        let theta = |t: f64| free_theta(t) - if t > tc { c * cube(t - tc) } else { 0.0 };
        let hist = ring_of(60, theta, free_torque);
        assert_eq!(contact_instant(&hist, 10, ST, 2_094_395), None);
        // Too little history for the free-motion parabola (4w + 1 samples).
        let hist = ring_of(40, free_theta, free_torque);
        assert_eq!(contact_instant(&hist, 10, ST, 2_094_395), None);
    }

    #[test]
    fn knee_is_on_the_free_motion_line_at_the_detection_angle() {
        // Free motion along T = 0.3 N·m + 0.7 N·m/rad (θ − θ0), 800 µrad per sample; the
        // contact at sample 50 stiffens it to 10 N·m/rad.
        let (theta0, k_free) = (-400_000.0, 0.7);
        let mut hist = Ring::new();
        let mut s = sample(0, 0, 0);
        for k in 1..=58u32 {
            let th = if k <= 50 {
                theta0 + 800.0 * f64::from(k)
            } else {
                theta0 + 800.0 * 50.0 + 56.0 * f64::from(k - 50)
            };
            let tq = if k <= 50 {
                300_000.0 + k_free * (th - theta0)
            } else {
                300_000.0 + k_free * 800.0 * 50.0 + 10.0 * (th - (theta0 + 40_000.0))
            };
            s = sample(k * ST, th as i32, tq as i32);
            hist.push(s);
        }
        let got = knee(&hist, s, 10);
        let want = 300_000.0 + k_free * (f64::from(s.theta_a_urad) - theta0);
        assert_eq!(got.theta_a_urad, s.theta_a_urad);
        assert!(
            (f64::from(got.torque_unm) - want).abs() <= 1.0,
            "{} vs {want}",
            got.torque_unm
        );
        assert!(
            got.torque_unm < s.torque_unm,
            "below the measured (stiff) torque"
        );
    }

    /// The seated controller's supervisor (its detection is the default's; the tests follow
    /// it into seating).
    fn supervisor() -> Supervisor {
        let p = ControllerConfig {
            seating: true,
            ..ControllerConfig::default()
        }
        .params()
        .expect("default config");
        let mut sup = Supervisor::new(&p);
        sup.handle(Input::Started);
        sup.handle(Input::Calibrated {
            tick: 200,
            offset_q8: 0,
        });
        sup
    }

    /// One sample of means (θa, T_a) ending at `tick`, as the loop's sums; the bridge off
    /// and the encoder still, so the back-EMF check agrees.
    fn sums(tick: u32, theta_a_urad: i32, torque_unm: i32) -> Input {
        let n = ST as i32;
        Input::Sample(SampleSums {
            tick,
            n: ST,
            theta_urad: theta_a_urad * n,
            torque_unm: torque_unm * n,
            duty: 0,
            ua: 0,
            counts: 0,
            torque_ref_unm: torque_unm,
        })
    }

    /// Feeds a quasi-static approach: T_a rises 560 µN·m per sample; θa follows the free
    /// motion (0.7 N·m/rad, 800 µrad per sample) until sample `contact`, then a 10 N·m/rad
    /// contact (56 µrad per sample). Returns the tick of the ContactDetected event.
    fn approach(sup: &mut Supervisor, contact: u32, samples: u32) -> Option<u32> {
        let mut theta = -600_000;
        let mut torque = 200_000;
        for k in 1..=samples {
            theta += if k <= contact { 800 } else { 56 };
            torque += 560;
            sup.handle(sums(200 + k * ST, theta, torque));
            while let Some(e) = sup.poll_event() {
                if let Event::ContactDetected { tick, .. } = e {
                    return Some(tick);
                }
            }
        }
        None
    }

    #[test]
    fn detection_fires_when_the_window_turns_stiff_twice() {
        let mut sup = supervisor();
        let tick = approach(&mut sup, 30, 60).expect("a contact");
        // By hand: with j of the window's 10 samples past the contact, Δθ = 800(10 − j) +
        // 56 j and ΔT = 5600 µN·m, so ΔT/Δθ ≥ 1.5 N·m/rad from j = 6 (Δθ = 3536 µrad); the
        // second stiff window in a row (j = 7) confirms.
        assert_eq!(tick, 200 + (30 + 7) * ST);
        assert_eq!(sup.state(), State::Seating);
        // Seating presses at T_a,c + δ_seat at once.
        assert!(matches!(sup.setpoint().reference, Reference::Set(_)));
    }

    /// The default controller does not seat: the same detection starts the step from T_a,c
    /// (the detection's knee).
    #[test]
    fn by_default_the_detection_starts_the_step() {
        let p = ControllerConfig::default()
            .params()
            .expect("default config");
        assert!(!p.seating);
        let mut sup = Supervisor::new(&p);
        sup.handle(Input::Started);
        sup.handle(Input::Calibrated {
            tick: 200,
            offset_q8: 0,
        });
        assert!(approach(&mut sup, 30, 60).is_some());
        assert_eq!(sup.state(), State::Step);
        // The reference is put at T_a,c at once; the step's ramp starts from there.
        assert!(matches!(sup.setpoint().reference, Reference::Set(_)));
    }

    #[test]
    fn detection_needs_free_motion_first_and_ignores_free_motion() {
        // Pressed from the first sample (never armed): no contact, whatever the stiffness.
        let mut sup = supervisor();
        assert_eq!(approach(&mut sup, 0, 60), None);
        assert_eq!(sup.state(), State::Approach);
        // Free motion only: no contact.
        let mut sup = supervisor();
        assert_eq!(approach(&mut sup, 1000, 200), None);
        assert_eq!(sup.state(), State::Approach);
    }

    /// A full ring whose newest `window` samples sit at θa = 1000 + `offsets`[i] µrad,
    /// T_a = 50 000 + 10·i µN·m, labelled from `first` on.
    fn still_ring(first: u32, offsets: &[i32]) -> Ring {
        let mut r = Ring::new();
        for (i, d) in offsets.iter().enumerate() {
            let i32_i = i as i32;
            r.push(sample(first + i as u32 * ST, 1000 + d, 50_000 + 10 * i32_i));
        }
        r
    }

    #[test]
    fn still_mean_averages_a_window_inside_the_band() {
        // 5 samples at 1000 ± 25 µrad (band 50): mean θ 1000 µrad by symmetry; torques
        // 50 000, …, 50 040: mean 50 020 µN·m.
        let r = still_ring(400, &[-25, 25, 0, 25, -25]);
        assert_eq!(still_mean(&r, 400, 5, 50), Some((1000, 50_020)));
        // The same window is not still for a band of 49 µrad.
        assert_eq!(still_mean(&r, 400, 5, 49), None);
        // A sample labelled before `since` (the stage's start) is not part of it.
        assert_eq!(still_mean(&r, 401, 5, 50), None);
        // Fewer samples than the window.
        assert_eq!(still_mean(&r, 400, 6, 50), None);
    }

    #[test]
    fn settling_needs_the_minimum_wait_and_a_still_window() {
        // The settle window (25 samples = 100 ms) must lie after `since`: a still finger
        // reports its mean only once 25 samples have passed since the stage began.
        let offsets = [0i32; 30];
        let r = still_ring(40, &offsets);
        let newest_label = 40 + 29 * ST;
        let oldest_in_window = newest_label - 24 * ST;
        assert!(still_mean(&r, oldest_in_window, 25, 50).is_some());
        assert_eq!(still_mean(&r, oldest_in_window + 1, 25, 50), None);
    }
}
