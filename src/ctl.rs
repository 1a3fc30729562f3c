//! The controller this firmware runs (crates/grasp) and how it is configured: the one place
//! that knows where the drive constants come from.
//!
//! * board: [`grasp::DriveConfig::DEFAULT`] (the prototype drive), with the drive, motor,
//!   encoder and current-sense values of the finger file when `FINGER_TOML` was given at build
//!   time (build.rs turns them into `config::FINGER_DRIVE`);
//! * simulated board (QEMU and the host runner): the nominal constants of the scene's drive and
//!   sensors, exactly what a firmware for that hardware would be built with (the plant's error
//!   terms stay unknown to it).

pub use grasp::{ControllerConfig, DriveConfig, State};
use grasp::{EstimateError, EstimateRequest, EstimateResult, Estimator};
use pathfit::PathFitError;
use pts::PtsError;

/// The estimator of this build, fixed at build time (feature `path-fit`, or its alias
/// `FINGER_FW_ESTIMATOR=two-point|path-fit`;
/// default: the controller's default). `grasp::run_estimate` picks it at run time from the
/// request, which links both; choosing here lets the linker drop the other one: the path fit
/// is much larger fixed-point code (and its table is built at init).
pub const ESTIMATOR: Estimator = match crate::config::ESTIMATOR {
    Some(e) => e,
    None => ControllerConfig::DEFAULT.estimator,
};

/// The torque step ΔT_a after contact (N·m): `FINGER_FW_DELTA_TA_NM` at build time, default
/// 0.8 N·m, what grasp's closed-loop Table 2 test uses and the more accurate step. The
/// controller's own default (0.2) is answered without seating; with seating (`seating on`) it
/// mostly lies inside the realistic drive's stiction band (≈ 0.11 N·m) once the contact is
/// seated, and grasp reports a step that does not move the finger (NoMotion).
pub const DELTA_TA_NM: f64 = match crate::config::DELTA_TA_NM {
    Some(v) => v,
    None => 0.8,
};

/// The table this build's estimate runs on, for the build's finger: the path fit's
/// (`cfg(fw_path_fit)`; on the board built at build time, a constant in flash:
/// `config::PATH_TABLE`), or the two-point method's free-motion table (built at build time, a
/// constant in flash: `config::FREE_TABLE`).
#[cfg(all(fw_path_fit, target_os = "none", not(feature = "qemu")))]
pub type EstimatorTable = &'static pathfit::q::PathTable;
/// The table this build's estimate runs on, for the build's finger: the path fit's
/// (`cfg(fw_path_fit)`; on the simulated board built at init, for its scene's control
/// period), or the two-point method's free-motion table (built at build time, a constant in
/// flash: `config::FREE_TABLE`).
#[cfg(all(fw_path_fit, any(not(target_os = "none"), feature = "qemu")))]
pub type EstimatorTable = pathfit::q::PathTable;
/// The table this build's estimate runs on, for the build's finger: the path fit's
/// (`cfg(fw_path_fit)`, built at init), or the two-point method's free-motion table (built at
/// build time, a constant in flash: `config::FREE_TABLE`).
#[cfg(not(fw_path_fit))]
pub type EstimatorTable = &'static grasp::estimate::TwoPointTable;

/// Where `init` keeps the estimator's table: a C-like enum whose empty state is all zero
/// bits, so the slot lands in .bss (an `Option` would use a niche and go to .data, costing
/// the same again in flash).
#[repr(u8)]
#[cfg_attr(not(target_os = "none"), allow(dead_code))]
#[allow(clippy::large_enum_variant)] // a static slot: no allocator, the size is the point
pub enum TableSlot {
    /// No table (not built yet, or the finger is outside the table's formats).
    Empty = 0,
    /// The table.
    Built(EstimatorTable),
}

#[cfg_attr(not(target_os = "none"), allow(dead_code))]
impl TableSlot {
    /// Keeps the table built at init.
    pub fn fill(&mut self, table: Option<EstimatorTable>) {
        if let Some(t) = table {
            *self = TableSlot::Built(t);
        }
    }

    /// The table, if built.
    pub fn get(&self) -> Option<&EstimatorTable> {
        match self {
            TableSlot::Built(t) => Some(t),
            TableSlot::Empty => None,
        }
    }
}

// The table and the estimator agree.
const _: () = assert!(cfg!(fw_path_fit) == matches!(ESTIMATOR, Estimator::PathFit));

/// The estimator's table for a finger and its drive (control period, measurement model): the
/// path fit's, on the board the build-time table (`config::PATH_TABLE`: the build's finger and
/// drive at the board's period, `DriveConfig::DEFAULT.dt_s`; the init that built it in RAM
/// linked 5.3 KB of builder), on the simulated board built at init (f64 arithmetic, once), or
/// the build-time two-point table (the build's finger); `None` when the finger is outside the
/// table's formats or, on the board, is not the table's finger or period (the estimate then
/// reports that error).
pub fn estimator_table(finger: &pts::Finger, drive: &DriveConfig) -> Option<EstimatorTable> {
    #[cfg(all(fw_path_fit, target_os = "none", not(feature = "qemu")))]
    // The board's drive is always the build's (`board_drive`), the table's.
    return crate::config::PATH_TABLE
        .as_ref()
        .filter(|t| t.model().finger == *finger && t.tick_ns() == (drive.dt_s * 1e9) as u32);
    #[cfg(all(fw_path_fit, any(not(target_os = "none"), feature = "qemu")))]
    return grasp::path_table(finger, drive, (drive.dt_s * 1e9) as u32).ok();
    #[cfg(not(fw_path_fit))]
    {
        let _ = (finger, drive);
        crate::config::FREE_TABLE.as_ref()
    }
}

/// The estimate task's work for a settled step: the build's estimator on the table from
/// [`estimator_table`] (`grasp::estimate::two_point_fw` or `path_fit_fw`, the functions
/// `cargo xtask bench` counts; same numbers as `grasp::run_estimate` for the controller's
/// finger). `_finger` is the controller's finger, which the table was built for.
pub fn run_estimate(
    _finger: &pts::Finger,
    req: &EstimateRequest,
    table: Option<&EstimatorTable>,
) -> Result<EstimateResult, EstimateError> {
    let Some(t) = table else {
        return Err(match ESTIMATOR {
            Estimator::PathFit => EstimateError::PathFit(PathFitError::Model(PtsError::OutOfRange)),
            Estimator::TwoPoint => EstimateError::Model(PtsError::OutOfRange),
        });
    };
    #[cfg(fw_path_fit)]
    return grasp::estimate::path_fit_fw(t, req);
    #[cfg(not(fw_path_fit))]
    grasp::estimate::two_point_fw(t, req)
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
#[cfg_attr(not(target_os = "none"), allow(dead_code))] // the host runner names its estimator
/// The estimators this build can run at run time: the two-point method always, the path fit
/// when its table is built in (feature `path-fit`).
pub const AVAILABLE: &[Estimator] = match ESTIMATOR {
    Estimator::PathFit => &[Estimator::TwoPoint, Estimator::PathFit],
    Estimator::TwoPoint => &[Estimator::TwoPoint],
};

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
/// The estimate with the estimator the request names (device mode: chosen per grasp): the
/// build's own estimator on its table ([`run_estimate`]); in a path-fit build the two-point
/// method too, on the path fit's table ([`two_point_on_path_table`]); a two-point build refuses
/// the path fit (its table is not built in). A path-fit answer carries the two-point k2 beside
/// it for reference.
pub fn run_estimate_as(
    finger: &pts::Finger,
    req: &EstimateRequest,
    table: Option<&EstimatorTable>,
) -> Result<EstimateResult, EstimateError> {
    match (req.estimator, ESTIMATOR) {
        (Estimator::TwoPoint, Estimator::TwoPoint) => run_estimate(finger, req, table),
        (Estimator::PathFit, Estimator::PathFit) => {
            let mut r = run_estimate(finger, req, table)?;
            // The paper's method beside the fit, for reference; its failure does not fail
            // the fit's answer.
            r.two_point_k2_um = two_point_on_path_table(req, table)
                .ok()
                .and_then(|t| t.k2_um);
            Ok(r)
        }
        (Estimator::TwoPoint, Estimator::PathFit) => two_point_on_path_table(req, table),
        (Estimator::PathFit, Estimator::TwoPoint) => Err(EstimateError::PathFit(
            PathFitError::Model(PtsError::OutOfRange),
        )),
    }
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
/// The two-point estimate in a path-fit build, whose two-point table is not built in: on the
/// path fit's table (`grasp::estimate::two_point_q`: its free motion and its model, no model
/// solve of its own). A two-point build answers from its own table ([`run_estimate`]).
fn two_point_on_path_table(
    req: &EstimateRequest,
    table: Option<&EstimatorTable>,
) -> Result<EstimateResult, EstimateError> {
    #[cfg(fw_path_fit)]
    if let Some(t) = table {
        return grasp::estimate::two_point_q(t, req).map_err(EstimateError::Model);
    }
    let _ = (req, table);
    Err(EstimateError::Model(PtsError::OutOfRange))
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
/// The protocol's view of an estimator.
pub fn proto_estimator(e: Estimator) -> proto::Estimator {
    match e {
        Estimator::TwoPoint => proto::Estimator::TwoPoint,
        Estimator::PathFit => proto::Estimator::PathFit,
    }
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
/// The build's settings: what a power-up grasp uses and what device mode starts from.
pub fn default_settings() -> proto::Settings {
    let c = ControllerConfig::DEFAULT;
    proto::Settings {
        layout: proto::Settings::LAYOUT,
        delta_ta_nm: DELTA_TA_NM,
        step_shape: match c.step_shape {
            grasp::StepShape::Step => proto::StepShape::Step,
            grasp::StepShape::Ramp(r) => proto::StepShape::RampNmPerS(r),
        },
        estimator: proto_estimator(ESTIMATOR),
        approach_speed_rad_s: c.approach_speed_max_rad_s,
        approach_max_nm: c.approach_max_nm,
        telemetry_hz: 50,
        seating: c.seating,
    }
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
/// The controller configuration for a drive and the host's settings (device mode, and the
/// host runner's reference of it).
pub fn config_with(drive: DriveConfig, s: &proto::Settings) -> ControllerConfig {
    let mut c = config(drive).with_delta_ta(s.delta_ta_nm);
    c.estimator = match s.estimator {
        proto::Estimator::TwoPoint => Estimator::TwoPoint,
        proto::Estimator::PathFit => Estimator::PathFit,
    };
    c.step_shape = match s.step_shape {
        proto::StepShape::Step => grasp::StepShape::Step,
        proto::StepShape::RampNmPerS(r) => grasp::StepShape::Ramp(r),
    };
    c.approach_speed_max_rad_s = s.approach_speed_rad_s;
    c.approach_max_nm = s.approach_max_nm;
    c.seating = s.seating;
    c
}

/// The controller for a configuration of this build's finger (`cfg.finger` is
/// `config::FINGER`): checked and converted by `grasp`, the finger's part of the check done at
/// build time (`config::FINGER_REST`), so the firmware links no model for it.
pub fn controller(cfg: ControllerConfig) -> Result<grasp::Controller, grasp::config::ConfigError> {
    grasp::Controller::new_for(cfg, &crate::config::FINGER_REST)
}

#[cfg_attr(all(target_os = "none", not(feature = "device")), allow(dead_code))] // device mode
#[cfg_attr(not(target_os = "none"), allow(dead_code))] // the calibration sweep is device mode's
/// The integer parameters of a configuration of this build's finger (as [`controller`]).
pub fn params(cfg: &ControllerConfig) -> Result<grasp::config::Params, grasp::config::ConfigError> {
    cfg.params_for(&crate::config::FINGER_REST)
}

/// True once the grasp has nothing left to do: estimate delivered (holding or released) or
/// the safe state.
pub fn finished(state: State) -> bool {
    matches!(state, State::Holding | State::Done | State::Fault(_))
}

/// Exit status of a finished run: 0 estimate delivered, 2 controller fault (bridge off).
pub fn status(state: State) -> i32 {
    match state {
        State::Fault(_) => 2,
        _ => 0,
    }
}

/// The drive of the build's finger: the finger file's constants when one was given at build
/// time, the controller's default drive otherwise; the encoder zeroed at the finger's rest.
pub fn file_drive() -> DriveConfig {
    let mut d = DriveConfig::DEFAULT;
    if let Some(f) = crate::config::FINGER_DRIVE {
        d.gear_ratio = f.gear_ratio;
        d.efficiency = f.efficiency;
        d.kt_nm_per_a = f.kt_nm_per_a;
        d.resistance_ohm = f.resistance_ohm;
        d.bus_v = f.supply_v;
        d.encoder_counts_per_rev = f.counts_per_rev;
        d.amps_per_code = f.amps_per_count;
        d.adc_zero_code = f.zero_count;
        d.inertia_kgm2 = f.inertia_kgm2;
        d.backlash_rad = f.backlash_rad;
        d.priors = f.priors;
    }
    d.theta_a_rest_rad = crate::config::FINGER_THETA_A_REST_RAD;
    d
}

/// Drive constants for the real board.
#[cfg(all(target_os = "none", not(feature = "qemu")))]
pub fn board_drive() -> DriveConfig {
    file_drive()
}

/// A simulated scene as the build's finger: with a finger file given at build time, the plant
/// is built from the same geometry, springs and drive constants the controller uses.
#[cfg(any(feature = "qemu", not(target_os = "none")))]
pub fn finger_scene(scene: plant::Scene) -> plant::Scene {
    match crate::config::FINGER_DRIVE {
        Some(_) => sim_board::scene_for_finger(
            scene,
            &crate::config::FINGER,
            &file_drive(),
            &crate::config::FINGER_STOPS,
        ),
        None => scene,
    }
}

/// The controller's view of a simulated scene's drive and sensors (nominal constants).
#[cfg(any(feature = "qemu", not(target_os = "none")))]
pub fn scene_drive(scene: &plant::Scene) -> DriveConfig {
    DriveConfig {
        // The estimate's priors are the build's finger file's, whatever the scene.
        priors: file_drive().priors,
        ..sim_board::scene_drive(scene, crate::config::FINGER_THETA_A_REST_RAD)
    }
}

/// Whether this build finds the rest pose before the encoder is zeroed (grasp::rest):
/// `FINGER_FW_REST_CHECK=on|off` at build time; by default on the board (a reset or a power-up
/// can leave the finger anywhere) and off on the simulated board, whose scenes start at rest
/// and whose recorded figures were measured without it (a scene with
/// `faults.power_up_offset_rad` needs it on).
pub const REST_CHECK: bool = match crate::config::REST_CHECK {
    Some(on) => on,
    None => cfg!(all(target_os = "none", not(feature = "qemu"))),
};

/// The board's rest check: the build's finger against its stops (the finger file's `[stops]`,
/// by default just below its rest angles), its drive's backlash; built at build time.
pub const BOARD_REST_CHECK: grasp::RestCheck = crate::config::FINGER_REST_CHECK;

/// The controller configuration for a drive: the build's finger (and its current limit when a
/// finger file was given), grasp's defaults otherwise; the board's rest check when
/// [`REST_CHECK`] (the simulated board replaces it by its scene's, [`with_scene_rest_check`]).
pub fn config(drive: DriveConfig) -> ControllerConfig {
    let overcurrent_a = match crate::config::FINGER_DRIVE {
        Some(f) => f.max_current_a,
        None => ControllerConfig::DEFAULT.overcurrent_a,
    };
    ControllerConfig {
        finger: crate::config::FINGER,
        drive,
        estimator: ESTIMATOR,
        overcurrent_a,
        rest_check: REST_CHECK.then_some(BOARD_REST_CHECK),
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(DELTA_TA_NM)
}

/// The simulated board's configuration: the rest check (when [`REST_CHECK`]) for the scene's
/// finger, its stop from the scene's geometry (`sim_board::scene_rest_check`).
#[cfg(any(feature = "qemu", not(target_os = "none")))]
pub fn with_scene_rest_check(mut cfg: ControllerConfig, scene: &plant::Scene) -> ControllerConfig {
    cfg.rest_check = if REST_CHECK {
        sim_board::scene_rest_check(scene)
    } else {
        None
    };
    cfg
}

/// The scene of this build (`FINGER_FW_SCENE` at build time; build.rs checked the name).
#[cfg(any(feature = "qemu", not(target_os = "none")))]
pub fn scene() -> Option<plant::Scene> {
    match crate::config::SCENE_CONST {
        Some(s) => Some(s),
        None => plant::scenes::by_name(crate::config::SCENE),
    }
    .map(finger_scene)
}

/// Control ticks between two telemetry samples: 50 Hz whatever the loop rate.
pub fn decimation(drive: &DriveConfig) -> u32 {
    let n = (0.02 / drive.dt_s) as u32;
    n.max(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn telemetry_is_50_hz_whatever_the_loop_rate() {
        let mut d = DriveConfig::DEFAULT;
        for (dt, n) in [(100e-6, 200), (200e-6, 100), (1e-3, 20), (0.05, 1)] {
            d.dt_s = dt;
            assert_eq!(decimation(&d), n, "dt {dt}");
        }
    }

    #[test]
    fn exit_status_and_end_of_run() {
        assert_eq!(status(State::Holding), 0);
        assert_eq!(status(State::Fault(grasp::FaultReason::Stall)), 2);
        assert!(finished(State::Done) && finished(State::Holding));
        assert!(!finished(State::Approach) && !finished(State::Estimating));
    }

    /// The build-time two-point table is the one the f64 model gives for the build's finger
    /// (bit for bit) and answers like it.
    #[test]
    fn the_build_time_table_is_the_finger_s_table() {
        let built = pts::table::FreeTable::<pts::fixed::Fx32>::new(&crate::config::FINGER).unwrap();
        let fixed = crate::config::FREE_TABLE.as_ref().unwrap();
        assert_eq!(fixed.to_raw(), built.to_raw());
        assert_eq!(fixed.model().finger, crate::config::FINGER);
        let th = pts::fixed::Fx32::from_bits(-(1 << 30));
        assert_eq!(fixed.free_torque(th), built.free_torque(th));
    }

    /// The board's rest check, built at build time from the build's finger file, is for the
    /// paper's finger (the default build) the prototype's hand-written one: its stop within
    /// 0.01 mrad, the springs' and friction's torque there within 1 mN·m, the same backlash
    /// and compliance.
    #[test]
    fn the_board_s_rest_check_is_the_prototype_s_for_the_paper_finger() {
        if crate::config::FINGER_DRIVE.is_some() {
            return; // built for another finger file
        }
        let (b, p) = (BOARD_REST_CHECK, grasp::RestCheck::PAPER);
        assert!(
            (b.stop_from_rest_rad - p.stop_from_rest_rad).abs() < 1e-5,
            "{b:?}"
        );
        assert!((b.stop_spring_nm - p.stop_spring_nm).abs() < 1e-3, "{b:?}");
        assert!((b.friction_nm - p.friction_nm).abs() < 1e-3, "{b:?}");
        assert_eq!(b.backlash_rad, p.backlash_rad);
        assert_eq!(b.stop_compliance_rad_per_nm, p.stop_compliance_rad_per_nm);
        assert_eq!(b.open_torque_nm, p.open_torque_nm);
    }

    /// The board's build-time path-fit table is the one init builds for the build's finger
    /// at the board's period (bit for bit), so the board estimates as before.
    #[test]
    fn the_build_time_path_table_is_the_board_s_table() {
        let dt_ns = (DriveConfig::DEFAULT.dt_s * 1e9) as u32;
        let built = grasp::path_table(&crate::config::FINGER, &file_drive(), dt_ns).unwrap();
        let fixed = crate::config::PATH_TABLE.as_ref().unwrap();
        assert_eq!(fixed.to_raw(), built.to_raw());
        assert_eq!(file_drive().dt_s, DriveConfig::DEFAULT.dt_s);
        let th = pts::fixed::Fx32::from_bits(-(1 << 30));
        assert_eq!(fixed.free_torque(th), built.free_torque(th));
    }

    /// Device mode starts from the build's settings: the controller it configures from them is
    /// the power-up grasp's.
    #[test]
    fn default_settings_configure_the_power_up_grasp() {
        let d = scene_drive(&plant::scenes::table2());
        assert_eq!(config_with(d, &default_settings()), config(d));
        assert!(default_settings().validate().is_ok());
        let mut s = default_settings();
        s.delta_ta_nm = 0.5;
        s.estimator = proto::Estimator::PathFit;
        let c = config_with(d, &s);
        assert_eq!(c.delta_ta_nm, 0.5);
        assert_eq!(c.estimator, Estimator::PathFit);
    }

    /// The simulated board's controller sees the scene's nominal drive: one encoder count
    /// and one ADC code convert the way the plant's sensor model defines them.
    #[test]
    fn scene_drive_matches_the_plant_sensors() {
        let s = plant::scenes::table2();
        let d = scene_drive(&s);
        assert_eq!(d.dt_s, s.dt_s);
        assert_eq!(
            d.encoder_counts_per_rev,
            f64::from(s.sensors.counts_per_turn())
        );
        assert!((d.amps_per_code * s.sensors.codes_per_amp() - 1.0).abs() < 1e-12);
    }
}
