//! The paper's Table 2 scene closed loop: the real controller against the plant.
mod common;

use common::*;
use grasp::{ControllerConfig, DriveConfig, Estimator, Located, State};

/// MODEL.md: the quasi-static two-point result for Table 2 with ΔT_a = 0.8 N·m.
const K2_HAT_MODEL: f64 = 0.041529;

#[test]
fn table2_ideal_matches_the_model_two_point_result() {
    let scene = plant::scenes::by_name("table2_ideal").expect("scene");
    let cfg = ControllerConfig {
        estimator: Estimator::TwoPoint,
        ..config(&scene, 0.8)
    };
    let o = run(&scene, cfg, 10.0, 0.0, |_, _, _| {});
    assert_eq!(o.state, State::Holding, "events {:?}", o.events);
    let r = o.estimate.unwrap().unwrap();
    let k2 = k2_hat(&o).unwrap();
    let (tc, kc) = o.first_contact.unwrap();
    println!(
        "table2 ideal: k2_hat {k2:.6} m (model {K2_HAT_MODEL}), err {:.3} % of l2; {r:?}; \
         contact at {tc:.4} s k2 {kc:.5}, detected at {:.4} s",
        (k2 - K2_HAT_MODEL) / L2 * 100.0,
        o.detected_s.unwrap()
    );
    assert_eq!(r.located, Located::Distal);
    assert!(
        (k2 - K2_HAT_MODEL).abs() <= 0.005 * L2,
        "k2_hat {k2} vs {K2_HAT_MODEL}"
    );
    // The torque step actually applied is ΔT_a within 2 %.
    let dta = f64::from(r.delta_ta_unm) * 1e-6;
    assert!((dta - 0.8).abs() < 0.016, "ΔT_a applied {dta}");
}

#[test]
fn drive_constants_agree_with_the_plant() {
    let scene = plant::Scene::DEFAULT;
    let mine = DriveConfig::DEFAULT;
    let plant_view = drive_config(&scene);
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
    assert!(close(mine.dt_s, plant_view.dt_s), "dt");
    assert!(close(mine.gear_ratio, plant_view.gear_ratio), "ratio");
    assert!(close(mine.efficiency, plant_view.efficiency), "efficiency");
    assert!(close(mine.kt_nm_per_a, plant_view.kt_nm_per_a), "kt");
    assert!(close(mine.resistance_ohm, plant_view.resistance_ohm), "R");
    assert!(close(mine.bus_v, plant_view.bus_v), "bus");
    assert!(
        close(
            mine.encoder_counts_per_rev,
            plant_view.encoder_counts_per_rev
        ),
        "counts/rev"
    );
    assert!(
        close(mine.amps_per_code, plant_view.amps_per_code),
        "A/code"
    );
    assert!(
        close(mine.adc_zero_code, plant_view.adc_zero_code),
        "zero code"
    );
    // θa at rest: the plant's own rest pose.
    let p = plant::Plant::new(&scene).unwrap();
    assert!((mine.theta_a_rest_rad - p.theta_a_rest_rad()).abs() < 1e-6);
}

#[test]
fn table2_realistic_two_point_and_path_fit() {
    // The realistic plant (friction, backlash, noise, gear losses, sensor errors), ΔT_a = 0.8:
    // the two-point estimate carries the transmission friction into K̂c; the path fit
    // models it. Errors against the initial contact k2 = 0.02927 m.
    let scene = plant::scenes::table2();
    let k2_true = 0.02927;
    let mut errs = Vec::new();
    for est in [Estimator::TwoPoint, Estimator::PathFit] {
        let cfg = ControllerConfig {
            estimator: est,
            ..config(&scene, 0.8)
        };
        let o = run(&scene, cfg, 20.0, 0.0, |_, _, _| {});
        assert_eq!(o.state, State::Holding, "{est:?}: {:?}", o.events);
        let k2 = k2_hat(&o).unwrap();
        let e = (k2 - k2_true) / L2 * 100.0;
        println!("table2 realistic ΔT_a 0.8, {est:?}: k2_hat {k2:.5} m, error {e:+.2} % of l2");
        errs.push(e);
    }
    // Measured: two-point +17.0 % (the quasi-static two-point result is +16.35 %, MODEL.md;
    // it was +22.6 % while the impact's rest point, held anywhere in the stiction band, was
    // the first static point); path fit −4.7 % (+1.1 % at commit 7599292; its accuracy is
    // pathfit's, tested there). Here: the two-point estimate is within 1.5 % l2 of the
    // quasi-static result (friction's honest cost: Coulomb cancels in ΔT_a, what is left is
    // the sensor gain error and the back-dating), and the path fit, which the selection
    // reaches, is at least twice as close as the two-point estimate on this run.
    let qs = (K2_HAT_MODEL - k2_true) / L2 * 100.0;
    assert!((errs[0] - qs).abs() < 1.5, "two-point {} vs {qs}", errs[0]);
    assert!(errs[1].abs() < errs[0].abs() / 2.0, "path fit {}", errs[1]);
}

#[test]
fn table2_contact_event_is_the_true_contact() {
    // The ContactDetected event reports the contact instant itself (not the detection, which
    // comes ~36 ms and ~9 mrad later): against the plant's first contact, ideal and realistic
    // (there, the encoder on the motor sees θa through the backlash: +1.0 mrad while
    // approaching). Measured: ideal 0.3 ms / 0.10 mrad, realistic 4.0 ms / 0.51 mrad
    // (the detection itself: 42 / 36 ms, 9.5 / 9.4 mrad).
    for name in ["table2_ideal", "table2"] {
        let scene = plant::scenes::by_name(name).expect("scene");
        let mut truths: Vec<plant::Truth> = Vec::new();
        let o = run(&scene, config(&scene, 0.8), 20.0, 0.0, |_, _, p| {
            truths.push(p.truth())
        });
        let (tc, _) = o.first_contact.expect("plant contact");
        let truth = truths
            .iter()
            .min_by(|a, b| (a.t_s - tc).abs().total_cmp(&(b.t_s - tc).abs()))
            .expect("truth");
        let (tick, theta) = o
            .events
            .iter()
            .find_map(|e| match e {
                grasp::Event::ContactDetected {
                    contact_tick,
                    theta_a_urad,
                    ..
                } => Some((*contact_tick, f64::from(*theta_a_urad) * 1e-6)),
                _ => None,
            })
            .expect("contact event");
        let t_ev = f64::from(tick) * scene.dt_s;
        println!(
            "{name}: event contact at {t_ev:.4} s θa {theta:.6}; plant {tc:.4} s θa {:.6}",
            truth.theta_a_rad
        );
        assert!((t_ev - tc).abs() < 0.008, "{name}: {t_ev} vs {tc}");
        assert!(
            (theta - truth.theta_a_rad).abs() < 2e-3,
            "{name}: θa,c {theta} vs {}",
            truth.theta_a_rad
        );
    }
}
