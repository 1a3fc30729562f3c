//! The rest check against the plant: a finger powered up away from its rest pose (the plant's
//! `faults.power_up_offset_rad`, the encoder reading 0 there) is found against its open stop,
//! the encoder zeroed from there, and the grasp's estimate is the one of a finger powered up
//! at rest; without the check the same power-up shifts θa,c by the offset. A finger that never
//! reaches a stop (encoder stuck) is refused with the bridge off within the stated time.
mod common;

use common::*;
use grasp::{FaultReason, RestCheck, State};
use plant::{Plant, Scene};

fn scene(offset_rad: f64) -> Scene {
    let mut s = plant::scenes::table2();
    s.faults.power_up_offset_rad = offset_rad;
    s
}

fn checked(scene: &Scene) -> grasp::ControllerConfig {
    grasp::ControllerConfig {
        rest_check: Some(RestCheck::PAPER),
        ..config(scene, 0.8)
    }
}

/// θa,c of a delivered estimate (rad).
fn theta_c(o: &Outcome) -> f64 {
    match o.estimate {
        Some(Ok(r)) => f64::from(r.theta_a_c_urad) * 1e-6,
        ref e => panic!("no estimate: {:?} {e:?}", o.state),
    }
}

/// Drives the plant of `s` open at the stall duty of `c`'s opening torque for `ticks`; returns
/// its truth there, with θa and the gear's angle from the plant's rest, and θa from rest where
/// `c` expects the lock: the stop less the stop's compliance under the opening torque net of
/// the springs' share and the friction. The plant's truth, independent of the check's code.
fn drive_open(s: &Scene, c: &RestCheck, ticks: u32) -> (plant::Truth, f64, f64, f64) {
    let mut p = Plant::new(s).unwrap();
    let rest = p.theta_a_rest_rad();
    let d = drive_config(s);
    let stall_full = d.torque_per_amp() * d.bus_v / d.resistance_ohm;
    for _ in 0..ticks {
        p.step(-c.open_torque_nm / stall_full);
    }
    let t = p.truth();
    let expect = c.stop_from_rest_rad
        - (c.open_torque_nm - c.stop_spring_nm - c.friction_nm) * c.stop_compliance_rad_per_nm;
    (t, t.theta_a_rad - rest, t.gear_out_rad - rest, expect)
}

/// The stop the check assumes is where the plant's finger locks: both joints on their
/// extension stops, found by driving it open with the check's torque (independent of the
/// check's own code: the plant's truth).
#[test]
fn the_paper_stop_angle_is_where_the_plant_locks() {
    let c = RestCheck::PAPER;
    let (t, got, gear, expect) = drive_open(&plant::scenes::table2(), &c, 30_000);
    assert_eq!(t.contact, plant::ContactState::Locked);
    println!("plant locks at {got:.5} rad from rest, the check assumes {expect:.5}");
    // The encoder is on the motor: the gear sits on its opening flank there.
    let expect_gear = expect - 0.5 * c.backlash_rad;
    println!("gear at {gear:.5} rad from rest, the check assumes {expect_gear:.5}");
    assert!((gear - expect_gear).abs() < 3e-4, "{gear} vs {expect_gear}");
    // Stiction beyond the Coulomb friction (0.038 N·m / 200) and two encoder counts.
    assert!((got - expect).abs() < 3e-4, "{got} vs {expect}");
}

#[test]
fn powered_up_away_from_rest_is_homed_and_the_estimate_is_right() {
    let at_rest = run(&scene(0.0), checked(&scene(0.0)), 60.0, 0.0, |_, _, _| {});
    let reference = theta_c(&at_rest);
    // The check leaves the grasp of a finger powered up at rest as it was.
    let unchecked = theta_c(&run(
        &scene(0.0),
        config(&scene(0.0), 0.8),
        60.0,
        0.0,
        |_, _, _| {},
    ));
    println!("at rest without the check: θa,c {unchecked:.5}");
    assert!(
        (unchecked - reference).abs() < 3e-4,
        "{unchecked} vs {reference}"
    );
    let r0 = at_rest.rest_report.expect("rest report");
    println!("at rest: {r0:?}, θa,c {reference:.5}");
    let upc = drive_config(&scene(0.0)).rad_per_count();
    assert!((f64::from(r0.power_up_counts) * upc).abs() < 1e-3, "{r0:?}");
    for off in [0.2, 0.45] {
        let s = scene(off);
        // Without the check: the encoder zero is `off` wrong and so is θa,c.
        let blind = run(&s, config(&s, 0.8), 60.0, 0.0, |_, _, _| {});
        let o = run(&s, checked(&s), 60.0, 0.0, |_, _, _| {});
        let r = o.rest_report.expect("rest report");
        let seen = f64::from(r.power_up_counts) * upc;
        let th = theta_c(&o);
        println!(
            "powered up {off} rad flexed: check saw {seen:.4} rad, stop after {:.3} s, \
             back at rest after {:.3} s; θa,c {th:.5} (at rest {reference:.5}); without the \
             check {:?}",
            f64::from(r.stop_ticks) * s.dt_s,
            f64::from(r.done_ticks) * s.dt_s,
            blind.estimate.map(|e| e.map(|e| e.theta_a_c_urad))
        );
        assert!((seen - off).abs() < 2e-3, "power-up pose {seen} vs {off}");
        assert!((th - reference).abs() < 3e-4, "θa,c {th} vs {reference}");
        if let Some(Ok(b)) = blind.estimate {
            let tb = f64::from(b.theta_a_c_urad) * 1e-6;
            assert!((tb - reference).abs() > 0.5 * off, "without the check {tb}");
        }
    }
}

/// A stuck encoder: while the motor turns (back-EMF, little current) a still count is not
/// taken for the stop; once the finger is against it (stall current) the stop is found, but
/// the return never shows the rest: refused at the return's timeout with the bridge off,
/// never driven towards an approach.
#[test]
fn a_stuck_encoder_is_refused_with_the_bridge_off() {
    let mut s = scene(0.3);
    s.faults.encoder_stuck_at_s = 0.0;
    let cfg = checked(&s);
    let o = run(&s, cfg, 30.0, 0.05, |_, _, _| {});
    println!("{:?} at {:.3} s", o.state, o.t_end_s);
    assert!(matches!(
        o.state,
        State::Fault(FaultReason::RestNotFound {
            returning: true,
            ..
        })
    ));
    assert!(o.bridge_off);
    assert!(o.estimate.is_none());
    // Refused within the two phases' timeouts (+ the 0.05 s run-out of the harness).
    assert!(
        o.t_end_s <= 2.0 * RestCheck::PAPER.timeout_s + 0.06,
        "{}",
        o.t_end_s
    );
}

/// A finger powered up so far flexed (no object) that the gentle opening (≈ 0.07 rad/s)
/// cannot reach the stop within the timeout: the opening phase refuses at its timeout.
#[test]
fn no_stop_within_the_timeout_is_refused_with_the_bridge_off() {
    let mut s = Scene::DEFAULT;
    s.faults.power_up_offset_rad = 0.9;
    let o = run(&s, checked(&s), 30.0, 0.05, |_, _, _| {});
    println!("{:?} at {:.3} s", o.state, o.t_end_s);
    assert!(matches!(
        o.state,
        State::Fault(FaultReason::RestNotFound {
            returning: false,
            ..
        })
    ));
    assert!(o.bridge_off);
    assert!(
        o.t_end_s <= RestCheck::PAPER.timeout_s + 0.06,
        "{}",
        o.t_end_s
    );
}

/// The simulated board's check for the paper finger is the paper one (its stop from the
/// geometry agrees with the constant written from it within 0.1 mrad).
#[test]
fn the_simulated_board_uses_the_paper_check_for_the_paper_finger() {
    let s = plant::scenes::table2();
    let c = sim_board::scene_rest_check(&s).unwrap();
    println!(
        "stop from rest (geometry): {:.6} rad, springs {:.6} N·m",
        c.stop_from_rest_rad, c.stop_spring_nm
    );
    let p = RestCheck::PAPER;
    assert!((c.stop_from_rest_rad - p.stop_from_rest_rad).abs() < 1e-5);
    assert!((c.stop_spring_nm - p.stop_spring_nm).abs() < 1e-3);
    assert!((c.friction_nm - p.friction_nm).abs() < 1e-3);
    assert_eq!(c.backlash_rad, RestCheck::PAPER.backlash_rad);
    assert_eq!(
        c.stop_compliance_rad_per_nm,
        RestCheck::PAPER.stop_compliance_rad_per_nm
    );
}

/// The check drives the motor, so its current is watched as the grasp's is: with the winding
/// shorted to 2 Ω at power-up the opening duty stalls at 0.58 A (about 5 N·m) against the
/// stop; over-current trips within the over-current time of the current passing the limit,
/// bridge off, instead of taking the stall for the stop.
#[test]
fn a_short_during_the_check_trips_over_current() {
    let mut s = scene(0.2);
    s.faults.short_at_s = 0.0;
    s.faults.short_r_ohm = 2.0;
    let cfg = checked(&s);
    let (mut run_s, mut longest_s) = (0.0f64, 0.0f64);
    let o = run(&s, cfg, 8.0, 0.01, |_, _, p| {
        if p.truth().current_a.abs() > cfg.overcurrent_a {
            run_s += s.dt_s;
            longest_s = longest_s.max(run_s);
        } else {
            run_s = 0.0;
        }
    });
    println!(
        "{:?} at {:.4} s; longest time above {} A: {:.4} s",
        o.state, o.t_end_s, cfg.overcurrent_a, longest_s
    );
    assert!(matches!(
        o.state,
        State::Fault(FaultReason::OverCurrent { .. })
    ));
    assert!(o.bridge_off && o.rest_report.is_none());
    // The over-current time plus a tick and the winding's decay with the bridge off.
    assert!(
        longest_s > 0.0 && longest_s <= cfg.overcurrent_s + 5e-4,
        "{longest_s}"
    );
}

/// A finger whose extension stops sit further from its rest than the prototype's (a finger
/// file's `[stops]`; here both 0.12 rad below the rest angles, on its free-motion path): the
/// check built from them (`sim_board::finger_rest_check`, what build.rs bakes into the board)
/// expects the plant's lock where the plant locks, and a finger powered up flexed is homed to
/// the θa,c of one powered up at rest. The prototype's check (`RestCheck::PAPER`) on the same
/// finger zeroes the encoder at the wrong stop.
#[test]
fn a_finger_file_s_stops_reach_the_rest_check() {
    let finger = pts::Finger::PAPER;
    let stops = pts::Stops {
        theta1_min_rad: finger.theta01 - 0.12,
        theta2_min_rad: finger.theta02 - 0.12,
        stiffness_nm_per_rad: 200.0,
    };
    let base = plant::scenes::table2();
    let drive = drive_config(&base);
    let at = |offset_rad: f64| {
        let mut s = sim_board::scene_for_finger(base, &finger, &drive, &stops);
        s.faults.power_up_offset_rad = offset_rad;
        s
    };
    let check = sim_board::finger_rest_check(&finger, &drive, &stops).unwrap();
    let p = RestCheck::PAPER;
    println!(
        "stop from rest: file {:.5} rad (paper {:.5}), springs there {:.4} N·m (paper {:.4})",
        check.stop_from_rest_rad, p.stop_from_rest_rad, check.stop_spring_nm, p.stop_spring_nm
    );
    // Where the plant locks when driven open (6 s: the drive opens at about 0.07 rad/s),
    // against where the check expects it.
    let (t, got, _, expect) = drive_open(&at(0.0), &check, 60_000);
    assert_eq!(t.contact, plant::ContactState::Locked);
    println!("plant locks at {got:.5} rad from rest, the file's check expects {expect:.5}");
    // The check's stop model (both joints on their stops, 1/k of compliance at the crank) is
    // approximate beyond the prototype's stops: within 1 mrad here (30 encoder counts, under
    // 1 mN·m of free-motion torque), against the 0.11 rad the prototype's check is off.
    const TOL_RAD: f64 = 1e-3;
    assert!((got - expect).abs() < TOL_RAD, "{got} vs {expect}");
    let with = |s: &Scene, c: RestCheck| grasp::ControllerConfig {
        rest_check: Some(c),
        ..config(s, 0.8)
    };
    let reference = theta_c(&run(
        &at(0.0),
        config(&at(0.0), 0.8),
        60.0,
        0.0,
        |_, _, _| {},
    ));
    let s = at(0.3);
    let th = theta_c(&run(&s, with(&s, check), 60.0, 0.0, |_, _, _| {}));
    let paper = run(&s, with(&s, p), 60.0, 0.0, |_, _, _| {});
    let th_paper = paper
        .estimate
        .and_then(Result::ok)
        .map(|e| f64::from(e.theta_a_c_urad) * 1e-6);
    println!(
        "powered up 0.3 rad flexed: θa,c {th:.5} with the file's check, {th_paper:.5?} with the \
         prototype's (at rest {reference:.5})"
    );
    assert!((th - reference).abs() < TOL_RAD, "θa,c {th} vs {reference}");
    // The prototype's stop is 0.11 rad nearer the rest: the zero, and θa,c, that far off.
    let off = check.stop_from_rest_rad - p.stop_from_rest_rad;
    assert!(off.abs() > 0.05, "the stops differ by {off} rad only");
    if let Some(tp) = th_paper {
        assert!(
            (tp - reference).abs() > 0.5 * off.abs(),
            "θa,c {tp} vs {reference}"
        );
    }
}
