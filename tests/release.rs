//! The release against the plant: after the estimate the torque ramps down and a small
//! opening torque takes the finger back to rest through a gear its springs cannot back-drive,
//! then the bridge goes off. Without the opening torque the finger stays near the object.
mod common;

use common::*;
use grasp::{AfterEstimate, Event, State};

fn released(open_torque_nm: f64) -> Outcome {
    let s = plant::scenes::table2();
    let cfg = grasp::ControllerConfig {
        after_estimate: AfterEstimate::Release,
        open_torque_nm,
        ..config(&s, 0.8)
    };
    run(&s, cfg, 30.0, 0.5, |_, _, _| {})
}

#[test]
fn a_release_opens_the_finger_back_to_rest_and_switches_the_bridge_off() {
    let s = plant::scenes::table2();
    let rest = plant::Plant::new(&s).unwrap().theta_a_rest_rad();
    let cfg = grasp::ControllerConfig::DEFAULT;
    let o = released(cfg.open_torque_nm);
    assert_eq!(o.state, State::Done, "{:?}", o.events);
    assert!(o.bridge_off);
    let at = |pick: fn(&Event) -> bool| {
        let i = o.events.iter().position(pick).expect("event");
        (o.event_truth[i].t_s, o.event_truth[i].theta_a_rad)
    };
    let (t_rel, theta_rel) = at(|e| matches!(e, Event::Releasing { .. }));
    let (t_done, theta_done) = at(|e| matches!(e, Event::Released { .. }));
    println!(
        "release: θa {:.4} → {:.4} rad (rest {rest:.4}) in {:.2} s",
        theta_rel - rest,
        theta_done - rest,
        t_done - t_rel
    );
    // Back within the controller's end band (plus a little overshoot of the coasting finger).
    assert!(
        (theta_done - rest).abs() <= cfg.open_end_rad + 0.02,
        "{theta_done} vs rest {rest}"
    );
    assert!(t_done - t_rel < cfg.open_timeout_s + 2.0);
}

#[test]
fn without_the_opening_torque_the_finger_stays_closed() {
    let s = plant::scenes::table2();
    let rest = plant::Plant::new(&s).unwrap().theta_a_rest_rad();
    let o = released(0.0);
    assert_eq!(o.state, State::Done);
    let i = o
        .events
        .iter()
        .position(|e| matches!(e, Event::Released { .. }))
        .expect("released");
    let left = o.event_truth[i].theta_a_rad - rest;
    println!("torque down, no opening torque: θa {left:.4} rad from rest");
    assert!(left > 0.3, "{left}");
}

/// The device's path: hold, then `release()` on command (refused outside holding).
#[test]
fn release_on_command_from_holding_only() {
    let s = plant::scenes::table2();
    let mut hw = PlantHw::new(plant::Plant::new(&s).unwrap());
    let rest = hw.plant.theta_a_rest_rad();
    let cfg = config(&s, 0.8);
    let mut c = grasp::Controller::new(cfg).unwrap();
    let mut released_at = None;
    for n in 0..(40.0 / s.dt_s) as u64 {
        let out = grasp::tick_dyn(&mut c, &mut hw);
        if out.estimate_ready {
            let req = c.take_request().unwrap();
            c.deliver(&mut hw, grasp::run_estimate(&cfg.finger, &cfg.drive, &req));
        }
        hw.advance();
        match c.state() {
            State::Approach => assert!(!c.release(), "release accepted while approaching"),
            State::Holding if released_at.is_none() && n % 1000 == 0 => {
                assert!(c.release());
                released_at = Some(hw.plant.truth().t_s);
            }
            State::Done | State::Fault(_) => break,
            _ => {}
        }
    }
    assert_eq!(c.state(), State::Done);
    assert!(hw.is_off());
    let t = hw.plant.truth();
    println!(
        "released on command: θa {:.4} rad from rest after {:.2} s",
        t.theta_a_rad - rest,
        t.t_s - released_at.unwrap()
    );
    assert!((t.theta_a_rad - rest).abs() <= cfg.open_end_rad + 0.02);
}
