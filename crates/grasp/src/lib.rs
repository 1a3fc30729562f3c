//! The grasp controller of a PTS finger: the part of the firmware that turns encoder counts
//! and shunt current into a contact estimate.
//!
//! * [`Hardware`]: what a board (real, QEMU sim, or the host plant adapter) provides.
//! * The controller in two halves joined by a [`Link`]: the [`ControlLoop`] (one
//!   [`ControlLoop::tick`] per control period: sensor conditioning ([`sensors`]), the torque
//!   loop ([`torque_loop`]), the faults that must be caught within a tick, sums per sample; no
//!   division) and the [`Supervisor`] (the grasp state machine and the rest of the fault
//!   supervision, one step per finished sample, every [`Event`] of a transition). The firmware
//!   runs them in two tasks ([`Controller::into_parts`]); [`Controller`] ticks both together
//!   for the host with the same numbers. Integer arithmetic only, no allocation, no panic
//!   path: `tests/no_float.rs` checks the thumbv6m assembly of [`tick_dyn`], [`loop_tick_dyn`]
//!   and [`supervise_dyn`].
//! * [`run_estimate`]: the low-priority part. It takes the [`EstimateRequest`] that `tick()`
//!   hands out once the step has settled and runs the [`Estimator`] the configuration names
//!   (the paper's two-point method, or `pathfit` on the same samples) as the firmware does,
//!   through [`two_point_fw`] or [`path_fit_fw`] (integers and [`EstReal`] =
//!   `pts::FirmwareReal`, no floating point); the result goes back through
//!   [`Controller::deliver`].
//!
//! The state machine, and why it looks like this. The drive's reflected rotor inertia
//! (J·N² ≈ 0.066 kg·m² at the base link for an RE10 on 3072:1) makes the finger under pure
//! torque control an undamped oscillator on its contact stiffness, and turns the contact
//! into an impact that carries θa ~10 mrad past the contact point. So:
//!
//! 1. **Calibrate**: bridge off, the ADC offset is averaged (sensor fault if implausible).
//! 2. **Approach**: the torque reference ramps up while the actuator speed is below a limit
//!    (0.25 rad/s); the loop adds virtual damping T_cmd = T_ref − B·ω̂a (B = 1 N·m·s/rad),
//!    which changes nothing at rest.
//! 3. **Contact**: the measured ΔT_a/Δθa over a 40 ms window exceeds 1.5 N·m/rad
//!    (between free motion ≈ 0.55–0.9 and a proximal contact ≈ 2.6) twice in a row.
//!    Detection delay on the plant: mean 37 ms, max 57 ms after the true contact.
//! 4. **Seating**, only with [`ControllerConfig::seating`] (off by default): the reference
//!    is held at T_a,c + δ (δ = 0.01 N·m) until θa is static (first static point), then
//!    raised until the drive slides forward and held for two loading points.
//! 5. **Step**: raised to T_a,c + ΔT_a (by default a 4 N·m/s ramp from T_a,c at the
//!    detection) and **Settling** until static (end point). Static = θa within 50 µrad for
//!    100 ms.
//! 6. **Estimating**: the request (static points, history before contact, path samples) is
//!    out; the path fit (the default) fits the whole loading path from the contact instant,
//!    the two-point method inverts ΔT_a/Δθa between the static points. Without seating, a
//!    refusal or an answer that locates no distal contact is first probed (**Step** again,
//!    half a step higher) to name a finger locked at two points. **Holding** or
//!    **Releasing** → **Done**.
//!
//! Faults (→ [`State::Fault`], bridge off, reason in [`FaultReason`]): encoder jump or
//! encoder/back-EMF mismatch (stuck encoder), ADC code or offset, over-current, stall,
//! no contact within the torque ceiling or the finger's range, settle or estimate timeout,
//! no motion over the late half of the step (friction or locked), second contact (late
//! half of the step far stiffer than any contact or than the early
//! half), loss of contact (θa beyond what the contact stiffness allows, or fast), and an
//! estimate out of range.
//!
//! Units: SI scaled to integers and carried in names: `_urad` (µrad), `_unm` (µN·m),
//! `_ua` (µA), `_um` (µm), `_unm_per_rad` (µN·m/rad), ticks of the control period.
//! θa is the absolute model angle of MODEL.md (−0.8503608 rad at rest).
#![no_std]
#![forbid(unsafe_code)]

#[cfg(feature = "std")]
extern crate std;

pub mod calibrate;
pub mod config;
pub mod control_loop;
pub mod controller;
pub mod estimate;
pub mod rest;
pub mod sensors;
pub mod state;
pub mod torque_loop;

pub use config::{AfterEstimate, ControllerConfig, DriveConfig, Estimator, FingerRest, StepShape};
pub use control_loop::{
    ControlLoop, Input, Link, LoopOutput, Reference, SampleSums, Setpoint, TorqueQ16, LINK_SAMPLES,
};
pub use controller::{Controller, Supervisor, TickOutput};
pub use estimate::{
    path_fit_fw, path_table, run_estimate, run_estimate_fw, run_estimate_with,
    run_estimate_with_reference, two_point_fw, two_point_table, EstNum, EstReal, EstimateError,
    EstimateRequest, EstimateResult, Located, Quality, Sample, TwoPointTable, PATH_CAPACITY,
};
pub use rest::{RestCheck, RestReport};
pub use state::{Event, FaultReason, State};

/// Full-scale PWM duty: `set_duty(DUTY_MAX)` applies +100 % of the bus voltage (flexion),
/// `set_duty(-DUTY_MAX)` −100 %.
pub const DUTY_MAX: i16 = 10_000;

/// What the controller needs from a board. Implemented by the real board, the QEMU sim
/// board and the host plant adapter. Every method is called once per tick at most, from
/// the control task; none may block.
pub trait Hardware {
    /// Quadrature ×4 count of the motor-shaft encoder, wrapping at 2¹⁶ (counts).
    fn encoder_count(&mut self) -> u16;
    /// 12-bit ADC code (0‥4095) of the shunt-current amplifier.
    fn current_raw(&mut self) -> u16;
    /// PWM duty of the H-bridge, signed, clamped by the caller to ±[`DUTY_MAX`]
    /// (positive = flexion torque).
    fn set_duty(&mut self, duty: i16);
    /// Safe state, immediately: bridge disabled (all switches off, motor coasting).
    fn bridge_off(&mut self);
}

/// [`Controller::tick`] through a trait object: one concrete, non-generic function, so the
/// target build has a symbol to measure (instruction counts, size) and to check for
/// soft-float calls (`crates/grasp/tests/no_float.rs`).
#[inline(never)]
pub fn tick_dyn(controller: &mut Controller, hw: &mut dyn Hardware) -> TickOutput {
    controller.tick(hw)
}

/// [`ControlLoop::tick`] through a trait object: the sampling task's work on the target, as
/// one symbol to count and to check for soft-float and panic calls.
#[inline(never)]
pub fn loop_tick_dyn(lp: &mut ControlLoop, link: &mut Link, hw: &mut dyn Hardware) -> LoopOutput {
    lp.tick(hw, link)
}

/// [`Supervisor::service`] as one symbol (the state machine's step, below the sampling task).
#[inline(never)]
pub fn supervise_dyn(sup: &mut Supervisor, link: &mut Link) -> bool {
    sup.service(link)
}
