//! The simulated PTS finger: an independent plant to judge the estimator and the firmware against.
//!
//! `no_std` + `libm`, f64 everywhere, no allocation, no panics on any input (typed
//! [`PlantError`]s). SI units: m, rad, N, N·m, A, V, s. Angles follow MODEL.md: θa is the
//! absolute model angle of the input crank (−0.8503608 rad at rest), flexion positive.
//!
//! * [`kin`]: quasi-static kinetostatics of the two-phalanx linkage finger against a vertex or a
//!   cylinder and the joint stops (own formulation, see the module doc), [`track`]: events
//!   located by bisection, [`path`]: the frictionless path after contact ([`quasi_static_path`]).
//! * [`drive`]: Maxon RE10 motor + GP10A-class gearhead + cable stage, friction, backlash.
//! * [`sensors`]: quadrature encoder and shunt/ADC current sensor, seeded noise.
//! * [`Plant`]: all of it stepped at the control rate. [`scenes`]: built-in scenes.
#![no_std]
#![forbid(unsafe_code)]
// `!(x > lim)` is deliberate: it also rejects NaN, which `x <= lim` would let through.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

#[cfg(feature = "std")]
extern crate std;

pub mod drive;
mod error;
pub mod geom;
pub mod kin;
pub mod path;
mod plant;
pub mod scene;
pub mod scenes;
pub mod sensors;
#[cfg(feature = "std")]
pub mod toml_scene;
#[cfg(feature = "std")]
pub mod trace;
pub mod track;

pub use error::PlantError;
pub use geom::FingerGeom;
pub use kin::{Object, Phalanx};
pub use path::{quasi_static_path, quasi_static_path_with, ContactSpec, PathResult, PathSample};
pub use plant::{ContactState, Fault, Plant, Truth};
pub use scene::Scene;
pub use track::{Event, EventKind, EVENT_TOL_RAD};
