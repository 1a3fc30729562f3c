//! The written traces follow the recorded-trace conventions: header, 1 kHz rows from t = 0, θa
//! absolute (rest row at the model's −0.8503608 rad), encoder steps of 2π/16384, the torque
//! profile (0.1 s at zero, 0.5 N·m/s ramp, ΔT_a over 0.2 s after the detection delay, 0.3 s hold),
//! and a truth whose contact is where the object was placed.

use dynsim::grasp::{self, GraspSpec, SensorSpec, Target};
use dynsim::linkage::L2_M;
use dynsim::sim::{DriveFriction, EngineSettings, FingerParams};

// The model document's rest angle of the input crank.
const THETA_A_REST_RAD: f64 = -0.8503608;

fn spec() -> GraspSpec {
    GraspSpec {
        target: Target::Object {
            radius_m: 0.0,
            k_m: 0.6 * L2_M,
            distal: true,
            theta1_c_rad: 1.2797,
        },
        delta_ta_nm: 0.5,
        rise_s: 0.2,
        detection_delay_s: 0.015,
        hold_s: 0.3,
        ramp_nm_per_s: 0.5,
        finger: FingerParams {
            drive_inertia_kgm2: 5e-3,
            friction: DriveFriction::REALISTIC,
            contact_mu: 0.3,
            torque_lag_s: 5e-4,
        },
        engine: EngineSettings::default(),
    }
}

/// The grids' realistic sensor (2π/16384 encoder steps, 0.004 N·m noise, 0.003 N·m offset).
fn realistic_sensor(seed: u64) -> SensorSpec {
    SensorSpec {
        counts_per_turn: 16384,
        torque_sigma_nm: 0.004,
        torque_offset_nm: 0.003,
        seed,
    }
}

fn parse(csv: &str) -> Vec<[f64; 3]> {
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("t_s,theta_a_rad,torque_nm"));
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[test]
fn a_grasp_is_written_as_a_recording() {
    let s = spec();
    let rec = grasp::run(&s).unwrap();
    let rows = parse(&grasp::to_csv(&rec, &SensorSpec::IDEAL));
    for (i, r) in rows.iter().enumerate() {
        assert!((r[0] - i as f64 * 1e-3).abs() < 1e-9, "1 kHz from t = 0");
    }
    assert!((rows[0][1] - THETA_A_REST_RAD).abs() < 1e-6);
    // Zero command for 0.1 s, then the 0.5 N·m/s ramp (the torque loop lags by 0.5 ms).
    assert!(rows[..=100].iter().all(|r| r[2].abs() < 1e-12));
    let at = |t: f64| rows[(t * 1e3).round() as usize];
    assert!((at(0.5)[2] - 0.5 * 0.4).abs() < 0.5 * 1e-3);

    // The truth: a distal contact within 0.1 mm of where the object was placed, and θa at that
    // time is the recorded one.
    let t = rec.truth;
    assert_eq!(t.phalanx, "distal");
    assert!((t.k_c_m.unwrap() - 0.6 * L2_M).abs() < 1e-4);
    let t_c = t.t_contact_s.unwrap();
    let row_c = at((t_c * 1e3).floor() * 1e-3);
    assert!((row_c[1] - t.theta_a_c_rad.unwrap()).abs() < 2e-3);
    // The rise: ΔT_a reached 0.2 s after contact + delay, then held 0.3 s to the end.
    let start = t_c + s.detection_delay_s;
    let before = 0.5 * (start - 0.1);
    let end = rows.last().unwrap();
    assert!((end[0] - (start + 0.5)).abs() < 2e-3);
    assert!(
        (end[2] - (before + 0.5)).abs() < 2e-3,
        "{} vs {}",
        end[2],
        before + 0.5
    );
    assert!((at(start + 0.1)[2] - (before + 0.25)).abs() < 2e-3);
}

#[test]
fn the_sensor_quantises_and_adds_noise() {
    let rec = grasp::run(&spec()).unwrap();
    let sensor = realistic_sensor(7);
    let rows = parse(&grasp::to_csv(&rec, &sensor));
    let q = 2.0 * std::f64::consts::PI / 16384.0;
    for r in &rows {
        let counts = (r[1] - THETA_A_REST_RAD) / q;
        assert!(
            (counts - counts.round()).abs() < 1e-3,
            "whole encoder counts"
        );
    }
    // Over the 100 rows at zero command the noise has mean ≈ offset and σ ≈ 0.004 (±4σ/√100).
    let zero: Vec<f64> = rows[..100].iter().map(|r| r[2]).collect();
    let mean = zero.iter().sum::<f64>() / 100.0;
    let sd = (zero.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 99.0).sqrt();
    assert!((mean - 0.003).abs() < 0.0016, "{mean}");
    assert!((sd - 0.004).abs() < 0.0012, "{sd}");
}

/// Another draw of a sensor records the same grasp: torques differing by the noise alone
/// (their difference has σ √2·0.004 N·m about zero) and θa by at most one encoder count
/// (another quantiser phase), while draw 0 is the sensor itself and a perfect sensor has
/// nothing to draw.
#[test]
fn a_redrawn_sensor_records_the_same_grasp_with_other_noise() {
    let rec = grasp::run(&spec()).unwrap();
    let sensor = realistic_sensor(1007);
    assert_eq!(sensor.redrawn(0), sensor);
    assert!(sensor.is_noisy() && !SensorSpec::IDEAL.is_noisy());
    let a = parse(&grasp::to_csv(&rec, &sensor));
    let b = parse(&grasp::to_csv(&rec, &sensor.redrawn(3)));
    assert_eq!(a.len(), b.len());
    let q = 2.0 * std::f64::consts::PI / 16384.0;
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| y[2] - x[2]).collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let expected = 2f64.sqrt() * 0.004;
    assert!(
        mean.abs() < 4.0 * expected / n.sqrt(),
        "mean difference {mean}"
    );
    assert!(
        (sd - expected).abs() < 0.1 * expected,
        "σ of the difference {sd}"
    );
    assert!(a
        .iter()
        .zip(&b)
        .all(|(x, y)| (y[1] - x[1]).abs() <= q * 1.001));
    assert!(a.iter().zip(&b).any(|(x, y)| x[2] != y[2]));
}

#[test]
fn the_truth_file_carries_the_shared_fields() {
    let s = spec();
    let rec = grasp::run(&s).unwrap();
    let json = grasp::to_json("x", "default", &s, &rec);
    for field in [
        "\"id\"",
        "\"source\"",
        "\"level\"",
        "\"expected\"",
        "\"k2_c_m\"",
        "\"k2_end_m\"",
        "\"phalanx\"",
        "\"radius_m\"",
        "\"delta_ta_nm\"",
        "\"t_contact_s\"",
        "\"theta_a_c_rad\"",
        "\"contact_friction_mu\"",
    ] {
        assert!(json.contains(field), "{field} missing");
    }
}

#[test]
fn negatives_stay_negative() {
    let mut none = spec();
    none.target = Target::None;
    let rec = grasp::run(&none).unwrap();
    assert_eq!(rec.truth.phalanx, "none");
    // Ramp to 0.8 N·m (1.6 s after 0.1 s) then hold 0.5 s.
    assert!((rec.samples.last().unwrap().t_s - 2.2).abs() < 2e-3);

    let mut prox = spec();
    prox.target = Target::Object {
        radius_m: 0.0075,
        k_m: 0.055,
        distal: false,
        theta1_c_rad: 1.05,
    };
    let rec = grasp::run(&prox).unwrap();
    assert_eq!(rec.truth.phalanx, "proximal");
    assert!((rec.truth.k_c_m.unwrap() - 0.055).abs() < 1e-4);
}

#[test]
fn the_drive_inertia_range_runs_stably() {
    // 1e-4 and 0.1 kg·m² bound the drive's range: the loop stays closed and the contact is found
    // on the distal phalanx (where depends on the approach's dynamics, not checked here).
    for j in [1e-4, 0.1] {
        let mut s = spec();
        s.finger.drive_inertia_kgm2 = j;
        let rec = grasp::run(&s).unwrap();
        println!(
            "J {j}: k2_c {:?}, t_c {:?}, loop gap {:.2e}, losses {}",
            rec.truth.k_c_m, rec.truth.t_contact_s, rec.max_loop_gap_m, rec.truth.contact_losses
        );
        assert_eq!(rec.truth.phalanx, "distal");
        assert!(rec.max_loop_gap_m < 1e-6);
        assert!(rec.samples.iter().all(|x| x.theta_a_rad.is_finite()));
    }
}
