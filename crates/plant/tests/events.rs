//! Each event, on a scene built to trigger it, found where it happens: checked against MODEL.md
//! numbers or the independent geometry of tests/common, within the stated bisection tolerance.

mod common;
use common::*;
use plant::drive::Input;
use plant::kin::{Constraint, Phalanx};
use plant::scene::ObjectSpec;
use plant::{scenes, ContactSpec, ContactState, Event, EventKind, Plant, Scene};

/// θa,c of the Table 2 scene (MODEL.md).
const THETA_A_C: f64 = -0.223_771;

fn ideal(name: &str) -> Scene {
    scenes::by_name(name).unwrap().ideal()
}

/// Runs `steps` control periods with `input(step)`, returns all events.
fn run(p: &mut Plant, steps: usize, mut input: impl FnMut(usize, &Plant) -> Input) -> Vec<Event> {
    let mut out = Vec::new();
    for i in 0..steps {
        let u = input(i, p);
        p.step_input(u);
        while let Some(e) = p.poll_event() {
            out.push(e);
        }
    }
    out
}

fn find(ev: &[Event], name: &str) -> Event {
    *ev.iter()
        .find(|e| e.kind.name() == name)
        .unwrap_or_else(|| panic!("no {name} in {ev:?}"))
}

#[test]
fn first_contact_where_model_md_says() {
    let mut p = Plant::new(&ideal("table2")).unwrap();
    let ev = run(&mut p, 40_000, |_, _| Input::Duty(1.0));
    let e = find(&ev, "first_contact");
    assert!((e.theta_a_rad - THETA_A_C).abs() < 2e-6, "{e:?}");
    match e.kind {
        EventKind::FirstContact { phalanx, k_m } => {
            assert_eq!(phalanx, Phalanx::Distal);
            assert!((k_m - 0.02927).abs() < 1e-8, "k = {k_m}");
        }
        _ => unreachable!(),
    }
    // The torque at contact is the free-motion one: K1(θ1,c − π/4) = 0.340821 (MODEL.md).
    assert!((e.torque_nm - 0.340_821).abs() < 1e-5);
    assert_eq!(p.truth().contact, ContactState::Distal);
}

#[test]
fn loss_of_contact_at_the_contact_angle() {
    let mut p = Plant::new(&ideal("table2")).unwrap();
    // Close at full duty, then let the springs open the finger (bridge at duty −0.2).
    let ev = run(&mut p, 40_000, |i, _| {
        Input::Duty(if i < 28_000 { 1.0 } else { -0.2 })
    });
    let fc = find(&ev, "first_contact");
    let loss = find(&ev, "loss_of_contact");
    assert!(loss.t_s > fc.t_s);
    // λ = 0 exactly where the free path touches the object: θa,c again.
    assert!((loss.theta_a_rad - THETA_A_C).abs() < 2e-6, "{loss:?}");
    assert_eq!(p.truth().contact, ContactState::Free);
}

#[test]
fn beyond_tip_where_the_projection_reaches_l2() {
    let s = ideal("vertex_beyond_tip");
    let obj = s.resolve_object().unwrap().unwrap();
    let mut p = Plant::new(&s).unwrap();
    let ev = run(&mut p, 60_000, |_, _| Input::Duty(1.0));
    let e = find(&ev, "beyond_tip");
    let (h, k) = line_dist(2, e.theta1_rad, e.theta2_rad, obj.x_m, obj.y_m);
    assert!((k - L2).abs() < 1e-8, "k at beyond_tip = {k}");
    assert!(h.abs() < 1e-9, "vertex on the phalanx line: {h}");
    // A vertex slides off: the contact is lost at the same point, the finger is free.
    let loss = find(&ev, "loss_of_contact");
    assert_eq!(loss.theta_a_rad, e.theta_a_rad);
}

#[test]
fn second_contact_where_the_distal_phalanx_reaches_the_cylinder() {
    let s = ideal("large_cyl_second_contact");
    let obj = s.resolve_object().unwrap().unwrap();
    let mut p = Plant::new(&s).unwrap();
    let ev = run(&mut p, 60_000, |_, _| Input::Duty(1.0));
    let e = find(&ev, "second_contact");
    assert!(matches!(
        e.kind,
        EventKind::SecondContact {
            phalanx: Phalanx::Distal,
            ..
        }
    ));
    let (h2, k2) = line_dist(2, e.theta1_rad, e.theta2_rad, obj.x_m, obj.y_m);
    let (h1, _) = line_dist(1, e.theta1_rad, e.theta2_rad, obj.x_m, obj.y_m);
    assert!(
        (h2 - obj.radius_m).abs() < 1e-8,
        "distal gap {}",
        h2 - obj.radius_m
    );
    assert!(
        (h1 - obj.radius_m).abs() < 1e-8,
        "proximal still touching {}",
        h1 - obj.radius_m
    );
    assert!((0.0..=L2).contains(&k2));
    assert_eq!(p.truth().contact, ContactState::Locked);
}

#[test]
fn cylinder_cutting_the_proximal_phalanx_touches_it_first() {
    let mut p = Plant::new(&ideal("large_cyl_cuts_proximal")).unwrap();
    let ev = run(&mut p, 40_000, |_, _| Input::Duty(1.0));
    let fc = find(&ev, "first_contact");
    assert!(matches!(
        fc.kind,
        EventKind::FirstContact {
            phalanx: Phalanx::Proximal,
            ..
        }
    ));
    assert!(fc.theta_a_rad < THETA_A_C);
    find(&ev, "second_contact");
}

#[test]
fn joint_limits_where_the_stops_are() {
    // Extension: negative duty drives θ1 onto its lower stop, then θ2 onto its lower stop.
    let s = Scene {
        object: ObjectSpec::None,
        ..ideal("free")
    };
    let mut p = Plant::new(&s).unwrap();
    let ev = run(&mut p, 20_000, |_, _| Input::Duty(-0.3));
    let lims: Vec<_> = ev
        .iter()
        .filter(|e| e.kind.name() == "joint_limit")
        .collect();
    assert!(lims.len() >= 2, "{ev:?}");
    assert!(matches!(
        lims[0].kind,
        EventKind::JointLimit {
            constraint: Constraint::Theta1Min
        }
    ));
    assert!(
        (lims[0].theta1_rad - (TH01 - 0.05)).abs() < 1e-8,
        "{:?}",
        lims[0]
    );
    assert!(matches!(
        lims[1].kind,
        EventKind::JointLimit {
            constraint: Constraint::Theta2Min
        }
    ));
    assert!((lims[1].theta2_rad - (-0.05)).abs() < 1e-8);
    // Independent closure at the event pose gives the event's θa.
    assert!((theta_a(lims[0].theta1_rad, lims[0].theta2_rad) - lims[0].theta_a_rad).abs() < 1e-9);
    assert_eq!(p.truth().contact, ContactState::Locked);

    // Flexion: θ1 reaches its upper stop at T_a = K1(2.4 − π/4) (free motion up to it).
    let mut p = Plant::new(&s).unwrap();
    let ev = run(&mut p, 120_000, |_, _| Input::Duty(1.0));
    let e = find(&ev, "joint_limit");
    assert!(matches!(
        e.kind,
        EventKind::JointLimit {
            constraint: Constraint::Theta1Max
        }
    ));
    assert!((e.theta1_rad - 2.4).abs() < 1e-8);
    assert!((e.torque_nm - K1 * (2.4 - TH01)).abs() < 1e-7, "{e:?}");
}

#[test]
fn removing_the_object_is_a_loss_of_contact() {
    let mut p = Plant::new(&scenes::by_name("fault_loss_of_contact").unwrap()).unwrap();
    let ev = run(&mut p, 40_000, |_, pl| {
        let c = pl.scene().command;
        Input::Duty(c.value_at(pl.truth().t_s))
    });
    let fc = find(&ev, "first_contact");
    let loss = find(&ev, "loss_of_contact");
    assert!(loss.t_s >= 3.5 && loss.t_s > fc.t_s);
    assert_eq!(p.truth().contact, ContactState::Free);
}

#[test]
fn placement_spec_round_trip() {
    // The object placed by `Touching` is tangent at the requested point (independent geometry).
    let spec = ContactSpec {
        theta1_c_rad: 1.2797,
        phalanx: Phalanx::Distal,
        k_c_m: 0.02927,
        radius_m: 0.05,
    };
    let (obj, pose) = plant::path::place_object(&plant::FingerGeom::PAPER, &spec).unwrap();
    let (h, k) = line_dist(2, pose.theta1_rad, pose.theta2_rad, obj.x_m, obj.y_m);
    assert!((h - 0.05).abs() < 1e-12 && (k - 0.02927).abs() < 1e-12);
    assert!((pose.theta2_rad - 0.209_196).abs() < 1e-6);
}

/// The approach shortcut: starting at θa = −0.3 rad (free motion) the encoder reads as if the
/// motor had driven there from rest, and the first contact is still at MODEL.md's θa,c.
#[test]
fn start_pose_shortcut() {
    let s = Scene {
        start_theta_a_rad: Some(-0.3),
        ..ideal("table2")
    };
    let mut p = Plant::new(&s).unwrap();
    let t = p.truth();
    assert!((t.theta_a_rad - -0.3).abs() < 1e-12);
    // Free motion there: T_a = K1(θ1 − π/4) with θa = θ1 + closure(θ2) (independent closure).
    assert!((theta_a(t.theta1_rad, t.theta2_rad) - -0.3).abs() < 1e-10);
    assert!((t.torque_a_nm - K1 * (t.theta1_rad - TH01)).abs() < 1e-12);
    let rest = -0.850_360_8;
    let counts = (-0.3 - rest) * 3072.0 * 64.0 / std::f64::consts::TAU;
    assert!((p.encoder_count_unwrapped() as f64 - counts).abs() <= 1.0);
    assert!((p.measured_theta_a_rad() - -0.3).abs() < 1e-4);
    let ev = run(&mut p, 20_000, |_, _| Input::Duty(1.0));
    let e = find(&ev, "first_contact");
    assert!((e.theta_a_rad - THETA_A_C).abs() < 2e-6);
    assert!(
        e.t_s < 0.5,
        "the shortcut saves the approach: contact at {} s",
        e.t_s
    );
    // A start inside the object or past a stop is rejected by key.
    for bad in [0.5, -2.0, f64::NAN] {
        let s = Scene {
            start_theta_a_rad: Some(bad),
            ..ideal("table2")
        };
        assert_eq!(
            Plant::new(&s).err(),
            Some(plant::PlantError::Invalid("start_theta_a_rad"))
        );
    }
}

/// Leaving the extension stops again: unlocked at the lock angle, then θ1 leaves its stop
/// where its stop torque is zero, i.e. at T_a = K1(θ1,min − π/4) in free motion.
#[test]
fn leaving_the_stops() {
    let s = Scene {
        object: ObjectSpec::None,
        ..ideal("free")
    };
    let mut p = Plant::new(&s).unwrap();
    let ev = run(&mut p, 30_000, |i, _| {
        Input::Duty(if i < 10_000 { -0.3 } else { 0.3 })
    });
    let names: Vec<_> = ev.iter().map(|e| e.kind.name()).collect();
    assert_eq!(
        names,
        ["joint_limit", "joint_limit", "unlocked", "limit_released"],
        "{ev:?}"
    );
    let lock = ev[1];
    assert!((ev[2].theta_a_rad - lock.theta_a_rad).abs() < 1e-12);
    // Unlocking releases the stop that locked second (θ2); θ1 then leaves its stop where its
    // stop torque vanishes, at T_a = K1(θ1,min − π/4).
    let th1 = ev
        .iter()
        .find(|e| {
            matches!(
                e.kind,
                EventKind::LimitReleased {
                    constraint: Constraint::Theta1Min
                }
            )
        })
        .unwrap();
    assert!((th1.theta1_rad - (TH01 - 0.05)).abs() < 1e-8);
    assert!((th1.torque_nm - K1 * -0.05).abs() < 1e-6, "{th1:?}");
    assert_eq!(p.truth().contact, ContactState::Free);
}

/// Cylinders past the tip: the corner rests on them; a small one jams the corner (the
/// contact path folds) instead of failing; unloading always ends in the loss of contact at
/// MODEL.md's θa,c (λ = 0 where the free path touched).
#[test]
fn corner_contacts_never_fail() {
    for (k, r) in [(0.07, 0.05), (0.072, 0.01), (0.074, 0.0975)] {
        let s = Scene {
            object: ObjectSpec::Touching(ContactSpec {
                theta1_c_rad: 1.2797,
                phalanx: Phalanx::Distal,
                k_c_m: k,
                radius_m: r,
            }),
            start_theta_a_rad: Some(-0.23),
            ..Scene::DEFAULT.ideal()
        };
        let mut p = Plant::new(&s).unwrap();
        let ev = run(&mut p, 60_000, |i, _| {
            Input::Duty(if i < 40_000 { 1.0 } else { -0.5 })
        });
        let names: Vec<_> = ev
            .iter()
            .map(|e| e.kind.name())
            .filter(|n| *n != "over_current")
            .collect();
        assert!(!names.contains(&"solver_failure"), "{names:?}");
        assert_eq!(names[..2], ["first_contact", "beyond_tip"], "{names:?}");
        let loss = find(&ev, "loss_of_contact");
        assert!(
            (loss.theta_a_rad - THETA_A_C).abs() < 2e-6,
            "k={k} R={r}: {loss:?}"
        );
        assert_eq!(p.truth().contact, ContactState::Free);
        if r == 0.01 {
            assert!(names.contains(&"jammed"), "{names:?}");
        }
    }
}

/// A finger powered up away from rest stays there (held by the gear's friction, no current)
/// and its encoder reads 0 there: a controller zeroing at power-up is off by the offset.
#[test]
fn powered_up_away_from_rest_reads_zero_there() {
    let mut s = plant::scenes::table2();
    s.faults.power_up_offset_rad = 0.3;
    let mut p = Plant::new(&s).unwrap();
    let rest = p.theta_a_rest_rad();
    assert_eq!(p.encoder_count(), 0);
    assert!((p.truth().theta_a_rad - (rest + 0.3)).abs() < 1e-12);
    assert_eq!(p.truth().current_a, 0.0);
    for _ in 0..1000 {
        p.step_off();
    }
    // Held: the springs' torque back-driven through the gear does not beat its stiction.
    assert!((p.truth().theta_a_rad - (rest + 0.3)).abs() < 1e-9);
    assert_eq!(p.encoder_count(), 0);
    assert!((p.measured_theta_a_rad() - rest).abs() < 1e-9);
    // Refused with the approach shortcut (two starting poses) and beyond ±1 rad.
    let mut b = s;
    b.start_theta_a_rad = Some(-0.3);
    assert_eq!(
        Plant::new(&b).err(),
        Some(plant::PlantError::Invalid("faults.power_up_offset_rad"))
    );
    b = s;
    b.faults.power_up_offset_rad = f64::NAN;
    assert!(b.validate().is_err());
}
