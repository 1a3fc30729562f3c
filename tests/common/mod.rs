//! Shared harness of the closed-loop tests: the real `grasp::Controller` against `plant::Plant`.
#![allow(dead_code)]

use grasp::{
    run_estimate, Controller, ControllerConfig, DriveConfig, EstimateResult, Event, State,
    TickOutput,
};
use plant::{EventKind, Plant, Scene, Truth};
use sim_board::run::{Limits, Observer, Timing};

/// Length of the distal phalanx (m), MODEL.md Table 1.
pub const L2: f64 = 0.075;

/// Large cylinders near O2 that the finger touches first with the proximal phalanx, the
/// distal one touching too while the torque rises (the plant reports the second contact):
/// three of them on the realistic plant ([`Scene::ideal`] for the other).
pub fn second_contact_scenes() -> [Scene; 3] {
    use plant::path::ContactSpec;
    use plant::scene::ObjectSpec;
    [(1.1, 0.006, 0.10), (1.2797, 0.003, 0.10), (1.0, 0.004, 0.2)].map(
        |(theta1_c_rad, k_c_m, radius_m)| Scene {
            name: "second_contact",
            object: ObjectSpec::Touching(ContactSpec {
                theta1_c_rad,
                phalanx: plant::Phalanx::Distal,
                k_c_m,
                radius_m,
            }),
            ..Scene::DEFAULT
        },
    )
}

/// "R=… k2=… θ1,c=…" of a scene whose object touches at a given configuration, for messages.
pub fn touching_label(scene: &Scene) -> String {
    match scene.object {
        plant::scene::ObjectSpec::Touching(c) => {
            format!("R={} k2={} θ1,c={}", c.radius_m, c.k_c_m, c.theta1_c_rad)
        }
        _ => scene.name.to_string(),
    }
}

/// `grasp::Hardware` on top of the simulated finger (the shared adapter of crates/sim-board).
pub use sim_board::PlantBoard as PlantHw;

/// The controller's view of a scene's drive and sensors: the nominal constants a firmware
/// would be built with (no error terms), θa,rest of MODEL.md.
pub fn drive_config(scene: &Scene) -> DriveConfig {
    sim_board::scene_drive(scene, -0.850_360_8)
}

/// The default controller configuration for a scene, with ΔT_a (N·m).
pub fn config(scene: &Scene, delta_ta_nm: f64) -> ControllerConfig {
    ControllerConfig {
        drive: drive_config(scene),
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(delta_ta_nm)
}

/// The controller without seating (the step starts from T_a,c at the detection), the step a
/// 4 N·m/s ramp of ΔT_a (N·m): a grasp shaped like a recording that no seating controller made.
/// Spelled out rather than taken from the default, which it is today.
pub fn unseated(scene: &Scene, delta_ta_nm: f64) -> ControllerConfig {
    ControllerConfig {
        seating: false,
        step_shape: grasp::StepShape::Ramp(4.0),
        ..config(scene, delta_ta_nm)
    }
}

/// The seated controller (`pts board set seating on`): the contact seated in static stages
/// (the two-point method's static points) before a 1 N·m/s ramp of ΔT_a (N·m).
pub fn seated(scene: &Scene, delta_ta_nm: f64) -> ControllerConfig {
    ControllerConfig {
        seating: true,
        step_shape: grasp::StepShape::Ramp(1.0),
        ..config(scene, delta_ta_nm)
    }
}

/// What one closed-loop grasp produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Final controller state.
    pub state: State,
    /// The delivered estimate (or the solver's refusal).
    pub estimate: Option<Result<EstimateResult, grasp::EstimateError>>,
    /// The estimate request (when the grasp got that far).
    pub request: Option<grasp::EstimateRequest>,
    /// Plant truth when the controller reported "settled".
    pub truth_settled: Option<Truth>,
    /// Plant time of the first contact (s) and its location (m).
    pub first_contact: Option<(f64, f64)>,
    /// Plant time of the controller's contact detection (s).
    pub detected_s: Option<f64>,
    /// Plant time of a second contact (s).
    pub second_contact_s: Option<f64>,
    /// Controller events, in order.
    pub events: Vec<Event>,
    /// Plant truth at each controller event.
    pub event_truth: Vec<Truth>,
    /// Plant events, in order.
    pub plant_events: Vec<plant::Event>,
    /// Bridge off at the end.
    pub bridge_off: bool,
    /// Simulated time at the end (s).
    pub t_end_s: f64,
    /// What the rest check found (when configured and passed).
    pub rest_report: Option<grasp::RestReport>,
}

/// Runs one grasp: ticks the controller against the plant until it holds, finishes or
/// faults (plus `extra_s` of simulated time after that), at most `max_s`.
/// `inject` is called before every tick with the plant time and the controller state.
pub fn run(
    scene: &Scene,
    cfg: ControllerConfig,
    max_s: f64,
    extra_s: f64,
    mut inject: impl FnMut(f64, State, &mut Plant),
) -> Outcome {
    let plant = Plant::new(scene).expect("scene builds");
    let mut hw = PlantHw::new(plant);
    let mut c = Controller::new(cfg).expect("config valid");
    let mut out = Outcome {
        state: State::Init,
        estimate: None,
        request: None,
        truth_settled: None,
        first_contact: None,
        detected_s: None,
        second_contact_s: None,
        events: Vec::new(),
        event_truth: Vec::new(),
        plant_events: Vec::new(),
        bridge_off: true,
        t_end_s: 0.0,
        rest_report: None,
    };
    let dt = scene.dt_s;
    let trace: u64 = std::env::var("GRASP_TRACE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let limits = Limits {
        max_ticks: (max_s / dt) as u64,
        extra_ticks: Some((extra_s / dt) as u64),
        timing: Timing::Immediate,
    };
    let mut obs = Recorder {
        out: &mut out,
        finger: &cfg.finger,
        drive: cfg.drive,
        inject: &mut inject,
        trace,
    };
    sim_board::run::run(&mut c, &mut hw, limits, &mut obs);
    out.state = c.state();
    assert_eq!(
        hw.duty_clamped(),
        0,
        "the controller commanded a duty beyond ±DUTY_MAX"
    );
    out.bridge_off = hw.is_off();
    out.t_end_s = hw.plant.truth().t_s;
    out.rest_report = c.rest_report();
    out
}

/// What [`run`] records of each tick.
struct Recorder<'a, F> {
    out: &'a mut Outcome,
    finger: &'a pts::Finger,
    /// The controller's drive (the path fit's measurement model).
    drive: DriveConfig,
    inject: &'a mut F,
    /// Print every n-th tick to stderr (`GRASP_TRACE=n`), 0: never.
    trace: u64,
}

impl<F: FnMut(f64, State, &mut Plant)> Observer<PlantHw> for Recorder<'_, F> {
    fn before_tick(&mut self, _n: u64, ctl: &Controller, hw: &mut PlantHw) -> bool {
        let t = hw.plant.truth().t_s;
        (self.inject)(t, ctl.state(), &mut hw.plant);
        true
    }

    fn estimate(
        &mut self,
        req: &grasp::EstimateRequest,
        hw: &PlantHw,
    ) -> Result<EstimateResult, grasp::EstimateError> {
        self.out.truth_settled = Some(hw.plant.truth());
        let r = run_estimate(self.finger, &self.drive, req);
        self.out.estimate = Some(r);
        self.out.request = Some(req.clone());
        r
    }

    fn event(&mut self, e: Event, hw: &PlantHw) {
        if let Event::ContactDetected { .. } = e {
            self.out.detected_s = Some(hw.plant.truth().t_s);
        }
        self.out.events.push(e);
        self.out.event_truth.push(hw.plant.truth());
    }

    fn after_tick(&mut self, n: u64, o: &TickOutput, _ctl: &Controller, hw: &PlantHw) {
        if self.trace > 0 && n % self.trace == 0 {
            let tr = hw.plant.truth();
            eprintln!(
                "t {:.4} {:?} th {} T {} Tref {} duty {} | true th {:.5} T {:.4} i {:.4} w {:.1} {:?}",
                tr.t_s, o.state, o.theta_a_urad, o.torque_unm, o.torque_ref_unm, o.duty,
                tr.theta_a_rad, tr.torque_a_nm, tr.current_a, tr.motor_speed_rad_s, tr.contact
            );
        }
    }

    fn after_advance(&mut self, hw: &mut PlantHw) {
        let out = &mut *self.out;
        while let Some(e) = hw.plant.poll_event() {
            match e.kind {
                EventKind::FirstContact { k_m, .. } if out.first_contact.is_none() => {
                    out.first_contact = Some((e.t_s, k_m));
                }
                EventKind::SecondContact { .. } if out.second_contact_s.is_none() => {
                    out.second_contact_s = Some(e.t_s);
                }
                _ => {}
            }
            out.plant_events.push(e);
        }
    }
}

/// k2 of a delivered distal estimate (m).
pub fn k2_hat(o: &Outcome) -> Option<f64> {
    match o.estimate {
        Some(Ok(r)) => r.k2_um.map(|k| f64::from(k) * 1e-6),
        _ => None,
    }
}
