//! The drive and sensors against hand-computed values.

use plant::drive::{DriveParams, DriveState, Input, Load};
use plant::scene::ObjectSpec;
use plant::sensors::SensorParams;
use plant::{scenes, ContactState, Plant, PlantError, Scene};

const D: DriveParams = DriveParams::RE10_GP10A;

/// No-load speed: J dω/dt = kt i − Tc − bω, i = (V − kt ω)/R ⇒ ω = (kt V/R − Tc)/(kt²/R + b).
#[test]
fn free_running_speed_matches_hand_computation() {
    let hand: f64 = (4.5e-3 * 6.0 / 20.0 - 40e-6) / (4.5e-3 * 4.5e-3 / 20.0 + 2.0e-9);
    assert!((hand - 1291.4).abs() < 0.5, "hand value {hand}");
    let load = Load {
        theta_a_zero_rad: 0.0,
        theta_a0_rad: 0.0,
        t0_nm: 0.0,
        k_nm_per_rad: 0.0,
    };
    let d = DriveParams {
        backlash_rad: 0.0,
        ..D
    };
    let mut st = DriveState::default();
    // 0.3 s = 40 mechanical time constants (τm = RJ/kt² ≈ 6.9 ms).
    for _ in 0..3000 {
        d.advance(&mut st, Input::Duty(1.0), &load, 0.0, d.r_ohm, 100e-6);
    }
    println!(
        "free-running: ω = {:.2} rad/s, hand {hand:.2}",
        st.speed_rad_s
    );
    assert!(
        (st.speed_rad_s - hand).abs() / hand < 1e-3,
        "ω = {} vs {hand}",
        st.speed_rad_s
    );
    let i_hand = (6.0 - 4.5e-3 * hand) / 20.0;
    assert!(
        (st.current_a - i_hand).abs() < 1e-5,
        "i = {} vs {i_hand}",
        st.current_a
    );
    // Mechanical time constant: after τm ≈ 6.9 ms from rest the speed is ≈ 63 % of final.
    let mut st = DriveState::default();
    let tau: f64 = 20.0 * 7.0e-9 / (4.5e-3 * 4.5e-3);
    let n = (tau / 10e-6).round() as usize;
    for _ in 0..n {
        d.advance(&mut st, Input::Duty(1.0), &load, 0.0, d.r_ohm, 10e-6);
    }
    let frac = st.speed_rad_s / hand;
    assert!((frac - 0.632).abs() < 0.02, "ω(τm)/ω∞ = {frac}");
}

fn stall(scene: Scene, input: impl Fn(usize) -> Input, steps: usize) -> Plant {
    let mut p = Plant::new(&scene).unwrap();
    for i in 0..steps {
        p.step_input(input(i));
    }
    assert_eq!(p.truth().contact, ContactState::Locked, "{:?}", p.truth());
    p
}

/// Stall against the extension stops: T_a = N·η·kt·i within the friction band N·η·T_stiction.
#[test]
fn stall_torque_is_n_eta_kt_i_within_friction() {
    let free = Scene {
        object: ObjectSpec::None,
        ..Scene::DEFAULT
    };
    // Ideal drive (η = 1, no friction), duty −0.3 ⇒ i = −1.8 V / 20 Ω at standstill.
    let s = Scene {
        sensors: SensorParams::DEFAULT.ideal(),
        drive: D.ideal(),
        ..free
    };
    let p = stall(s, |_| Input::Duty(-0.3), 20_000);
    let t = p.truth();
    let i = -1.8 / 20.0;
    assert!((t.current_a - i).abs() < 1e-6, "i = {}", t.current_a);
    let hand = 3072.0 * 4.5e-3 * i;
    assert!(
        (t.torque_a_nm - hand).abs() < 1e-4,
        "T = {} vs {hand}",
        t.torque_a_nm
    );

    // Realistic drive, current source ramped slowly to −0.05 A (so the finger creeps into the
    // stop and the gear stays on its driving side): N·η·kt·i = −0.42683 N·m; friction band
    // N·η·T_stiction = 0.1138 N·m. (A fast impact can stick anywhere up to N·kt·i/η_back.)
    let s = Scene {
        sensors: SensorParams::DEFAULT.ideal(),
        ..free
    };
    let p = stall(
        s,
        |k| Input::Current(-0.05 * (k as f64 / 10_000.0).min(1.0)),
        15_000,
    );
    let t = p.truth();
    let hand: f64 = 3072.0 * 0.6175 * 4.5e-3 * -0.05;
    assert!((hand - -0.426_83).abs() < 1e-4);
    let band = 3072.0 * 0.6175 * 60e-6;
    println!(
        "stall: T = {:.5} N·m, N·η·kt·i = {hand:.5} ± {band:.4}",
        t.torque_a_nm
    );
    assert!(
        (t.torque_a_nm - hand).abs() <= band + 1e-9,
        "T = {} vs {hand} ± {band}",
        t.torque_a_nm
    );
    assert!(t.torque_a_nm < 0.0 && t.motor_speed_rad_s == 0.0);
}

/// Backlash: on a reversal the gear output crosses the dead band while θa stays put; the
/// encoder (on the motor) sees backlash·N·counts/turn/2π = 3e-3·3072·64/2π ≈ 93.9 counts of it.
#[test]
fn backlash_is_a_dead_band_on_reversal() {
    let s = Scene {
        object: ObjectSpec::None,
        sensors: SensorParams::DEFAULT.ideal(),
        drive: DriveParams {
            backlash_rad: 3.0e-3,
            ..D.ideal()
        },
        ..Scene::DEFAULT
    };
    let mut p = Plant::new(&s).unwrap();
    let rest = p.theta_a_rest_rad();
    // Flex a little, then reverse through rest into extension.
    let mut band_counts: Vec<i64> = Vec::new();
    let mut gears: Vec<f64> = Vec::new();
    for i in 0..12_000 {
        let duty = if i < 3000 { 0.3 } else { -0.3 };
        p.step(duty);
        let t = p.truth();
        if i >= 3000 && t.theta_a_rad == rest {
            band_counts.push(p.encoder_count_unwrapped());
            gears.push(t.gear_out_rad);
        }
    }
    let span = band_counts.iter().max().unwrap() - band_counts.iter().min().unwrap();
    let hand = 3.0e-3 * 3072.0 * 64.0 / std::f64::consts::TAU;
    println!("backlash dead band: {span} counts, hand {hand:.1}");
    assert!(
        (span as f64 - hand).abs() <= 3.0,
        "dead band {span} counts vs {hand:.1}"
    );
    let gspan = gears.iter().cloned().fold(f64::MIN, f64::max)
        - gears.iter().cloned().fold(f64::MAX, f64::min);
    assert!((gspan - 3.0e-3).abs() < 1e-4, "gear span {gspan}");
    // And the finger really went both ways.
    assert!(p.truth().theta_a_rad < rest - 1e-3);
}

/// Over-current: a shorted winding (2 Ω) at full duty draws > 0.28 A.
#[test]
fn short_fault_raises_over_current() {
    let mut p = Plant::new(&scenes::by_name("fault_short").unwrap()).unwrap();
    let mut seen = false;
    for _ in 0..40_000 {
        p.step_scene();
        while let Some(e) = p.poll_event() {
            if e.kind.name() == "over_current" && e.t_s >= 1.0 {
                seen = true;
            }
        }
    }
    assert!(seen);
    assert!(p.truth().current_a.abs() > 0.28);
}

#[test]
fn encoder_faults() {
    let mut p = Plant::new(&scenes::by_name("fault_encoder_stuck").unwrap()).unwrap();
    for _ in 0..10_001 {
        p.step_scene();
    }
    let stuck = p.encoder_count();
    for _ in 0..2000 {
        p.step_scene();
    }
    assert_eq!(p.encoder_count(), stuck);
    assert!(p.truth().motor_speed_rad_s > 100.0);

    let mut a = Plant::new(&scenes::by_name("fault_encoder_jump").unwrap()).unwrap();
    let mut b = Plant::new(&scenes::by_name("table2").unwrap()).unwrap();
    for _ in 0..12_000 {
        a.step_scene();
        b.step_scene();
    }
    assert_eq!(a.encoder_count().wrapping_sub(b.encoder_count()), 500);
}

/// The ADC code for a known current with ideal sensors: 2048 + i·0.5 Ω·10·4096/3.3 V.
#[test]
fn adc_scaling_by_hand() {
    let s = SensorParams::DEFAULT.ideal();
    assert_eq!(s.adc_code(0.0, 0.0), 2048);
    assert_eq!(
        s.adc_code(0.1, 0.0),
        (2048.0f64 + 0.1 * 5.0 * 4096.0 / 3.3).round() as u16
    );
    assert_eq!(s.adc_code(10.0, 0.0), 4095);
    assert_eq!(s.adc_code(-10.0, 0.0), 0);
    assert_eq!(s.adc_code(f64::NAN, 0.0), 0);
    // Realistic: +4 mV offset (≈ 5 LSB), +1 % gain.
    let r = SensorParams::DEFAULT;
    assert_eq!(
        r.adc_code(0.0, 0.0),
        (2048.0f64 + 0.004 * 4096.0 / 3.3).round() as u16
    );
}

/// Same seed → same trace, bit for bit; another seed → another ADC noise sequence.
#[test]
fn same_seed_same_trace() {
    let s = scenes::by_name("table2").unwrap();
    let trace = |seed: u64| {
        let s = Scene {
            sensors: SensorParams { seed, ..s.sensors },
            ..s
        };
        let mut p = Plant::new(&s).unwrap();
        let mut out = Vec::new();
        for _ in 0..30_000 {
            p.step_scene();
            let t = p.truth();
            out.push((
                t.theta_a_rad.to_bits(),
                t.torque_a_nm.to_bits(),
                t.current_a.to_bits(),
                p.encoder_count(),
                p.current_adc(),
            ));
        }
        out
    };
    let a = trace(7);
    assert_eq!(a, trace(7));
    let b = trace(8);
    assert!(a.iter().zip(&b).any(|(x, y)| x.4 != y.4));
}

/// Garbage in: no panic, finite truth, typed errors naming the key.
#[test]
fn never_panics_and_rejects_bad_scenes() {
    let mut p = Plant::new(&scenes::table2()).unwrap();
    for u in [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300, -1e300, 0.5] {
        for _ in 0..100 {
            p.step(u);
        }
    }
    for u in [
        Input::Current(f64::NAN),
        Input::MotorTorque(1e300),
        Input::Off,
        Input::Current(50.0),
    ] {
        for _ in 0..100 {
            p.step_input(u);
        }
    }
    let t = p.truth();
    assert!(t.theta_a_rad.is_finite() && t.torque_a_nm.is_finite() && t.current_a.is_finite());

    let bad = Scene {
        drive: DriveParams { r_ohm: -1.0, ..D },
        ..Scene::DEFAULT
    };
    assert_eq!(
        Plant::new(&bad).err(),
        Some(PlantError::Invalid("drive.r_ohm"))
    );
    let bad = Scene {
        dt_s: f64::NAN,
        ..Scene::DEFAULT
    };
    assert_eq!(Plant::new(&bad).err(), Some(PlantError::Invalid("dt_s")));
    let bad = Scene {
        drive: DriveParams {
            stiction_nm: 1e-6,
            ..D
        },
        ..Scene::DEFAULT
    };
    assert_eq!(
        Plant::new(&bad).err(),
        Some(PlantError::Invalid("drive.stiction_nm"))
    );
    // An object overlapping the finger at rest.
    let bad = Scene {
        object: scenes::fixed_object(0.05, 0.05, 0.02),
        ..Scene::DEFAULT
    };
    assert_eq!(Plant::new(&bad).err(), Some(PlantError::BadPlacement));
}

/// The hard-stop scene: both extension stops, then the stall current 6 V / 20 Ω = 0.3 A trips
/// the 0.28 A over-current flag, and the locked finger holds N·η·kt·i within friction.
#[test]
fn hard_stop_stall_scene() {
    let mut p = Plant::new(&scenes::by_name("hard_stop_stall").unwrap()).unwrap();
    let mut names = Vec::new();
    for _ in 0..20_000 {
        p.step_scene();
        while let Some(e) = p.poll_event() {
            names.push(e.kind.name());
        }
    }
    assert_eq!(names, ["joint_limit", "joint_limit", "over_current"]);
    let t = p.truth();
    assert!((t.current_a - -0.3).abs() < 1e-9, "i = {}", t.current_a);
    let hand = 3072.0 * 0.6175 * 4.5e-3 * -0.3;
    assert!(
        (t.torque_a_nm - hand).abs() <= 3072.0 * 0.6175 * 60e-6 + 1e-9,
        "T = {}",
        t.torque_a_nm
    );
}
