//! The two halves of the controller as the firmware runs them: the loop alone on a board that
//! holds still, the link's hand-over rules, and a whole grasp with the supervisor run late.
use grasp::{
    run_estimate, ControlLoop, Controller, ControllerConfig, FaultReason, Hardware, Input, Link,
    Reference, Setpoint, State, TorqueQ16, LINK_SAMPLES,
};

/// A board that never moves: fixed encoder count and ADC code, records the bridge.
struct Still {
    code: u16,
    enc: u16,
    duty: i16,
    off: bool,
}

impl Hardware for Still {
    fn encoder_count(&mut self) -> u16 {
        self.enc
    }
    fn current_raw(&mut self) -> u16 {
        self.code
    }
    fn set_duty(&mut self, duty: i16) {
        self.off = false;
        self.duty = duty;
    }
    fn bridge_off(&mut self) {
        self.off = true;
        self.duty = 0;
    }
}

fn still() -> Still {
    Still {
        code: ControllerConfig::DEFAULT.drive.adc_zero_code as u16,
        enc: 1000,
        duty: 0,
        off: true,
    }
}

fn params() -> grasp::config::Params {
    ControllerConfig::DEFAULT.params().unwrap()
}

/// A calibrated loop on a still board with the bridge enabled on `reference`.
fn enabled(reference: Reference) -> (grasp::config::Params, ControlLoop, Still, Link) {
    let p = params();
    let mut lp = ControlLoop::new(&p);
    let mut hw = still();
    let mut link = calibrated(&mut lp, &mut hw);
    link.setpoint = Setpoint {
        enable: true,
        reference,
        damp_unm: 0,
    };
    (p, lp, hw, link)
}

/// Ticks the loop through calibration; returns the link with its inputs taken.
fn calibrated(lp: &mut ControlLoop, hw: &mut Still) -> Link {
    let mut link = Link::new();
    let p = params();
    for _ in 0..p.calib_ticks {
        lp.tick(hw, &mut link);
    }
    assert_eq!(link.next_input(), Some(Input::Started));
    assert!(matches!(link.next_input(), Some(Input::Calibrated { .. })));
    assert_eq!(link.next_input(), None);
    // As the supervisor does when it answers the calibration.
    link.stamp(lp.ticks());
    link
}

#[test]
fn loop_drives_only_while_the_setpoint_enables_it() {
    let p = params();
    let mut lp = ControlLoop::new(&p);
    let mut hw = still();
    let mut link = calibrated(&mut lp, &mut hw);
    // Calibrated but not enabled: bridge stays off.
    let o = lp.tick(&mut hw, &mut link);
    assert!(hw.off && o.duty == 0);
    link.setpoint = Setpoint {
        enable: true,
        reference: Reference::Set(TorqueQ16::from_unm(100_000)),
        damp_unm: 0,
    };
    let o = lp.tick(&mut hw, &mut link);
    assert!(!hw.off && o.duty > 0, "{o:?}");
    assert_eq!(o.torque_ref_unm, 100_000);
    link.setpoint = Setpoint::OFF;
    let o = lp.tick(&mut hw, &mut link);
    assert!(hw.off && o.went_off && o.duty == 0);
    assert_eq!(lp.torque_ref_unm(), 0);
}

#[test]
fn ramp_moves_at_most_its_rate_per_tick_both_ways() {
    let p = params();
    let mut lp = ControlLoop::new(&p);
    let mut hw = still();
    let mut link = calibrated(&mut lp, &mut hw);
    let ramp = |target: i32, rate: i64| Setpoint {
        enable: true,
        reference: Reference::Ramp {
            target: TorqueQ16::from_unm(target),
            rate: TorqueQ16::new(rate),
        },
        damp_unm: 0,
    };
    link.setpoint = ramp(1000, 100 << 16);
    let refs: Vec<i32> = (0..12)
        .map(|_| lp.tick(&mut hw, &mut link).torque_ref_unm)
        .collect();
    assert_eq!(refs[..3], [100, 200, 300]);
    assert_eq!(refs[9..], [1000, 1000, 1000]);
    link.setpoint = ramp(-250, 400 << 16);
    let refs: Vec<i32> = (0..4)
        .map(|_| lp.tick(&mut hw, &mut link).torque_ref_unm)
        .collect();
    assert_eq!(refs, [600, 200, -200, -250]);
    // A negative rate holds instead of running away; an absurd target is limited.
    link.setpoint = ramp(5, -7);
    assert_eq!(lp.tick(&mut hw, &mut link).torque_ref_unm, -250);
    assert_eq!(TorqueQ16::new(i64::MAX).get(), TorqueQ16::LIMIT);
}

#[test]
fn sums_are_handed_over_in_order_and_overflow_is_counted() {
    let (p, mut lp, mut hw, mut link) = enabled(Reference::Hold);
    // Nobody takes the samples (the supervisor keeps stamping, so the loop keeps driving):
    // the link keeps LINK_SAMPLES, drops and counts the rest.
    let n = p.sample_ticks as usize * (LINK_SAMPLES + 3);
    let ready = (0..n)
        .filter(|_| {
            link.stamp(lp.ticks());
            lp.tick(&mut hw, &mut link).sample_ready
        })
        .count();
    assert_eq!(ready, LINK_SAMPLES + 3);
    assert_eq!(link.samples_dropped(), 3);
    let mut last = 0;
    for _ in 0..LINK_SAMPLES {
        let Some(Input::Sample(s)) = link.next_input() else {
            panic!("sample expected");
        };
        assert_eq!(s.n, p.sample_ticks);
        assert!(s.tick > last);
        last = s.tick;
        // The board holds still at rest: θa sums to n × θa,rest.
        assert_eq!(s.theta_urad, p.theta_a_rest_urad * s.n as i32);
    }
    assert_eq!(link.next_input(), None);
}

#[test]
fn a_loop_fault_switches_off_at_once_and_follows_the_samples_before_it() {
    let (p, mut lp, mut hw, mut link) = enabled(Reference::Set(TorqueQ16::from_unm(50_000)));
    for _ in 0..p.sample_ticks {
        lp.tick(&mut hw, &mut link);
    }
    hw.enc = hw.enc.wrapping_add(5000); // an impossible jump
    let o = lp.tick(&mut hw, &mut link);
    assert!(o.went_off && hw.off);
    assert!(matches!(link.next_input(), Some(Input::Sample(_))));
    assert!(matches!(
        link.next_input(),
        Some(Input::LoopFault {
            reason: FaultReason::EncoderJump { .. },
            ..
        })
    ));
    // Latched: the loop never drives again, whatever the setpoint says.
    for _ in 0..10 {
        lp.tick(&mut hw, &mut link);
        assert!(hw.off);
    }
}

/// A plant-free quasi-static finger (MODEL.md Table 2 contact) in integer steps, enough for a
/// whole grasp: free stiffness to the contact, K_c after it.
struct Finger {
    d: grasp::DriveConfig,
    duty: f64,
    off: bool,
    theta: f64,
}

impl Hardware for Finger {
    fn encoder_count(&mut self) -> u16 {
        let counts = (self.theta - self.d.theta_a_rest_rad) / self.d.rad_per_count();
        (counts.round() as i64 + 1000) as u16
    }
    fn current_raw(&mut self) -> u16 {
        let a = if self.off {
            0.0
        } else {
            self.duty * self.d.bus_v / self.d.resistance_ohm
        };
        (self.d.adc_zero_code + a / self.d.amps_per_code).round() as u16
    }
    fn set_duty(&mut self, duty: i16) {
        self.off = false;
        self.duty = f64::from(duty) / f64::from(grasp::DUTY_MAX);
        self.settle();
    }
    fn bridge_off(&mut self) {
        self.off = true;
        self.settle();
    }
}

impl Finger {
    /// At rest, bridge off, for the drive of `cfg`.
    fn at_rest(cfg: &ControllerConfig) -> Self {
        Finger {
            d: cfg.drive,
            duty: 0.0,
            off: true,
            theta: cfg.drive.theta_a_rest_rad,
        }
    }

    fn settle(&mut self) {
        let (rest, theta_c, ta_c, kc) = (self.d.theta_a_rest_rad, -0.223_771, 0.340_821, 6.7249);
        let t = if self.off {
            0.0
        } else {
            self.duty * self.d.bus_v / self.d.resistance_ohm * self.d.torque_per_amp()
        };
        let k_free = ta_c / (theta_c - rest);
        self.theta = if t <= ta_c {
            rest + t / k_free
        } else {
            theta_c + (t - ta_c) / kc
        };
    }
}

/// The controller for the toy finger: no damping or speed limit (it has no inertia), no
/// back-EMF check (it has no back-EMF), and seated, so that a run passes through every
/// state, `Seating` included, on slow ramps the inertia-free toy follows without jumps.
fn toy_config() -> ControllerConfig {
    ControllerConfig {
        damping_nm_s_per_rad: 0.0,
        approach_speed_max_rad_s: 100.0,
        detect_min_rise_nm: 0.002,
        emf_mismatch_v: 1000.0,
        seating: true,
        step_shape: grasp::StepShape::Ramp(1.0),
        ..ControllerConfig::DEFAULT
    }
    .with_delta_ta(0.5)
}

/// The firmware's arrangement: the supervisor runs only every `every` ticks (a busy
/// lower-priority task), on everything the loop left. The state machine must reach the same
/// estimate as the composed controller ticking it every period, since it acts per sample.
#[test]
fn a_late_supervisor_changes_nothing_while_the_link_has_room() {
    let cfg = toy_config();
    let run = |every: u32| -> (State, Option<i32>, u32) {
        let mut hw = Finger::at_rest(&cfg);
        let (mut lp, mut link, mut sup) = Controller::new(cfg).unwrap().into_parts();
        let mut k2 = None;
        for tick in 1..=60_000u32 {
            lp.tick(&mut hw, &mut link);
            // Run at the end of each sample interval (as the firmware's spawn does), or only
            // every `every` ticks.
            if tick % every == 0 && sup.service(&mut link) {
                let req = sup.take_request().unwrap();
                sup.deliver(run_estimate(&pts::Finger::PAPER, &cfg.drive, &req));
                sup.publish(&mut link);
                k2 = sup.result().and_then(|r| r.k2_um);
            }
            if matches!(sup.state(), State::Holding | State::Fault(_)) {
                break;
            }
        }
        (sup.state(), k2, link.samples_dropped())
    };
    let p = cfg.params().unwrap();
    let on_time = run(1);
    assert_eq!(on_time.0, State::Holding, "{on_time:?}");
    assert!(on_time.1.is_some());
    // Late by a whole sample: the setpoints reach the loop later, the samples do not change
    // their order, nothing is dropped; the estimate moves by at most a few µm.
    let late = run(p.sample_ticks * 2);
    assert_eq!(late.0, State::Holding, "{late:?}");
    assert_eq!(late.2, 0);
    let (a, b) = (on_time.1.unwrap(), late.1.unwrap());
    println!("k2 on time {a} µm, late {b} µm");
    assert!((a - b).abs() <= 750, "k2 {a} µm on time vs {b} µm late");
}

/// The supervisor's heartbeat: in every state the supervisor can stop in (its task stalled,
/// starved or stuck in a lock), the loop switches the bridge off within
/// `max_setpoint_age_ticks` + 1 ticks of the last stamp, latches, and the supervisor, if it
/// ever runs again, reports `SupervisorStalled`.
#[test]
fn a_stalled_supervisor_switches_the_bridge_off_in_every_state() {
    let cfg = toy_config();
    let mut seen = Vec::new();
    for stop_in in [
        State::Calibrating,
        State::Approach,
        State::Seating,
        State::Step,
        State::Settling,
        State::Estimating,
        State::Holding,
    ] {
        let mut hw = Finger::at_rest(&cfg);
        let (mut lp, mut link, mut sup) = Controller::new(cfg).unwrap().into_parts();
        let max_age = lp.max_setpoint_age_ticks();
        assert_eq!(
            max_age,
            LINK_SAMPLES as u32 * cfg.params().unwrap().sample_ticks
        );
        // Run normally until the state is reached (the estimate is delivered at once, except
        // when the stall is to happen while estimating).
        let mut reached = false;
        for _ in 0..60_000u32 {
            lp.tick(&mut hw, &mut link);
            if sup.service(&mut link) && stop_in != State::Estimating {
                let req = sup.take_request().unwrap();
                sup.deliver(run_estimate(&pts::Finger::PAPER, &cfg.drive, &req));
                sup.publish(&mut link);
            }
            if sup.state() == stop_in {
                reached = true;
                break;
            }
        }
        assert!(reached, "never reached {stop_in:?}");
        // One more tick, so the loop applies what the supervisor just published.
        lp.tick(&mut hw, &mut link);
        sup.service(&mut link);
        let was_driving = lp.driving();
        // The supervisor stops: the loop goes on alone.
        let last_stamp = link.stamp_tick();
        let mut off_at = None;
        for _ in 0..(max_age + 50) {
            let o = lp.tick(&mut hw, &mut link);
            if hw.off && !lp.driving() && off_at.is_none() {
                off_at = Some(o.tick);
            }
            if off_at.is_some() {
                assert!(
                    hw.off && o.duty == 0,
                    "drove again after the trip in {stop_in:?}"
                );
            }
        }
        let off_at = off_at.expect("bridge off");
        if stop_in == State::Calibrating {
            // Never enabled: the bridge never came on.
            assert!(!was_driving);
            continue;
        }
        assert!(
            was_driving,
            "{stop_in:?}: the loop was driving before the stall"
        );
        assert!(
            off_at.wrapping_sub(last_stamp) <= max_age + 1,
            "{stop_in:?}: off {} ticks after the last stamp",
            off_at.wrapping_sub(last_stamp)
        );
        // The supervisor wakes: the loop's reason reaches the state machine.
        sup.service(&mut link);
        assert!(
            matches!(
                sup.state(),
                State::Fault(FaultReason::SupervisorStalled { age_ticks }) if age_ticks == max_age + 1
            ),
            "{stop_in:?}: {:?}",
            sup.state()
        );
        // And the loop stays off whatever the supervisor now asks.
        link.stamp(lp.ticks());
        link.setpoint = Setpoint {
            enable: true,
            reference: Reference::Set(TorqueQ16::from_unm(100_000)),
            damp_unm: 0,
        };
        lp.tick(&mut hw, &mut link);
        assert!(hw.off);
        seen.push((stop_in, off_at.wrapping_sub(last_stamp)));
    }
    println!("supervisor stalled in state → bridge off (ticks after the last stamp): {seen:?}");
    assert_eq!(seen.len(), 6);
}

/// The heartbeat does not trip a supervisor that keeps up: run the whole grasp with the
/// supervisor as late as the link allows minus one sample.
#[test]
fn a_supervisor_late_by_less_than_the_link_never_trips_the_heartbeat() {
    let cfg = toy_config();
    let p = cfg.params().unwrap();
    let mut hw = Finger::at_rest(&cfg);
    let (mut lp, mut link, mut sup) = Controller::new(cfg).unwrap().into_parts();
    let every = p.sample_ticks * (LINK_SAMPLES as u32 - 1);
    for tick in 1..=60_000u32 {
        lp.tick(&mut hw, &mut link);
        if tick % every == 0 && sup.service(&mut link) {
            let req = sup.take_request().unwrap();
            sup.deliver(run_estimate(&pts::Finger::PAPER, &cfg.drive, &req));
            sup.publish(&mut link);
        }
        if matches!(sup.state(), State::Holding | State::Fault(_)) {
            break;
        }
    }
    assert_eq!(sup.state(), State::Holding);
}

/// A current ADC pinned at a rail while driving is a fault of its own after the over-current
/// time, bridge off (named as the sensor at its rail, not as an over-current: the current
/// beyond the rail is unknown).
#[test]
fn an_adc_pinned_at_a_rail_while_driving_trips_adc_rail() {
    for rail in [0u16, 4095] {
        let (p, mut lp, mut hw, mut link) = enabled(Reference::Hold);
        hw.code = rail;
        let mut tripped_after = None;
        for n in 1..=p.overcurrent_ticks + 5 {
            let o = lp.tick(&mut hw, &mut link);
            if o.went_off {
                tripped_after = Some(n);
                break;
            }
        }
        assert_eq!(tripped_after, Some(p.overcurrent_ticks), "rail {rail}");
        assert!(hw.off);
        let mut fault = None;
        while let Some(i) = link.next_input() {
            if let Input::LoopFault { reason, .. } = i {
                fault = Some(reason);
            }
        }
        assert_eq!(fault, Some(FaultReason::AdcRail { code: rail }));
    }
}

/// A limit the sensor cannot read is refused when the configuration is validated.
#[test]
fn an_overcurrent_limit_beyond_the_sensor_range_is_refused() {
    let d = ControllerConfig::DEFAULT.drive;
    let full_scale_a = d.adc_zero_code.min(4095.0 - d.adc_zero_code) * d.amps_per_code;
    let with = |a: f64| ControllerConfig {
        overcurrent_a: a,
        ..ControllerConfig::DEFAULT
    };
    assert!(with(0.9 * full_scale_a).params().is_ok());
    assert_eq!(
        with(full_scale_a).params(),
        Err(grasp::config::ConfigError::OverCurrentBeyondSensor)
    );
    // The same limit with a sensor of half the range (twice the gain): refused.
    let mut half = ControllerConfig::DEFAULT;
    half.drive.amps_per_code = d.amps_per_code / 2.0;
    assert!(ControllerConfig::DEFAULT.params().is_ok());
    assert_eq!(
        half.params(),
        Err(grasp::config::ConfigError::OverCurrentBeyondSensor)
    );
}

/// The estimate task's static slot: `take_request_into` overwrites whatever an earlier grasp
/// left in it (more samples than this one took, other fields), fills it with exactly what the
/// supervisor collected, once, and leaves it alone when no request is ready.
#[test]
fn the_request_slot_is_refilled_whole_and_only_once() {
    let cfg = toy_config();
    let mut hw = Finger::at_rest(&cfg);
    let (mut lp, mut link, mut sup) = Controller::new(cfg).unwrap().into_parts();
    let mut slot = grasp::EstimateRequest::EMPTY;
    // A stale request, larger in every list than the one to come.
    let junk = grasp::estimate::Sample {
        tick: 7,
        theta_a_urad: -1,
        torque_unm: -2,
        torque_ref_unm: -3,
    };
    while slot.pre.push(junk).is_ok() {}
    while slot.path.push(junk).is_ok() {}
    slot.end = junk;
    slot.dt_ns = 1;
    assert!(
        !sup.take_request_into(&mut slot),
        "no request before the step"
    );
    assert_eq!(slot.dt_ns, 1);
    let mut ready = false;
    for _ in 0..60_000u32 {
        lp.tick(&mut hw, &mut link);
        if sup.service(&mut link) {
            ready = true;
            break;
        }
    }
    assert!(ready, "no request; state {:?}", sup.state());
    assert!(sup.take_request_into(&mut slot));
    let req = slot.clone();
    assert!(!req.path.is_empty() && req.path.len() < req.path.capacity());
    // The history before the contact is full by then: every entry must be this grasp's.
    assert!(!req.pre.is_empty());
    assert!(req.pre.iter().chain(req.path.iter()).all(|s| *s != junk));
    assert_ne!(req.end, junk);
    assert_eq!(req.dt_ns, cfg.params().unwrap().dt_ns);
    // The path runs from the contact's detection to the settled end, in time order.
    assert!(req.path.windows(2).all(|w| w[0].tick < w[1].tick));
    assert!(req.pre.last().unwrap().tick <= req.path[0].tick);
    // Taken once: a second call changes nothing, and the estimate on it is the one delivered.
    assert!(!sup.take_request_into(&mut slot));
    assert_eq!(slot, req);
    sup.deliver(run_estimate(&pts::Finger::PAPER, &cfg.drive, &slot));
    sup.publish(&mut link);
    assert!(
        matches!(sup.state(), State::Holding | State::Releasing),
        "{:?}",
        sup.state()
    );
}
