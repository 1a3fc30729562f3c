//! Faults injected through the plant end in the safe state (bridge off, torque reference
//! zero) with the right reason; a proximal contact is reported as proximal (or as the
//! stated proximal-or-near-O2 ambiguity).
mod common;

use common::*;
use grasp::{Event, FaultReason, Located, State};
use plant::{ContactState, Fault, Scene};

fn table2_ideal() -> Scene {
    plant::scenes::by_name("table2_ideal").expect("scene")
}

/// The fault event is the last controller event and matches the final state; the bridge is
/// off and the plant's motor current decays to zero.
fn assert_safe(o: &Outcome) -> FaultReason {
    let State::Fault(reason) = o.state else {
        panic!(
            "not in the safe state: {:?}; events {:?}",
            o.state, o.events
        );
    };
    assert!(o.bridge_off, "bridge still on after {reason:?}");
    match o.events.last() {
        Some(Event::Fault { reason: r, .. }) => assert_eq!(*r, reason),
        e => panic!("last event {e:?}"),
    }
    reason
}

#[test]
fn second_contact_is_detected() {
    // Large cylinders near O2: the finger first touches them with the proximal phalanx, then
    // the distal one touches too while the torque rises (the plant reports it).
    for scene in second_contact_scenes() {
        let scene = scene.ideal();
        let o = run(&scene, config(&scene, 0.8), 20.0, 0.2, |_, _, _| {});
        let name = touching_label(&scene);
        println!(
            "{name}: {:?}, plant second contact at {:?} s",
            o.state, o.second_contact_s
        );
        assert!(
            o.second_contact_s.is_some(),
            "{name}: the plant saw no second contact"
        );
        let r = assert_safe(&o);
        assert!(
            matches!(r, FaultReason::SecondContact { .. }),
            "{name}: {r:?}"
        );
    }
}

#[test]
fn loss_of_contact_while_holding_and_during_the_step() {
    for when in [State::Step, State::Holding] {
        let scene = table2_ideal();
        let mut done = false;
        let o = run(&scene, config(&scene, 0.5), 20.0, 0.2, |_, st, p| {
            if st == when && !done {
                p.inject(Fault::RemoveObject);
                done = true;
            }
        });
        assert!(done, "never reached {when:?}");
        let r = assert_safe(&o);
        assert!(
            matches!(r, FaultReason::LossOfContact { .. }),
            "removed in {when:?}: {r:?}"
        );
    }
}

#[test]
fn encoder_jump_and_stuck_encoder_are_sensor_faults() {
    let scene = table2_ideal();
    // A jump of 5000 counts in one tick, during the approach.
    let mut done = false;
    let o = run(&scene, config(&scene, 0.5), 20.0, 0.1, |t, _, p| {
        if t > 1.0 && !done {
            p.inject(Fault::EncoderJump(5000));
            done = true;
        }
    });
    let r = assert_safe(&o);
    assert!(matches!(r, FaultReason::EncoderJump { .. }), "{r:?}");
    assert!(r.is_sensor_fault());
    // The encoder freezes while the finger closes: caught by the back-EMF check.
    let mut done = false;
    let o = run(&scene, config(&scene, 0.5), 20.0, 0.1, |t, _, p| {
        if t > 1.0 && !done {
            p.inject(Fault::EncoderStuck);
            done = true;
        }
    });
    let r = assert_safe(&o);
    assert!(
        matches!(r, FaultReason::EncoderMismatch { .. }),
        "stuck encoder: {r:?}"
    );
    assert!(r.is_sensor_fault());
    let t_fault = o.t_end_s - 0.1;
    println!("stuck encoder at 1.0 s caught at {t_fault:.3} s: {r:?}");
    assert!(t_fault < 1.1, "caught late: {t_fault} s");
}

#[test]
fn shorted_winding_is_over_current() {
    // The winding resistance drops to 2 Ω while holding: the current overshoots the limit.
    for name in ["table2_ideal", "table2"] {
        let scene = plant::scenes::by_name(name).expect("scene");
        let mut done = false;
        let o = run(&scene, config(&scene, 0.5), 20.0, 0.2, |_, st, p| {
            if st == State::Holding && !done {
                p.inject(Fault::Short(2.0));
                done = true;
            }
        });
        assert!(done);
        let r = assert_safe(&o);
        assert!(
            matches!(r, FaultReason::OverCurrent { .. }),
            "{name}: {r:?}"
        );
    }
}

#[test]
fn proximal_contact_is_reported_as_proximal() {
    for name in ["proximal_vertex_k1_50"] {
        for ideal in [true, false] {
            let mut scene = plant::scenes::by_name(name).expect("scene");
            if ideal {
                scene = scene.ideal();
            }
            let o = run(&scene, config(&scene, 0.5), 20.0, 0.0, |_, _, _| {});
            let truth = o.truth_settled.expect("settled");
            assert_eq!(truth.contact, ContactState::Proximal);
            let r = o
                .estimate
                .unwrap_or_else(|| panic!("{name}: no estimate, {:?}", o.state))
                .unwrap_or_else(|e| panic!("{name}: estimate refused: {e:?}"));
            println!("{name} ideal={ideal}: {r:?}");
            assert!(
                matches!(r.located, Located::Proximal | Located::ProximalOrNearO2),
                "{name} ideal={ideal}: {r:?}"
            );
        }
    }
}

#[test]
fn no_object_ends_in_the_safe_state() {
    // No object: the finger closes onto its joint stops. Whatever the stiffness there reads
    // as, the grasp must end in the safe state, never in Holding with a contact.
    let scene = plant::scenes::by_name("free").expect("scene").ideal();
    let o = run(&scene, config(&scene, 0.5), 30.0, 0.1, |_, _, _| {});
    println!("free: {:?} events {:?}", o.state, o.events);
    let r = assert_safe(&o);
    println!("no object: {r:?}");
}

#[test]
fn release_after_the_estimate_ends_with_the_bridge_off() {
    let scene = table2_ideal();
    let cfg = grasp::ControllerConfig {
        after_estimate: grasp::AfterEstimate::Release,
        ..config(&scene, 0.5)
    };
    let o = run(&scene, cfg, 20.0, 0.1, |_, _, _| {});
    assert_eq!(o.state, State::Done, "{:?}", o.events);
    assert!(o.bridge_off);
    assert!(matches!(o.events.last(), Some(Event::Released { .. })));
    assert!(matches!(o.estimate, Some(Ok(_))));
}

#[test]
fn undelivered_estimate_times_out_into_the_safe_state() {
    // The application never runs the estimate: the controller must not hold forever.
    let scene = table2_ideal();
    let plant = plant::Plant::new(&scene).unwrap();
    let mut hw = PlantHw::new(plant);
    let mut c = grasp::Controller::new(config(&scene, 0.5)).unwrap();
    let mut requested = false;
    for _ in 0..(20.0 / scene.dt_s) as u64 {
        let o = c.tick(&mut hw);
        requested |= o.estimate_ready;
        hw.advance();
        if matches!(c.state(), State::Fault(_)) {
            break;
        }
    }
    assert!(requested);
    assert_eq!(c.state(), State::Fault(FaultReason::EstimateTimeout));
    assert!(hw.is_off());
}

#[test]
fn torque_step_instead_of_ramp_gives_the_same_estimate() {
    // ΔT_a applied as one step: the impact is absorbed by the damping and the two-point
    // estimate uses static points only, so it matches the ramp's within the grid's noise.
    let scene = table2_ideal();
    let mut k = Vec::new();
    for shape in [grasp::StepShape::Ramp(1.0), grasp::StepShape::Step] {
        let cfg = grasp::ControllerConfig {
            step_shape: shape,
            estimator: grasp::Estimator::TwoPoint,
            ..config(&scene, 0.8)
        };
        let o = run(&scene, cfg, 20.0, 0.0, |_, _, _| {});
        assert_eq!(o.state, State::Holding, "{shape:?}: {:?}", o.events);
        k.push(k2_hat(&o).unwrap());
    }
    println!("k2_hat ramp {:.5} m, step {:.5} m", k[0], k[1]);
    assert!((k[0] - k[1]).abs() < 0.005 * L2, "{k:?}");
}
