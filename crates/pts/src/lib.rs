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
pub mod pathfit;
pub mod real;
pub mod table;

pub use error::PtsError;
pub use finger::Finger;
pub use model::{Closure, Config, Contact, Estimate, Model, Phalanx};
pub use real::Real;

/// The numeric back end of the firmware's estimator, `table::FreeTable<FirmwareReal>`
/// (chosen from `cargo xtask bench`): `f32` where the core has a single-precision FPU
/// (thumbv7em-none-eabihf: ≈ 820 instructions per estimate, k2 within 1.4e-5·l2 of f64),
/// Q32.32 fixed point everywhere else (thumbv6m: no FPU, where soft-float f32 costs more
/// than [`fixed::Fx32`]; and the host, where Fx32 is what the target-independent tests pin).
#[cfg(target_abi = "eabihf")]
pub type FirmwareReal = f32;
/// The numeric back end of the firmware's estimator (see the `eabihf` definition).
#[cfg(not(target_abi = "eabihf"))]
pub type FirmwareReal = fixed::Fx32;
