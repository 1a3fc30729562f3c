//! Garbage and abuse: random duties (with NaN/inf), random fault injection, every scene.
//! Nothing may panic, the truth stays finite, the event queue never overflows silently.

use plant::drive::Input;
use plant::sensors::Rng;
use plant::{scenes, Fault, Plant};

#[test]
fn random_abuse_never_panics() {
    let mut rng = Rng::new(42);
    for name in scenes::NAMES {
        for ideal in [false, true] {
            let mut s = scenes::by_name(name).unwrap();
            if ideal {
                s = s.ideal();
            }
            let mut p = Plant::new(&s).unwrap();
            let mut duty = 0.0;
            for k in 0..20_000 {
                if k % 2000 == 0 {
                    duty = rng.uniform() * 3.0 - 1.5;
                }
                let r = rng.uniform();
                let input = if r < 0.002 {
                    Input::Duty(f64::NAN)
                } else if r < 0.004 {
                    Input::Current(f64::INFINITY)
                } else if r < 0.006 {
                    Input::Off
                } else if r < 0.008 {
                    Input::MotorTorque(-1e9)
                } else {
                    Input::Duty(duty)
                };
                p.step_input(input);
                if r > 0.9995 {
                    let f = match (rng.next_u64() % 5) as u8 {
                        0 => Fault::EncoderStuck,
                        1 => Fault::EncoderJump(i32::MAX),
                        2 => Fault::Short(1e-9),
                        3 => Fault::RemoveObject,
                        _ => Fault::Clear,
                    };
                    p.inject(f);
                }
                while let Some(e) = p.poll_event() {
                    if let plant::EventKind::SolverFailure(err) = e.kind {
                        println!("{name} ideal={ideal} k={k}: solver failure {err:?} at {e:?}");
                    }
                }
                let t = p.truth();
                assert!(
                    t.theta_a_rad.is_finite()
                        && t.torque_a_nm.is_finite()
                        && t.current_a.is_finite(),
                    "{name}: {t:?}"
                );
                let _ = (p.encoder_count(), p.current_adc(), p.measured_torque_nm());
            }
            assert_eq!(p.events_dropped(), 0, "{name}");
        }
    }
}

/// Random objects (vertex or cylinder up to 15 cm, either phalanx, anywhere along it, contact
/// anywhere on the closing path), closed at full duty then driven by random duties: the solver
/// never fails (every outcome is a typed event: contact, loss, beyond tip, second contact,
/// joint limit, jam).
#[test]
fn random_objects_never_break_the_solver() {
    let mut rng = Rng::new(7);
    for case in 0..80 {
        let ph = if rng.uniform() < 0.3 {
            plant::Phalanx::Proximal
        } else {
            plant::Phalanx::Distal
        };
        let len = if ph == plant::Phalanx::Proximal {
            0.1
        } else {
            0.075
        };
        let spec = plant::ContactSpec {
            theta1_c_rad: 0.9 + rng.uniform() * 1.2,
            phalanx: ph,
            k_c_m: len * (0.02 + 0.98 * rng.uniform()),
            radius_m: if rng.uniform() < 0.3 {
                0.0
            } else {
                0.15 * rng.uniform()
            },
        };
        let base = if case % 2 == 0 {
            plant::Scene::DEFAULT
        } else {
            plant::Scene::DEFAULT.ideal()
        };
        let s = plant::Scene {
            object: plant::scene::ObjectSpec::Touching(spec),
            start_theta_a_rad: Some(-0.6),
            ..base
        };
        let Ok(mut p) = Plant::new(&s) else {
            continue; // the object already cuts the finger at the start pose
        };
        let mut duty = 1.0;
        for k in 0..40_000 {
            if k >= 15_000 && k % 5000 == 0 {
                duty = rng.uniform() * 2.4 - 1.2;
            }
            p.step_input(Input::Duty(duty));
            while let Some(e) = p.poll_event() {
                assert!(
                    !matches!(e.kind, plant::EventKind::SolverFailure(_)),
                    "case {case} {spec:?}: {e:?}"
                );
            }
        }
        assert!(!p.solver_failed());
    }
}
