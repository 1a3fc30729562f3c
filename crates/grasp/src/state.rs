//! What the controller reports to the outside: its [`State`], the [`Event`] of every
//! transition and the [`FaultReason`] of the safe state. A module of their own so that the
//! loop ([`crate::control_loop`]) and the state machine ([`crate::controller`]) both use them
//! without importing each other.

use crate::estimate::{EstimateError, EstimateResult};

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
    /// A second contact: the stiffness over the second half of the step (over the whole step
    /// without seating; and K̂c beyond a tip contact) is above that of any single contact, or
    /// far above the first half's: the finger is locked.
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
    /// Settled; the estimate request is out, waiting for
    /// [`Controller::deliver`](crate::Controller::deliver).
    Estimating,
    /// Estimate delivered; holding the torque.
    Holding,
    /// Estimate delivered; ramping the torque down.
    Releasing,
    /// Torque down; a small opening torque takes the finger back toward rest.
    Opening,
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
