//! The one place that names the controller and the simulated plant the app runs.
pub use crate::standin::{
    run_estimate, Controller, EstimateRequest, Event, Hardware, State, DUTY_MAX,
};

/// The simulated finger (QEMU board and host runner).
pub type Plant = crate::standin::ToyPlant;

/// The plant of the scene chosen at build time.
pub fn new_plant() -> Plant {
    crate::standin::ToyPlant::new()
}

/// The controller, configured for the finger and drive of this build.
pub fn new_controller() -> Controller {
    Controller::new()
}

/// True once the grasp has nothing left to do (estimate delivered and holding, or faulted).
pub fn finished(state: State) -> bool {
    matches!(state, State::Hold | State::Fault)
}
