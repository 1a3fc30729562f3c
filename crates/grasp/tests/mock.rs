//! The controller against a minimal quasi-static mock (no inertia, no friction, exact
//! piecewise-linear stiffness), independent of crates/plant: the stiffness after contact is
//! MODEL.md's K_c of the Table 2 contact, so the estimate must give back its k2.
use grasp::{
    run_estimate, Controller, ControllerConfig, DriveConfig, FaultReason, Hardware, Located, State,
    StepShape, DUTY_MAX,
};

/// MODEL.md Table 2 numbers.
const THETA_REST: f64 = -0.850_360_8;
const THETA_C: f64 = -0.223_771;
const TA_C: f64 = 0.340_821;
const KC: f64 = 6.7249;
const K2_TRUE: f64 = 0.02927;
const L2: f64 = 0.075;

struct Mock {
    d: DriveConfig,
    duty: f64,
    off: bool,
    theta: f64,
    k_free: f64,
    k_contact: f64,
    /// Contact removed (loss of contact) when true.
    gone: bool,
    /// Extra counts added to the encoder (fault injection).
    enc_glitch: i64,
    /// ADC code override (fault injection).
    adc_override: Option<u16>,
    /// Second contact: stiffness becomes this above `theta_second`.
    theta_second: f64,
    bridge_off_calls: u32,
}

impl Mock {
    fn new(d: DriveConfig) -> Self {
        Self {
            d,
            duty: 0.0,
            off: true,
            theta: THETA_REST,
            k_free: TA_C / (THETA_C - THETA_REST),
            k_contact: KC,
            gone: false,
            enc_glitch: 0,
            adc_override: None,
            theta_second: f64::INFINITY,
            bridge_off_calls: 0,
        }
    }
    fn current_a(&self) -> f64 {
        if self.off {
            0.0
        } else {
            self.duty * self.d.bus_v / self.d.resistance_ohm
        }
    }
    fn settle(&mut self) {
        let t = self.current_a() * self.d.torque_per_amp();
        let tc2 = TA_C + (self.theta_second - THETA_C) * self.k_contact;
        let target = if t <= TA_C || self.gone {
            THETA_REST + t / self.k_free
        } else if t <= tc2 {
            THETA_C + (t - TA_C) / self.k_contact
        } else {
            self.theta_second + (t - tc2) / 1000.0
        };
        // Finite speed (rad per tick): the mock has no inertia otherwise.
        self.theta += (target - self.theta).clamp(-1e-3, 1e-3);
    }
}

impl Hardware for Mock {
    fn encoder_count(&mut self) -> u16 {
        let c = ((self.theta - THETA_REST) / self.d.rad_per_count()).round() as i64;
        (c + 1000 + self.enc_glitch) as u16
    }
    fn current_raw(&mut self) -> u16 {
        if let Some(c) = self.adc_override {
            return c;
        }
        let code = self.d.adc_zero_code + self.current_a() / self.d.amps_per_code;
        code.round().clamp(0.0, 4095.0) as u16
    }
    fn set_duty(&mut self, duty: i16) {
        assert!(duty.abs() <= DUTY_MAX);
        self.off = false;
        self.duty = f64::from(duty) / f64::from(DUTY_MAX);
        self.settle();
    }
    fn bridge_off(&mut self) {
        self.off = true;
        self.bridge_off_calls += 1;
        self.settle();
    }
}

fn drive() -> DriveConfig {
    DriveConfig::DEFAULT
}

fn cfg(dta: f64) -> ControllerConfig {
    // The mock has no inertia: no damping needed, no speed limit. Its linear spring is what
    // the two-point method inverts exactly; the path fit's model is the finger's.
    ControllerConfig {
        estimator: grasp::Estimator::TwoPoint,
        drive: drive(),
        damping_nm_s_per_rad: 0.0,
        approach_speed_max_rad_s: 100.0,
        detect_min_rise_nm: 0.002,
        // The mock has no back-EMF.
        emf_mismatch_v: 1000.0,
        // The two-point method's static points.
        seating: true,
        step_shape: grasp::StepShape::Ramp(1.0),
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(dta)
}

/// Runs until the estimate is requested (or a terminal state), delivering it.
fn run(c: &mut Controller, hw: &mut Mock, max_ticks: u32, mut inject: impl FnMut(u32, &mut Mock)) {
    for t in 0..max_ticks {
        inject(t, hw);
        let out = c.tick(hw);
        if out.estimate_ready {
            let req = c.take_request().expect("request after estimate_ready");
            c.deliver(hw, run_estimate(&pts::Finger::PAPER, &drive(), &req));
        }
        if matches!(c.state(), State::Fault(_) | State::Done | State::Holding) {
            return;
        }
    }
}

#[test]
fn table2_contact_in_the_linear_mock() {
    for dta in [0.1, 0.2, 0.5, 0.8] {
        let mut c = Controller::new(cfg(dta)).unwrap();
        let mut hw = Mock::new(drive());
        run(&mut c, &mut hw, 60_000, |_, _| {});
        assert_eq!(c.state(), State::Holding, "dta {dta}");
        let r = *c.result().unwrap();
        let k2 = f64::from(r.k2_um.unwrap()) * 1e-6;
        let kc = f64::from(r.kc_hat_unm_per_rad) * 1e-6;
        let thc = f64::from(r.theta_a_c_urad) * 1e-6;
        let tac = f64::from(r.ta_c_unm) * 1e-6;
        let err = (k2 - K2_TRUE) / L2 * 100.0;
        println!("dta {dta}: kc_hat {kc:.4} k2 {k2:.5} err {err:.2} % l2  theta_c {thc:.5} (true {THETA_C}) ta_c {tac:.4} (true {TA_C})");
        assert_eq!(r.located, Located::Distal);
        assert!(err.abs() < 1.0, "dta {dta}: error {err} % of l2");
    }
}

#[test]
fn encoder_jump_is_a_sensor_fault() {
    let mut c = Controller::new(cfg(0.2)).unwrap();
    let mut hw = Mock::new(drive());
    run(&mut c, &mut hw, 60_000, |t, hw| {
        if t == 15_000 {
            hw.enc_glitch = 5000;
        }
    });
    assert!(
        matches!(c.state(), State::Fault(FaultReason::EncoderJump { .. })),
        "{:?}",
        c.state()
    );
    assert!(hw.off);
}

#[test]
fn adc_rail_is_a_fault() {
    let mut c = Controller::new(cfg(0.2)).unwrap();
    let mut hw = Mock::new(drive());
    run(&mut c, &mut hw, 60_000, |t, hw| {
        if t == 15_000 {
            hw.adc_override = Some(4095);
        }
    });
    assert!(
        matches!(c.state(), State::Fault(FaultReason::AdcRail { code: 4095 })),
        "{:?}",
        c.state()
    );
    assert!(hw.off);
}

#[test]
fn bad_offset_is_a_sensor_fault() {
    let mut c = Controller::new(cfg(0.2)).unwrap();
    let mut hw = Mock::new(drive());
    hw.adc_override = Some(3000);
    run(&mut c, &mut hw, 2_000, |_, _| {});
    assert!(matches!(
        c.state(),
        State::Fault(FaultReason::AdcOffset { .. })
    ));
}

#[test]
fn object_removed_after_contact_is_loss_of_contact() {
    let mut c = Controller::new(cfg(0.8)).unwrap();
    let mut hw = Mock::new(drive());
    let mut seen_step = false;
    for _ in 0..60_000 {
        if c.state() == State::Step && !seen_step {
            seen_step = true;
        }
        if seen_step {
            hw.gone = true;
        }
        c.tick(&mut hw);
        if matches!(c.state(), State::Fault(_)) {
            break;
        }
    }
    assert!(
        matches!(c.state(), State::Fault(FaultReason::LossOfContact { .. })),
        "{:?}",
        c.state()
    );
}

#[test]
fn second_contact_during_the_ramp() {
    let mut c = Controller::new(ControllerConfig {
        step_shape: StepShape::Ramp(1.0),
        ..cfg(0.8)
    })
    .unwrap();
    let mut hw = Mock::new(drive());
    hw.theta_second = THETA_C + 0.02;
    run(&mut c, &mut hw, 60_000, |_, _| {});
    assert!(
        matches!(c.state(), State::Fault(FaultReason::SecondContact { .. })),
        "{:?}",
        c.state()
    );
}

#[test]
fn no_object_ends_in_no_contact() {
    let mut c = Controller::new(cfg(0.2)).unwrap();
    let mut hw = Mock::new(drive());
    hw.k_contact = hw.k_free;
    run(&mut c, &mut hw, 120_000, |_, _| {});
    assert_eq!(c.state(), State::Fault(FaultReason::NoContact));
}

#[test]
fn drive_that_cannot_follow_is_a_stall() {
    // The board's supply is 1 V, the configuration says 6 V: the duty saturates and the
    // torque never arrives. With the seating stages and with a fast step from the detection
    // (which settles within the stall's persistence unless a settled step must be delivered).
    for (seating, step_shape) in [(true, StepShape::Ramp(1.0)), (false, StepShape::Ramp(4.0))] {
        let mut c = Controller::new(ControllerConfig {
            seating,
            step_shape,
            ..cfg(0.2)
        })
        .unwrap();
        let mut hw = Mock::new(DriveConfig {
            bus_v: 1.0,
            ..drive()
        });
        run(&mut c, &mut hw, 120_000, |_, _| {});
        assert_eq!(
            c.state(),
            State::Fault(FaultReason::Stall),
            "seating {seating}"
        );
        assert!(hw.off);
    }
}
