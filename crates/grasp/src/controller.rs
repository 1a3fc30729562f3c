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
//! Why the static points come after a forward slide: the transmission's friction (Coulomb
//! ≈ 0.076 N·m at the base link while sliding, stiction ≈ 0.11 N·m, and a back-driving
//! efficiency that makes the drive hard to push back) holds the finger wherever the impact
//! leaves it, with any friction inside the band. On the plant (Table 2, ΔT_a 0.8) the
//! impact's rest point read T_meas − T_a = +0.005 N·m while every point reached by sliding
//! forward read +0.081…+0.083, as the approach did (+0.083): with the rest point as the first
//! static point, the estimator's parabola through the static points met the free-motion
//! curve 12 mrad late and the two-point error was +22.6 % l2 instead of the quasi-static
//! +16.35 %. With loading points only, the Coulomb term is the same at the contact
//! (back-dated onto the approach's shifted free-motion curve) and at the end point, so it
//! cancels in ΔT_a: +17.0 %.
#![deny(clippy::float_arithmetic)]

use heapless::{Deque, Vec};
use pathfit::PathFitError;
use pts::PtsError;

use crate::config::{AfterEstimate, ConfigError, ControllerConfig, Params, HISTORY};
use crate::control_loop::{ControlLoop, Input, Link, Reference, SampleSums, Setpoint, TorqueQ16};
use crate::estimate::{EstimateError, EstimateRequest, EstimateResult, Sample, PATH_CAPACITY};
use crate::sensors::sat_i32;
use crate::{Hardware, DUTY_MAX};

/// Events queued for logging (oldest dropped first is NOT done: new events are dropped
/// and counted when the queue is full, so the first fault is never lost).
pub const EVENT_CAPACITY: usize = 16;

/// Why the controller went to the safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultReason {
    /// The encoder jumped by more counts in one tick than the drive can move.
    EncoderJump {
        /// The jump (counts).
        step_counts: i32,
    },
    /// The encoder disagrees with the motor's back-EMF (bridge voltage − R·I) for longer than
    /// allowed: stuck or slipping encoder.
    EncoderMismatch {
        /// Back-EMF from the bridge voltage and current (mV).
        emf_mv: i32,
        /// Back-EMF implied by the encoder speed (mV).
        encoder_emf_mv: i32,
    },
    /// The ADC gave a code outside 0‥4095.
    AdcCode {
        /// The code.
        code: u16,
    },
    /// The zero-current offset measured with the bridge off is implausible (sensor fault).
    AdcOffset {
        /// Measured offset ×256 (codes).
        offset_q8: i32,
    },
    /// The current ADC sat at a rail (code 0 or 4095) for the over-current time while
    /// driving: the current is beyond the sensor's range, or the sensor failed.
    AdcRail {
        /// The code.
        code: u16,
    },
    /// |motor current| above the limit for the configured number of ticks.
    OverCurrent {
        /// Current at the trip (µA).
        current_ua: i32,
    },
    /// The duty stayed saturated: the drive cannot follow the torque reference.
    Stall,
    /// The approach reached its torque ceiling or the end of the finger's range without
    /// detecting a contact.
    NoContact,
    /// The finger did not settle after the step within the timeout.
    SettleTimeout,
    /// The estimate was not delivered within the timeout.
    EstimateTimeout,
    /// A second contact: the stiffness over the second half of the step (and K̂c beyond a
    /// tip contact) is above that of any single contact: the finger is locked.
    SecondContact {
        /// The stiffness seen (µN·m/rad).
        kc_unm_per_rad: i32,
    },
    /// The step cannot measure a stiffness: T_a,c + ΔT_a reached without the drive sliding
    /// out of the impact's rest (ΔT_a inside the transmission's stiction band), or sliding
    /// so late that the loading points span less than their distance back to the contact,
    /// or the second half of the step moved θa less than the minimum (held by friction or
    /// locked).
    NoMotion {
        /// θa travel since the impact's rest point (seating), or over the late half of the
        /// step (µrad).
        dtheta_a_urad: i32,
    },
    /// The finger moved further than a contact allows: the object is gone.
    LossOfContact {
        /// θa beyond the contact angle (µrad).
        dtheta_a_urad: i32,
    },
    /// The estimator refused the measurement.
    EstimateOutOfRange {
        /// The estimator's reason.
        error: EstimateError,
    },
    /// The loop found the setpoint older than it may drive on: the supervisor stopped
    /// stamping it (stalled or starved task). Found by the loop, bridge off at once.
    SupervisorStalled {
        /// Ticks since the supervisor's last stamp.
        age_ticks: u32,
    },
    /// The rest check ([`crate::rest`]) found no open stop before its timeout or within the
    /// finger's range, or could not return to the rest: the encoder cannot be zeroed.
    RestNotFound {
        /// Encoder travel of the failing phase (counts: from power-up while opening, from the
        /// stop while returning).
        moved_counts: i32,
        /// The return to rest failed (else the search for the stop).
        returning: bool,
    },
}

impl FaultReason {
    /// A stable snake_case name for logs.
    pub const fn kind(&self) -> &'static str {
        match self {
            FaultReason::EncoderJump { .. } => "encoder_jump",
            FaultReason::EncoderMismatch { .. } => "encoder_mismatch",
            FaultReason::AdcCode { .. } => "adc_code",
            FaultReason::AdcOffset { .. } => "adc_offset",
            FaultReason::AdcRail { .. } => "adc_rail",
            FaultReason::OverCurrent { .. } => "over_current",
            FaultReason::Stall => "stall",
            FaultReason::NoContact => "no_contact",
            FaultReason::SettleTimeout => "settle_timeout",
            FaultReason::EstimateTimeout => "estimate_timeout",
            FaultReason::SecondContact { .. } => "second_contact",
            FaultReason::NoMotion { .. } => "no_motion",
            FaultReason::LossOfContact { .. } => "loss_of_contact",
            FaultReason::EstimateOutOfRange { .. } => "estimate_out_of_range",
            FaultReason::SupervisorStalled { .. } => "supervisor_stalled",
            FaultReason::RestNotFound { .. } => "rest_not_found",
        }
    }

    /// True for the sensor faults (encoder or current sensor).
    pub const fn is_sensor_fault(&self) -> bool {
        matches!(
            self,
            FaultReason::EncoderJump { .. }
                | FaultReason::EncoderMismatch { .. }
                | FaultReason::AdcCode { .. }
                | FaultReason::AdcOffset { .. }
                | FaultReason::AdcRail { .. }
        )
    }
}

/// The controller's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum State {
    /// Not ticked yet.
    Init,
    /// Bridge off, measuring the current offset.
    Calibrating,
    /// Closing: torque reference ramping up, watching for contact.
    Approach,
    /// Contact detected: the reference is held at T_a,c + δ_seat while the impact dies out
    /// (stage 0, its rest point is not used by the estimate: friction there is anywhere in
    /// the stiction band); then it ramps until θa moves forward (the drive slides), a little
    /// more, and the first loading point is taken (stage 1); the second halfway to
    /// T_a,c + ΔT_a (stage 2). With the end point, they give the path's slope and curvature
    /// for back-dating.
    Seating,
    /// The reference is being raised to T_a,c + ΔT_a.
    Step,
    /// Reference at T_a,c + ΔT_a; waiting for θa to settle.
    Settling,
    /// Settled; the estimate request is out, waiting for [`Controller::deliver`].
    Estimating,
    /// Estimate delivered; holding the torque.
    Holding,
    /// Estimate delivered; ramping the torque down.
    Releasing,
    /// Released; bridge off.
    Done,
    /// Safe state: bridge off, with the reason.
    Fault(FaultReason),
}

/// Every transition, with its data (for defmt logging). Times in ticks since start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// Offset calibrated; approach starts.
    Calibrated {
        /// Tick.
        tick: u32,
        /// Zero-current ADC code ×256.
        offset_q8: i32,
    },
    /// Contact detected.
    ContactDetected {
        /// Tick of the detection.
        tick: u32,
        /// Tick of the back-dated contact instant (from the deceleration after the impact;
        /// falls back to the end of the free-motion data).
        contact_tick: u32,
        /// θa,c at the back-dated instant, on the free-motion trajectory (µrad).
        theta_a_urad: i32,
        /// T_a,c at the back-dated instant (µN·m, measured: the approach's sliding friction
        /// included).
        torque_unm: i32,
        /// Torque target of the step, T_a,c + ΔT_a (µN·m).
        target_unm: i32,
    },
    /// A static point after contact: where the impact came to rest at T_a,c + δ_seat
    /// (stage 0, not used by the estimate), the first loading point after the forward slide
    /// (stage 1), the second one halfway from there to T_a,c + ΔT_a (stage 2).
    Seated {
        /// Tick.
        tick: u32,
        /// 0, 1 or 2.
        stage: u8,
        /// Mean θa over the settle window (µrad).
        theta_a_urad: i32,
        /// Mean measured T_a over the settle window (µN·m).
        torque_unm: i32,
    },
    /// The reference reached T_a,c + ΔT_a.
    StepDone {
        /// Tick.
        tick: u32,
    },
    /// Settled: the estimate request is ready.
    Settled {
        /// Tick.
        tick: u32,
        /// Mean θa over the settle window (µrad).
        theta_a_urad: i32,
        /// Mean measured T_a over the settle window (µN·m).
        torque_unm: i32,
        /// Path samples handed to the estimator.
        path_len: u16,
    },
    /// The estimate came back.
    Estimated {
        /// Tick.
        tick: u32,
        /// The result.
        result: EstimateResult,
    },
    /// Holding after the estimate.
    Holding {
        /// Tick.
        tick: u32,
    },
    /// Releasing after the estimate.
    Releasing {
        /// Tick.
        tick: u32,
    },
    /// Released, bridge off.
    Released {
        /// Tick.
        tick: u32,
    },
    /// Fault: safe state.
    Fault {
        /// Tick.
        tick: u32,
        /// Why.
        reason: FaultReason,
    },
}

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
        self.sup.state
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
            state: self.sup.state,
            theta_a_urad: o.theta_a_urad,
            torque_unm: o.torque_unm,
            torque_ref_unm: o.torque_ref_unm,
            duty: o.duty,
            estimate_ready,
        }
    }
}

/// The grasp state machine: the slow half of the controller, one step per finished
/// sample (every `sample_ticks` ticks), fed through the [`Link`] by the [`ControlLoop`] and
/// answering with a [`Setpoint`]. On the target it runs in a task below the sampling task.
#[derive(Clone, Debug)]
pub struct Supervisor {
    p: Params,
    state: State,
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
    armed: bool,
    stiff_count: u32,
    contact: Sample,
    /// Where the impact came to rest (held by stiction anywhere in its band: not used
    /// by the estimate, only as the reference for the forward slide).
    rest: Sample,
    /// Seating stage 1: the drive has been seen sliding forward from `rest`.
    slid: bool,
    seat: Sample,
    seat2: Sample,
    seat_stage: u8,
    contact_hist: Vec<Sample, HISTORY>,
    target_unm: i32,
    phase_tick: u32,
    contact_tick: u32,
    path: Vec<Sample, PATH_CAPACITY>,
    path_stride: u32,
    path_skip: u32,
    end: Sample,
    request_ready: bool,
    result: Option<EstimateResult>,
    events: Deque<Event, EVENT_CAPACITY>,
    events_dropped: u32,
    last_counts: i32,
    emf_bad: u32,
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

impl Supervisor {
    /// A state machine before the loop has started.
    pub fn new(p: &Params) -> Self {
        Self {
            p: *p,
            state: State::Init,
            tick: 0,
            t_ref_unm: 0,
            jump_q16: None,
            vel: 0,
            theta_prev: [None, None],
            damp_unm: 0,
            hist: Ring::new(),
            armed: false,
            stiff_count: 0,
            contact: Sample::ZERO,
            rest: Sample::ZERO,
            slid: false,
            seat: Sample::ZERO,
            seat2: Sample::ZERO,
            seat_stage: 0,
            contact_hist: Vec::new(),
            target_unm: 0,
            phase_tick: 0,
            contact_tick: 0,
            path: Vec::new(),
            path_stride: 1,
            path_skip: 0,
            end: Sample::ZERO,
            request_ready: false,
            result: None,
            events: Deque::new(),
            events_dropped: 0,
            last_counts: 0,
            emf_bad: 0,
            pending: None,
        }
    }

    /// Current state.
    pub fn state(&self) -> State {
        self.state
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
        if !matches!(self.state, State::Fault(_)) {
            self.state = State::Fault(reason);
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
        let reference = match self.state {
            // The ramp pauses while the actuator is at its approach speed limit; it stops
            // just above the ceiling, where the approach gives up (NoContact).
            State::Approach if self.vel < p.approach_vmax_urad => Reference::Ramp {
                target: TorqueQ16::from_unm(p.approach_max_unm.saturating_add(1)),
                rate: TorqueQ16::new(p.approach_ramp_q16),
            },
            State::Seating | State::Step => match self.jump_q16 {
                Some(v) => Reference::Set(TorqueQ16::new(v)),
                None => {
                    let target = TorqueQ16::from_unm(self.target_unm);
                    // Stage 1 always ramps: the slide must be seen before the reference stops.
                    let rate_q16 = if self.state == State::Seating && self.seat_stage == 1 {
                        p.seat_ramp_q16
                    } else {
                        p.step_ramp_q16
                    };
                    if rate_q16 <= 0 {
                        Reference::Set(target)
                    } else {
                        Reference::Ramp {
                            target,
                            rate: TorqueQ16::new(rate_q16),
                        }
                    }
                }
            },
            State::Releasing => Reference::Ramp {
                target: TorqueQ16::new(0),
                rate: TorqueQ16::new(p.release_ramp_q16),
            },
            _ => Reference::Hold,
        };
        let enable = matches!(
            self.state,
            State::Approach
                | State::Seating
                | State::Step
                | State::Settling
                | State::Estimating
                | State::Holding
                | State::Releasing
        );
        if !enable {
            return Setpoint::OFF;
        }
        Setpoint {
            enable,
            reference,
            damp_unm: self.damp_unm,
        }
    }

    /// Writes the setpoint and the state into the link, stamped with the newest loop tick
    /// this supervisor has acted on (its heartbeat: the loop refuses an old setpoint).
    pub fn publish(&self, link: &mut Link) {
        link.setpoint = self.setpoint();
        link.state = self.state;
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
                if self.state == State::Init {
                    self.state = State::Calibrating;
                }
                false
            }
            Input::Calibrated { tick, offset_q8 } => {
                self.tick = tick;
                if matches!(self.state, State::Init | State::Calibrating) {
                    self.state = State::Approach;
                    self.phase_tick = tick;
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
            self.state,
            State::Init | State::Calibrating | State::Done | State::Fault(_)
        ) {
            return false;
        }
        self.tick = m.tick;
        self.jump_q16 = None;
        // 1..=64 (the loop never sums more): no division by zero or overflow.
        let n = m.n.clamp(1, 64) as i32;
        // Encoder plausibility: the back-EMF the bridge voltage and the current imply
        // must match the speed the encoder reports (a stuck or slipping encoder).
        let dcounts = i64::from(m.counts) - i64::from(self.last_counts);
        self.last_counts = m.counts;
        let (duty, ua) = (i64::from(m.duty / n), i64::from(m.ua / n));
        if let Some(f) = self.emf_check(dcounts, duty, ua) {
            self.fault(f);
            return false;
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
        self.on_sample(s);
        if let Some(f) = self.pending.take() {
            self.fault(f);
        }
        if let State::Fault(_) = self.state {
            return false;
        }
        let ready =
            self.state == State::Estimating && self.request_ready && self.tick == self.phase_tick;

        let (theta, t_ref) = (s.theta_a_urad, s.torque_ref_unm);
        match self.state {
            State::Seating | State::Step | State::Settling | State::Estimating | State::Holding => {
                let fast = self.vel.saturating_abs() > self.p.loss_speed_urad;
                if fast || self.lost(theta, t_ref).is_some() {
                    let d = sat_i32(i64::from(theta) - i64::from(self.contact.theta_a_urad));
                    self.fault(FaultReason::LossOfContact { dtheta_a_urad: d });
                }
            }
            _ => {}
        }
        let since = self.tick.wrapping_sub(self.phase_tick);
        match self.state {
            State::Approach
                if t_ref >= self.p.approach_max_unm || theta > self.p.approach_theta_max_urad =>
            {
                self.fault(FaultReason::NoContact);
            }
            State::Seating | State::Step | State::Settling
                if self.tick.wrapping_sub(self.contact_tick) > self.p.settle_timeout_ticks =>
            {
                self.fault(FaultReason::SettleTimeout);
            }
            State::Estimating if since > self.p.estimate_timeout_ticks => {
                self.fault(FaultReason::EstimateTimeout);
            }
            State::Releasing if t_ref <= 0 => {
                self.state = State::Done;
                let tick = self.tick;
                self.emit(Event::Released { tick });
            }
            _ => {}
        }
        ready && self.state == State::Estimating
    }

    /// Moves the estimate request out, once, after the step reported it ready.
    /// Hand it to [`run_estimate`](crate::run_estimate) in a low-priority task.
    pub fn take_request(&mut self) -> Option<EstimateRequest> {
        if !self.request_ready || self.state != State::Estimating {
            return None;
        }
        self.request_ready = false;
        let mut pre = Vec::new();
        core::mem::swap(&mut pre, &mut self.contact_hist);
        let mut path = Vec::new();
        core::mem::swap(&mut path, &mut self.path);
        Some(EstimateRequest {
            contact: self.contact,
            seat: self.seat,
            seat2: self.seat2,
            end: self.end,
            pre,
            path,
            sample_ticks: self.p.sample_ticks,
            path_stride: self.path_stride,
            delta_ta_cmd_unm: self.p.delta_ta_unm,
            estimator: self.p.estimator,
            dt_ns: self.p.dt_ns,
            detect_k_unm_per_rad: sat_i32(self.p.detect_k_unm_per_rad),
        })
    }

    /// Gives the estimate back (from the low-priority task). A refused estimate puts the
    /// state machine in the safe state. Ignored unless it is waiting for one. Publish the
    /// setpoint afterwards ([`Supervisor::publish`]) so the loop acts on it at once.
    pub fn deliver(&mut self, outcome: Result<EstimateResult, EstimateError>) {
        if self.state != State::Estimating {
            return;
        }
        let tick = self.tick;
        match outcome {
            Ok(r) => {
                self.result = Some(r);
                self.emit(Event::Estimated { tick, result: r });
                match self.p.after_estimate {
                    AfterEstimate::Hold => {
                        self.state = State::Holding;
                        self.emit(Event::Holding { tick });
                    }
                    AfterEstimate::Release => {
                        self.state = State::Releasing;
                        self.emit(Event::Releasing { tick });
                    }
                }
            }
            Err(EstimateError::Model(PtsError::BeyondTip)) if self.kc_locked() => {
                // Far stiffer than any single contact on the distal phalanx: the finger is
                // blocked at two points.
                let kc_unm_per_rad = self.kc_late_unm_per_rad();
                self.fault(FaultReason::SecondContact { kc_unm_per_rad });
            }
            Err(EstimateError::PathFit(PathFitError::SecondContact)) => {
                let kc_unm_per_rad = self.kc_late_unm_per_rad();
                self.fault(FaultReason::SecondContact { kc_unm_per_rad });
            }
            Err(error) => self.fault(FaultReason::EstimateOutOfRange { error }),
        }
    }

    /// Stiffness (µN·m/rad) of the second half of the step, seated again → settled.
    /// A second contact shows there.
    fn kc_late_unm_per_rad(&self) -> i32 {
        stiffness(&self.seat2, &self.end)
    }

    /// Whether the step's late stiffness says "locked" (above the second-contact threshold).
    fn kc_locked(&self) -> bool {
        i64::from(self.kc_late_unm_per_rad()) > self.p.second_k_unm_per_rad
    }

    /// Back-EMF check over one sample with `dcounts` encoder counts, mean duty and mean
    /// current (µA).
    fn emf_check(&mut self, dcounts: i64, duty: i64, ua: i64) -> Option<FaultReason> {
        let p = &self.p;
        let v_uv = duty
            .saturating_mul(p.bus_uv)
            .checked_div(i64::from(DUTY_MAX))
            .unwrap_or(0);
        let ri_uv = ua.saturating_mul(p.r_mohm) / 1000;
        let emf_uv = v_uv.saturating_sub(ri_uv);
        let enc_uv = dcounts.saturating_mul(p.emf_uv_per_count_q16) >> 16;
        if emf_uv.saturating_sub(enc_uv).saturating_abs() > p.emf_mismatch_uv {
            self.emf_bad = self.emf_bad.saturating_add(1);
        } else {
            self.emf_bad = 0;
        }
        if self.emf_bad >= p.emf_mismatch_samples {
            Some(FaultReason::EncoderMismatch {
                emf_mv: sat_i32(emf_uv / 1000),
                encoder_emf_mv: sat_i32(enc_uv / 1000),
            })
        } else {
            None
        }
    }

    /// Loss of contact: θa beyond what the contact allows. Before the second static point:
    /// a stiffness ≥ K_detect from the contact point. After it: 1.5× the displacement the
    /// early stiffness (seated → seated again) predicts from there (the path only stiffens).
    fn lost(&self, theta: i32, t_ref: i32) -> Option<i32> {
        let second_known = matches!(
            self.state,
            State::Step | State::Settling | State::Estimating | State::Holding
        );
        let k_early = i64::from(stiffness(&self.seat, &self.seat2));
        let (from, k, num, den) = if second_known && k_early > 0 && k_early < i64::from(i32::MAX) {
            (self.seat2, k_early, 3, 2)
        } else {
            (self.contact, self.p.detect_k_unm_per_rad, 1, 1)
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

    fn on_sample(&mut self, s: Sample) {
        match self.state {
            State::Approach => {
                self.hist.push(s);
                self.detect(s);
            }
            State::Seating => {
                self.path_push(s);
                self.hist.push(s);
                let top = self.contact.torque_unm.saturating_add(self.p.delta_ta_unm);
                if self.seat_stage == 1 && !self.slid {
                    let moved = i64::from(s.theta_a_urad) - i64::from(self.rest.theta_a_urad);
                    if moved >= i64::from(self.p.slide_min_urad) {
                        // Sliding forward: a little more, then hold for the first loading point.
                        self.slid = true;
                        self.target_unm = s
                            .torque_ref_unm
                            .saturating_add(self.p.slide_extra_unm)
                            .min(top);
                        self.phase_tick = self.tick;
                    }
                }
                let at_target = s.torque_ref_unm == self.target_unm;
                if at_target && self.tick.wrapping_sub(self.phase_tick) >= self.p.settle_min_ticks {
                    if let Some(p) = self.settled(self.phase_tick) {
                        let tick = self.tick;
                        let stage = self.seat_stage;
                        self.emit(Event::Seated {
                            tick,
                            stage,
                            theta_a_urad: p.theta_a_urad,
                            torque_unm: p.torque_unm,
                        });
                        match stage {
                            0 => {
                                // The impact is over; ramp until the drive slides forward.
                                self.rest = p;
                                self.slid = false;
                                self.seat_stage = 1;
                                self.target_unm = top;
                            }
                            1 if !self.slid => {
                                // T_a,c + ΔT_a reached without the drive sliding: ΔT_a is
                                // inside the stiction band, nothing to measure.
                                let d =
                                    i64::from(p.theta_a_urad) - i64::from(self.rest.theta_a_urad);
                                self.pending = Some(FaultReason::NoMotion {
                                    dtheta_a_urad: sat_i32(d),
                                });
                            }
                            1 => {
                                // The estimator extrapolates the path through the loading
                                // points back to the contact: it needs them to span at least
                                // the distance back (else the step is mostly stiction band).
                                let back =
                                    i64::from(self.target_unm) - i64::from(self.contact.torque_unm);
                                let span = i64::from(top) - i64::from(self.target_unm);
                                if span < back || span < i64::from(self.p.seat_above_unm) {
                                    let d = i64::from(p.theta_a_urad)
                                        - i64::from(self.rest.theta_a_urad);
                                    self.pending = Some(FaultReason::NoMotion {
                                        dtheta_a_urad: sat_i32(d),
                                    });
                                } else {
                                    self.seat = p;
                                    self.seat_stage = 2;
                                    let mid = (i64::from(self.target_unm) + i64::from(top)) / 2;
                                    self.target_unm = sat_i32(mid);
                                }
                            }
                            _ => {
                                self.seat2 = p;
                                self.state = State::Step;
                                self.target_unm = top;
                            }
                        }
                        self.phase_tick = self.tick;
                    }
                }
            }
            State::Step | State::Settling => {
                self.path_push(s);
                self.hist.push(s);
                if self.state == State::Step {
                    if s.torque_ref_unm == self.target_unm {
                        self.state = State::Settling;
                        self.phase_tick = self.tick;
                        let tick = self.tick;
                        self.emit(Event::StepDone { tick });
                    }
                } else if self.tick.wrapping_sub(self.phase_tick) >= self.p.settle_min_ticks {
                    self.check_settled();
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

    fn detect(&mut self, s: Sample) {
        let w = self.p.detect_window;
        let Some((dt, dth)) = self.window(w) else {
            return;
        };
        let stiff = dt >= i64::from(self.p.detect_min_rise_unm)
            && dt.saturating_mul(1_000_000) >= self.p.detect_k_unm_per_rad.saturating_mul(dth);
        if !stiff {
            // Free motion seen: from now on a stiff window means contact.
            if dth >= i64::from(self.p.detect_arm_urad)
                && dt.saturating_mul(1_000_000) < self.p.detect_k_unm_per_rad.saturating_mul(dth)
            {
                self.armed = true;
            }
            self.stiff_count = 0;
            return;
        }
        if !self.armed {
            return;
        }
        self.stiff_count = self.stiff_count.saturating_add(1);
        if self.stiff_count < self.p.detect_confirm {
            return;
        }
        // Contact. The finger's inertia carries it past the contact point before the stiffness
        // shows, so T_a,c is taken on the free-motion line (fitted well before the window)
        // at the θa of the detection: the bias is K_free × the overshoot (a few mN·m).
        // The estimator back-dates precisely from static points (estimate::contact_point).
        let w3 = 3 * w;
        let a = self.hist.back(w3).unwrap_or(s);
        let b = self
            .hist
            .back(self.hist.len.saturating_sub(1).min(w3 + 4 * w))
            .unwrap_or(a);
        let dth_ab = i64::from(a.theta_a_urad) - i64::from(b.theta_a_urad);
        let dt_ab = i64::from(a.torque_unm) - i64::from(b.torque_unm);
        let ext = (i64::from(s.theta_a_urad) - i64::from(a.theta_a_urad)).max(0);
        let tc = i64::from(a.torque_unm)
            + dt_ab
                .saturating_mul(ext)
                .checked_div(dth_ab)
                .unwrap_or(0)
                .clamp(
                    0,
                    i64::from(s.torque_unm.saturating_sub(a.torque_unm)).max(0),
                );
        let knee = Sample {
            tick: a.tick,
            theta_a_urad: s.theta_a_urad,
            torque_unm: sat_i32(tc),
            torque_ref_unm: s.torque_ref_unm,
        };
        self.contact = knee;
        // The event reports the contact instant itself, timed from the impact's signature.
        let at = self.contact_instant(w).unwrap_or(knee);
        self.contact_tick = self.tick;
        self.contact_hist.clear();
        let mut i = self.hist.len;
        while i > 0 {
            i -= 1;
            if let Some(h) = self.hist.back(i) {
                let _ = self.contact_hist.push(h);
            }
        }
        // Press gently (T_a,c + δ_seat) while the impact dies out; the first static point.
        let seat = knee.torque_unm.saturating_add(self.p.seat_above_unm);
        self.target_unm = seat;
        self.jump_q16 = Some(i64::from(seat) << 16);
        self.seat_stage = 0;
        self.path.clear();
        self.path_stride = 1;
        self.path_skip = 0;
        self.state = State::Seating;
        self.phase_tick = self.tick;
        let tick = self.tick;
        let ev = Event::ContactDetected {
            tick,
            contact_tick: at.tick,
            theta_a_urad: at.theta_a_urad,
            torque_unm: at.torque_unm,
            target_unm: knee.torque_unm.saturating_add(self.p.delta_ta_unm),
        };
        self.emit(ev);
    }

    /// The contact instant, from the impact's signature: after the contact the finger
    /// decelerates on the contact stiffness, so θa falls behind its free-motion trajectory
    /// by a deficit that grows as (t − t_c)³ at first (J θ̈ = −K v (t − t_c)). The free
    /// motion is the parabola in time through the samples 2w, 3w and 4w back (before any
    /// contact the detection can see: its delay is below 2w samples; the approach speed
    /// still creeps, so a line would not do). With d_n the deficit of the newest sample
    /// (t_n) and t_1 the time it crossed d_n/8, t_c = 2·t_1 − t_n. θa,c on the free-motion
    /// parabola and T_a,c (measured, friction included) on the line through the 2w and 4w
    /// samples, at t_c. `None` when the deficit is too small to time (< 4 encoder counts).
    fn contact_instant(&self, w: usize) -> Option<Sample> {
        let half = i64::from(self.p.sample_ticks / 2);
        let newest = self.hist.back(0)?;
        let a = self.hist.back(2 * w)?;
        let m = self.hist.back(3 * w)?;
        let b = self.hist.back(4 * w)?;
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
        let c1 = 3 * tha - 4 * thm + thb;
        let c2 = tha - 2 * thm + thb;
        let den = 2 * h * h;
        // θ(t) = θa + (c1·τ·h + c2·τ²)/(2h²), τ = t − ta (ticks; sample labels).
        let free = |t: i64| -> i64 {
            let tau = t - ta;
            tha.saturating_add(
                c1.saturating_mul(tau)
                    .saturating_mul(h)
                    .saturating_add(c2.saturating_mul(tau).saturating_mul(tau))
                    .checked_div(den)
                    .unwrap_or(0),
            )
        };
        let deficit = |s: &Sample| -> i64 { free(i64::from(s.tick)) - i64::from(s.theta_a_urad) };
        let dn = deficit(&newest);
        let min = (i64::from(self.p.urad_per_count_q16) * 4) >> 16;
        if dn < min.max(8) {
            return None;
        }
        let d1 = dn / 8;
        // Newest upward crossing of d1: samples i (≥ d1) and i + 1 (< d1).
        let mut i = 0usize;
        let mut hi = newest;
        let t1 = loop {
            if i + 1 >= 2 * w {
                return None;
            }
            let lo = self.hist.back(i + 1)?;
            let dl = deficit(&lo);
            if dl < d1 {
                let dh = deficit(&hi);
                let (tl, th) = (i64::from(lo.tick), i64::from(hi.tick));
                break tl
                    + (d1 - dl)
                        .saturating_mul(th - tl)
                        .checked_div(dh - dl)
                        .unwrap_or(0);
            }
            hi = lo;
            i += 1;
        };
        // Sample labels are the interval's end: the averages sit `half` earlier.
        let tn = i64::from(newest.tick);
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
            theta_a_urad: sat_i32(free(label)),
            torque_unm: sat_i32(tq),
            torque_ref_unm: newest.torque_ref_unm,
        })
    }

    /// Mean (θa, T_a) over the settle window when θa stayed within the settle band and every
    /// sample of the window is newer than `since`.
    fn settled(&self, since: u32) -> Option<Sample> {
        let w = self.p.settle_window;
        let mut lo = i32::MAX;
        let mut hi = i32::MIN;
        let mut st = 0i64;
        let mut sth = 0i64;
        for i in 0..w {
            let s = self.hist.back(i)?;
            if s.tick < since {
                return None;
            }
            lo = lo.min(s.theta_a_urad);
            hi = hi.max(s.theta_a_urad);
            st += i64::from(s.torque_unm);
            sth += i64::from(s.theta_a_urad);
        }
        if i64::from(hi) - i64::from(lo) > i64::from(self.p.settle_band_urad) {
            return None;
        }
        let n = w as i64;
        Some(Sample {
            tick: self.tick,
            theta_a_urad: sat_i32(sth.checked_div(n).unwrap_or(0)),
            torque_unm: sat_i32(st.checked_div(n).unwrap_or(0)),
            torque_ref_unm: self.t_ref_unm,
        })
    }

    fn check_settled(&mut self) {
        let Some(end) = self.settled(self.phase_tick) else {
            return;
        };
        self.end = end;
        // A second contact locks the finger: the late half of the step is far stiffer than
        // any single contact, or far stiffer than the early half (a proximal first contact,
        // K ≈ K_c,prox, then the distal phalanx touching too).
        // The finger did not move over the late half: held by transmission stiction (ΔT_a
        // below the friction band) or locked; the step cannot measure a stiffness.
        let dth_late = i64::from(end.theta_a_urad) - i64::from(self.seat2.theta_a_urad);
        if dth_late < i64::from(self.p.min_motion_urad) {
            self.pending = Some(FaultReason::NoMotion {
                dtheta_a_urad: sat_i32(dth_late),
            });
            return;
        }
        let late = i64::from(self.kc_late_unm_per_rad());
        let early = i64::from(stiffness(&self.seat, &self.seat2));
        if late > self.p.second_k_unm_per_rad
            || late > early.saturating_mul(i64::from(self.p.second_ratio))
        {
            self.pending = Some(FaultReason::SecondContact {
                kc_unm_per_rad: sat_i32(late),
            });
            return;
        }
        self.state = State::Estimating;
        self.phase_tick = self.tick;
        self.request_ready = true;
        let tick = self.tick;
        let ev = Event::Settled {
            tick,
            theta_a_urad: self.end.theta_a_urad,
            torque_unm: self.end.torque_unm,
            path_len: self.path.len() as u16,
        };
        self.emit(ev);
    }

    fn path_push(&mut self, s: Sample) {
        if self.path_skip > 0 {
            self.path_skip -= 1;
            return;
        }
        if self.path.is_full() {
            // Keep the whole span: drop every other sample, double the stride.
            let mut j = 0;
            for i in (0..self.path.len()).step_by(2) {
                if let Some(v) = self.path.get(i).copied() {
                    if let Some(slot) = self.path.get_mut(j) {
                        *slot = v;
                    }
                    j += 1;
                }
            }
            self.path.truncate(j);
            self.path_stride = self.path_stride.saturating_mul(2);
        }
        let _ = self.path.push(s);
        self.path_skip = self.path_stride.saturating_sub(1);
    }
}
