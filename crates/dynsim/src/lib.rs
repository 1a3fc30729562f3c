//! A second, independent dynamic simulation of the PTS finger, built on the rapier2d physics engine.
//!
//! It shares no code with the rest of the workspace: the linkage is set up from the Table 1 geometry
//! ([`linkage`]), its dynamics (joints, springs as joint motors, drive friction, contact with impact
//! and friction) are the engine's ([`sim`]), and [`grasp`] runs a recorded-style grasp and writes it
//! as a `t_s,theta_a_rad,torque_nm` CSV at 1 kHz with a JSON ground-truth file taken from the
//! engine's own contact points.

pub mod grasp;
pub mod grid;
pub mod linkage;
pub mod sim;
