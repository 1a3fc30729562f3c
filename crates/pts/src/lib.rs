//! Proprioceptive tactile sensing (PTS) for a two-phalanx linkage-driven finger.
//!
//! The kinetostatic model of Belzile & Birglen with the corrections of `MODEL.md`:
//! four-bar closure, transmission x2 and dx2/dθ2, the stiffness at the actuator (Eq. 2
//! closed forms), free motion, the inversion of a measured stiffness into a contact
//! location, and the paper's two-point estimator.
//!
//! One API, several numeric back ends: [`Model<f64>`] is the reference, [`Model<f32>`]
//! and the fixed-point types of [`fixed`] run on the target. No allocation, no panics:
//! every failure is a [`PtsError`].
#![no_std]
#![forbid(unsafe_code)]
// `!(a > b)` is deliberate throughout: it is true for NaN, so a NaN fails every range check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

#[cfg(feature = "std")]
pub mod config;
mod error;
mod finger;
pub mod fixed;
pub mod model;
pub mod real;
pub mod table;

pub use error::PtsError;
pub use finger::{Finger, Stops};
pub use model::{Closure, Config, Contact, Estimate, Model, Phalanx};
pub use real::Real;

/// The numeric back end of the firmware's estimator: Q32.32 fixed point, on every target.
///
/// The product is a fixed-point solver (issue 2); `cargo xtask bench` also measures f32,
/// which on the Cortex-M4F FPU is cheaper (table+f32 ≈ 380 instructions per estimate
/// against ≈ 1,700 for table+Fx32), and keeps it as the comparison.
pub type FirmwareReal = fixed::Fx32;
