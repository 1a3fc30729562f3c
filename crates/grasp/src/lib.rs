//! The grasp controller of a PTS finger: the part of the firmware that turns encoder counts
//! and shunt current into a contact estimate.
//!
//! * [`Hardware`]: what a board (real, QEMU sim, or the host plant adapter) provides.
//! * [`Controller`]: one [`Controller::tick`] per control period, integer arithmetic only
//!   (no floating point, no allocation): sensor conditioning, the torque (current) PI loop,
//!   the grasp state machine (calibrate → approach → contact → ΔT_a step → settle → estimate
//!   → hold/release) and fault supervision. Every transition is an [`Event`].
//! * [`run_estimate`]: the low-priority part. It takes the [`EstimateRequest`] that `tick()`
//!   hands out once the step has settled, runs the paper's two-point method through
//!   [`pts`] and gives back an [`EstimateResult`] for [`Controller::deliver`].
//!
//! Units: SI scaled to integers and carried in names: `_urad` (µrad), `_unm` (µN·m),
//! `_ua` (µA), `_um` (µm), `_unm_per_rad` (µN·m/rad), ticks of the control period.
//! θa is the absolute model angle of MODEL.md (−0.8503608 rad at rest).
#![no_std]
#![forbid(unsafe_code)]

pub mod config;
pub mod controller;
pub mod estimate;
pub mod sensors;
pub mod torque_loop;

pub use config::{AfterEstimate, ControllerConfig, DriveConfig, Estimator, StepShape};
pub use controller::{Controller, Event, FaultReason, State, TickOutput};
pub use estimate::{
    run_estimate, run_estimate_with, EstReal, EstimateError, EstimateRequest, EstimateResult,
    Located, Quality, Sample, PATH_CAPACITY,
};

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
