//! `pts sim`: the real grasp controller closed loop against the simulated finger, on the host.
//!
//! One control tick per plant step: the controller reads the plant's encoder and ADC, sets a
//! duty, the plant advances one period. When the step has settled, the estimate request goes
//! through [`grasp::run_estimate`] (the estimator the firmware runs) and back to the controller.
//! Every tick is recorded ([`TraceRow`]) for the CSV, the plots and `pts estimate`.

use crate::trace::{state_name, TraceRow};
use grasp::{Controller, ControllerConfig, DriveConfig, EstimateResult, State, TickOutput};
use plant::{EventKind, Plant, Scene};
use sim_board::run::{Limits, Observer, Timing};

/// Why the estimator refused a measurement: its snake_case kind and a description.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EstError {
    /// snake_case kind (`beyond_tip`, `ill_conditioned`, …).
    pub kind: &'static str,
    /// The estimator's error in words.
    pub detail: String,
}

impl EstError {
    /// From the estimator's error (whatever its type: it has a `kind()` and `Display`).
    pub fn new(kind: &'static str, e: &dyn std::fmt::Display) -> Self {
        EstError {
            kind,
            detail: e.to_string(),
        }
    }
}

impl std::fmt::Display for EstError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.detail)
    }
}

pub use sim_board::{scene_drive as drive_config, PlantBoard as PlantHw};

/// A scene: a built-in name (`plant::scenes::NAMES`) or a TOML scene file.
pub fn load_scene(name_or_file: &str) -> Result<Scene, String> {
    if let Some(s) = plant::scenes::by_name(name_or_file) {
        return Ok(s);
    }
    let path = std::path::Path::new(name_or_file);
    if path.is_file() {
        return plant::toml_scene::from_toml_file(path)
            .map_err(|e| format!("scene {}: {e}", path.display()));
    }
    Err(format!(
        "no scene \"{name_or_file}\": not a file, and the built-in scenes are {}",
        plant::scenes::NAMES.join(", ")
    ))
}

/// What to run.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// The scene.
    pub scene: Scene,
    /// Torque step ΔT_a after contact (N·m).
    pub delta_ta_nm: f64,
    /// Simulated time limit (s).
    pub max_s: f64,
    /// Simulated time kept after the controller holds or faults (s).
    pub extra_s: f64,
    /// Keep every tick in [`SimReport::rows`] (for the CSV and the plots).
    pub record: bool,
    /// The estimator the controller's request names.
    pub method: crate::method::Method,
    /// The over-current limit (A) of the finger file the scene was built from
    /// ([`finger_scene`]); `None`: the controller's default.
    pub overcurrent_a: Option<f64>,
    /// The path fit's priors of the finger file the scene was built from (its `[estimate]`);
    /// `None`: the defaults.
    pub priors: Option<pathfit::FitPriors>,
    /// How ΔT_a is applied; `None`: the controller's default.
    pub step_shape: Option<grasp::StepShape>,
    /// Seat the contact in static stages before the step
    /// ([`ControllerConfig::seating`]); `None`: the controller's default.
    pub seating: Option<bool>,
}

/// What a finger file gives the controller besides the plant's finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FileControl {
    /// The file's current limit (A), for [`SimOptions::overcurrent_a`].
    pub overcurrent_a: f64,
    /// The file's path-fit priors, for [`SimOptions::priors`].
    pub priors: pathfit::FitPriors,
}

/// A scene as the finger of a finger file: its geometry, springs and drive constants in the
/// plant (the scene's object, friction and sensor models stay), and what the file sets in the
/// controller. Checked by the controller's own validation first.
pub fn finger_scene(
    scene: Scene,
    file: &pts::config::FingerFile,
) -> Result<(Scene, FileControl), String> {
    let cfg = crate::replay::controller_config(file, scene.dt_s)?;
    Ok((
        sim_board::scene_for_finger(scene, &file.finger, &cfg.drive, &file.stops),
        FileControl {
            overcurrent_a: cfg.overcurrent_a,
            priors: cfg.drive.priors,
        },
    ))
}

/// A timed event from the controller or the plant, for people.
#[derive(Clone, Debug, PartialEq)]
pub struct TimedEvent {
    /// Simulated time (s).
    pub t_s: f64,
    /// `"ctl"` or `"plant"`.
    pub source: &'static str,
    /// snake_case name.
    pub name: String,
    /// Details.
    pub detail: String,
}

/// What one closed-loop grasp produced.
#[derive(Clone, Debug)]
pub struct SimReport {
    /// Scene name.
    pub scene: String,
    /// Final controller state.
    pub state: State,
    /// The estimate (or the estimator's refusal).
    pub estimate: Option<Result<EstimateResult, EstError>>,
    /// The estimator used.
    pub method: crate::method::Method,
    /// Plant: first contact (t, phalanx name, k in m).
    pub first_contact: Option<(f64, &'static str, f64)>,
    /// Plant truth when the estimate was requested: contact location (m).
    pub k_at_settle_m: Option<f64>,
    /// Controller: the back-dated contact instant (t s, θa,c rad, T_a,c N·m).
    pub contact: Option<(f64, f64, f64)>,
    /// Controller and plant events in time order.
    pub events: Vec<TimedEvent>,
    /// Every tick (when recorded).
    pub rows: Vec<TraceRow>,
    /// Simulated time at the end (s).
    pub t_end_s: f64,
    /// l2 of the scene's finger (m).
    pub l2_m: f64,
    /// Control period (s).
    pub dt_s: f64,
    /// The drive constants the controller was built with.
    pub drive: DriveConfig,
}

impl SimReport {
    /// Estimated k2 (m) when the estimate located a distal contact.
    pub fn k2_hat_m(&self) -> Option<f64> {
        match &self.estimate {
            Some(Ok(r)) => r.k2_um.map(|k| f64::from(k) / 1e6),
            _ => None,
        }
    }

    /// Error of k̂2 against the true contact location at first contact, % of l2.
    pub fn error_pct_l2(&self) -> Option<f64> {
        let (_, ph, k) = self.first_contact?;
        if ph != "distal" {
            return None;
        }
        Some((self.k2_hat_m()? - k) / self.l2_m * 100.0)
    }

    /// Time to know (s): from the plant's first contact to the estimate delivered.
    pub fn time_to_know_s(&self) -> Option<f64> {
        let (t_contact, _, _) = self.first_contact?;
        let t_estimate = self
            .events
            .iter()
            .find(|e| e.source == "ctl" && e.name == "estimated")?
            .t_s;
        Some(t_estimate - t_contact)
    }

    /// Fault kind, if the controller ended in its safe state.
    pub fn fault(&self) -> Option<&'static str> {
        match self.state {
            State::Fault(r) => Some(r.kind()),
            _ => None,
        }
    }
}

fn ctl_event(e: &grasp::Event, dt: f64) -> TimedEvent {
    use grasp::Event as E;
    // Tick n (counted from 1) reads the sensors at plant time (n − 1)·dt.
    let t = |tick: u32| f64::from(tick.saturating_sub(1)) * dt;
    let (tick, name, detail) = match *e {
        E::Calibrated { tick, offset_q8 } => (
            tick,
            "calibrated",
            format!("ADC zero {:.2} codes", f64::from(offset_q8) / 256.0),
        ),
        E::ContactDetected {
            tick,
            contact_tick,
            theta_a_urad,
            torque_unm,
            target_unm,
        } => (
            tick,
            "contact_detected",
            format!(
                "back-dated to t = {:.4} s: θa,c = {:.5} rad, T_a,c = {:.4} N·m; step to {:.4} N·m",
                t(contact_tick),
                f64::from(theta_a_urad) / 1e6,
                f64::from(torque_unm) / 1e6,
                f64::from(target_unm) / 1e6
            ),
        ),
        E::Seated {
            tick,
            stage,
            theta_a_urad,
            torque_unm,
        } => (
            tick,
            "seated",
            format!(
                "{}: θa = {:.5} rad, T_a = {:.4} N·m",
                match stage {
                    0 => "the impact at rest (not used by the estimate)",
                    1 => "first loading point",
                    _ => "second loading point",
                },
                f64::from(theta_a_urad) / 1e6,
                f64::from(torque_unm) / 1e6
            ),
        ),
        E::StepDone { tick } => (tick, "step_done", String::new()),
        E::Settled {
            tick,
            theta_a_urad,
            torque_unm,
            path_len,
        } => (
            tick,
            "settled",
            format!(
                "θa = {:.5} rad, T_a = {:.4} N·m, {path_len} path samples",
                f64::from(theta_a_urad) / 1e6,
                f64::from(torque_unm) / 1e6
            ),
        ),
        E::Estimated { tick, result } => (tick, "estimated", describe(&result)),
        E::Holding { tick } => (tick, "holding", String::new()),
        E::Releasing { tick } => (tick, "releasing", String::new()),
        E::Released { tick } => (tick, "released", String::new()),
        E::Fault { tick, reason } => (tick, "fault", format!("{} ({reason:?})", reason.kind())),
        // Events added to the controller later: their Debug form.
        #[allow(unreachable_patterns)]
        other => {
            let text = format!("{other:?}");
            let tick = text
                .split("tick: ")
                .nth(1)
                .and_then(|r| r.split([',', ' ', '}']).next())
                .and_then(|n| n.parse().ok())
                .unwrap_or(0);
            let name = crate::trace::snake(&text);
            return TimedEvent {
                t_s: t(tick),
                source: "ctl",
                name,
                detail: text,
            };
        }
    };
    TimedEvent {
        t_s: t(tick),
        source: "ctl",
        name: name.into(),
        detail,
    }
}

/// K̂c of an estimate (N·m/rad); `None` where the estimator computed none (the path fit's
/// proximal answer, which leaves it 0: no contact stiffness is fitted there).
pub fn kc_hat_nm_per_rad(r: &EstimateResult) -> Option<f64> {
    (r.kc_hat_unm_per_rad != 0).then(|| f64::from(r.kc_hat_unm_per_rad) / 1e6)
}

/// One line about an estimate.
pub fn describe(r: &EstimateResult) -> String {
    let mm = |um: i32| format!("{:.2} mm", f64::from(um) * 1e-3);
    let k2 = match (r.k2_um, r.k2_sigma_um) {
        (Some(k), Some(s)) => format!(", k2 = {} ± {}", mm(k), mm(s)),
        (Some(k), None) => format!(", k2 = {}", mm(k)),
        (None, _) => String::new(),
    };
    let radius = r
        .radius_um
        .map_or(String::new(), |v| format!(", R = {}", mm(v)));
    let reference = r.two_point_k2_um.map_or(String::new(), |v| {
        format!("; two-point k2 = {} (reference)", mm(v))
    });
    let kc = kc_hat_nm_per_rad(r).map_or(String::new(), |k| format!(", K̂c = {k:.4} N·m/rad"));
    format!(
        "{}{k2}{radius}{kc}, ΔT_a = {:.4} N·m, Δθa = {:.5} rad, quality {}{reference}",
        crate::trace::located_name(r.located),
        f64::from(r.delta_ta_unm) / 1e6,
        f64::from(r.delta_theta_a_urad) / 1e6,
        crate::trace::quality_name(r.quality),
    )
}

fn phalanx_name(p: plant::Phalanx) -> &'static str {
    match p {
        plant::Phalanx::Proximal => "proximal",
        plant::Phalanx::Distal => "distal",
    }
}

/// Runs one grasp: ticks until the controller holds, finishes or faults (plus `extra_s`),
/// at most `max_s` of simulated time.
pub fn run(opts: &SimOptions) -> Result<SimReport, String> {
    let scene = &opts.scene;
    let plant = Plant::new(scene).map_err(|e| format!("scene {}: {e}", scene.name))?;
    // The firmware knows the finger from its description, not the plant: θa at rest and the
    // estimator's model come from the pts model of the scene's finger.
    let finger = pts_finger(&scene.finger);
    let rest = grasp::config::finger_rest_theta_a_rad(&finger)
        .map_err(|e| format!("scene finger rest pose: {e:?}"))?;
    // Refused here, with the reason, rather than as an estimate error after the grasp.
    pts::Model::<grasp::EstReal>::new(&finger)
        .map_err(|e| format!("scene finger on the firmware back end: {e}"))?;
    let drive = DriveConfig {
        priors: opts.priors.unwrap_or(DriveConfig::DEFAULT.priors),
        ..drive_config(scene, rest)
    };
    let cfg = ControllerConfig {
        finger,
        drive,
        estimator: opts.method.estimator(),
        step_shape: opts
            .step_shape
            .unwrap_or(ControllerConfig::DEFAULT.step_shape),
        overcurrent_a: opts
            .overcurrent_a
            .unwrap_or(ControllerConfig::DEFAULT.overcurrent_a),
        seating: opts.seating.unwrap_or(ControllerConfig::DEFAULT.seating),
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(opts.delta_ta_nm);
    let mut ctl = Controller::new(cfg).map_err(|e| format!("controller configuration: {e:?}"))?;
    let mut hw = PlantHw::new(plant);
    let dt = scene.dt_s;
    let mut rep = SimReport {
        scene: scene.name.to_string(),
        state: State::Init,
        estimate: None,
        method: opts.method,
        first_contact: None,
        k_at_settle_m: None,
        contact: None,
        events: vec![],
        rows: vec![],
        t_end_s: 0.0,
        l2_m: scene.finger.l2_m,
        dt_s: dt,
        drive,
    };
    let limits = Limits {
        max_ticks: (opts.max_s / dt).ceil().max(0.0) as u64,
        extra_ticks: Some((opts.extra_s / dt).ceil().max(0.0) as u64),
        timing: Timing::Immediate,
    };
    let mut obs = SimRecorder {
        rep: &mut rep,
        finger: &finger,
        drive,
        record: opts.record,
        before: None,
    };
    sim_board::run::run(&mut ctl, &mut hw, limits, &mut obs);
    rep.state = ctl.state();
    rep.t_end_s = hw.plant.truth().t_s;
    rep.events.sort_by(|a, b| {
        a.t_s
            .partial_cmp(&b.t_s)
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    Ok(rep)
}

/// What [`run`] records of each tick.
struct SimRecorder<'a> {
    rep: &'a mut SimReport,
    finger: &'a pts::Finger,
    /// The controller's drive (the path fit's measurement model).
    drive: DriveConfig,
    record: bool,
    /// The raw readings and the truth before the tick.
    before: Option<(u16, u16, plant::Truth)>,
}

impl Observer<PlantHw> for SimRecorder<'_> {
    fn before_tick(&mut self, _n: u64, _ctl: &Controller, hw: &mut PlantHw) -> bool {
        let enc = hw.plant.encoder_count();
        let code = hw.plant.current_adc();
        self.before = Some((enc, code, hw.plant.truth()));
        true
    }

    fn estimate(
        &mut self,
        req: &grasp::EstimateRequest,
        _hw: &PlantHw,
    ) -> Result<EstimateResult, grasp::EstimateError> {
        self.rep.k_at_settle_m = self.before.map(|(_, _, truth)| truth.k_m);
        let r = grasp::run_estimate_with_reference(self.finger, &self.drive, req);
        self.rep.estimate = Some(r.map_err(|e| EstError::new(e.kind(), &e)));
        r
    }

    fn event(&mut self, e: grasp::Event, _hw: &PlantHw) {
        let dt = self.rep.dt_s;
        if let grasp::Event::ContactDetected {
            contact_tick,
            theta_a_urad,
            torque_unm,
            ..
        } = e
        {
            self.rep.contact = Some((
                f64::from(contact_tick.saturating_sub(1)) * dt,
                f64::from(theta_a_urad) / 1e6,
                f64::from(torque_unm) / 1e6,
            ));
        }
        self.rep.events.push(ctl_event(&e, dt));
    }

    fn after_tick(&mut self, _n: u64, out: &TickOutput, ctl: &Controller, hw: &PlantHw) {
        let Some((enc, code, truth)) = self.before.filter(|_| self.record) else {
            return;
        };
        self.rep.rows.push(TraceRow {
            t_s: truth.t_s,
            theta_a_rad: f64::from(out.theta_a_urad) / 1e6,
            torque_nm: f64::from(out.torque_unm) / 1e6,
            torque_ref_nm: Some(f64::from(out.torque_ref_unm) / 1e6),
            duty: Some(hw.duty()),
            state: Some(state_name(ctl.state())),
            encoder_count: Some(enc),
            current_code: Some(code),
            true_theta_a_rad: Some(truth.theta_a_rad),
            true_torque_nm: Some(truth.torque_a_nm),
            true_contact: Some(contact_name(truth.contact).to_string()),
            true_k_m: Some(truth.k_m),
        });
    }

    fn after_advance(&mut self, hw: &mut PlantHw) {
        while let Some(e) = hw.plant.poll_event() {
            if let EventKind::FirstContact { phalanx, k_m } = e.kind {
                if self.rep.first_contact.is_none() {
                    self.rep.first_contact = Some((e.t_s, phalanx_name(phalanx), k_m));
                }
            }
            self.rep.events.push(TimedEvent {
                t_s: e.t_s,
                source: "plant",
                name: e.kind.name().into(),
                detail: plant_detail(&e),
            });
        }
    }
}

/// The pts finger of a plant finger (geometry and springs).
pub fn pts_finger(g: &plant::FingerGeom) -> pts::Finger {
    pts::Finger {
        l1: g.l1_m,
        l2: g.l2_m,
        a: g.a_m,
        b: g.b_m,
        c: g.c_m,
        phi2: g.phi2_rad,
        theta01: g.theta01_rad,
        theta02: g.theta02_rad,
        k1: g.k1_nm_per_rad,
        k2: g.k2_nm_per_rad,
    }
}

fn contact_name(c: plant::ContactState) -> &'static str {
    match c {
        plant::ContactState::Free => "free",
        plant::ContactState::Proximal => "proximal",
        plant::ContactState::Distal => "distal",
        plant::ContactState::Limit => "limit",
        plant::ContactState::Locked => "locked",
    }
}

fn plant_detail(e: &plant::Event) -> String {
    let at = format!(
        "θa = {:.5} rad, T_a = {:.4} N·m",
        e.theta_a_rad, e.torque_nm
    );
    match e.kind {
        EventKind::FirstContact { phalanx, k_m } | EventKind::SecondContact { phalanx, k_m } => {
            format!("{} at k = {:.2} mm; {at}", phalanx_name(phalanx), k_m * 1e3)
        }
        EventKind::LossOfContact { phalanx, k_m } => {
            format!("{} at k = {:.2} mm; {at}", phalanx_name(phalanx), k_m * 1e3)
        }
        EventKind::OverCurrent { current_a } => format!("{current_a:.3} A"),
        _ => at,
    }
}
