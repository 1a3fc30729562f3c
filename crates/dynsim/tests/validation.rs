//! Validation of the engine-based finger against MODEL.md's reference numbers.

use dynsim::linkage;
use dynsim::sim::{DriveFriction, EngineSettings, Finger, FingerParams, Object};

fn quiet_finger() -> FingerParams {
    FingerParams {
        drive_inertia_kgm2: 1.0e-3,
        friction: DriveFriction {
            viscous_nm_s_per_rad: 0.02,
            ..DriveFriction::OFF
        },
        contact_mu: 0.0,
        torque_lag_s: 0.0,
    }
}

#[test]
fn free_motion_statics() {
    let t0 = std::time::Instant::now();
    let mut f = Finger::new(quiet_finger(), Object::None, EngineSettings::default());
    println!(
        "rest theta_a {} th1 {} th2 {}",
        f.theta_a_rad(),
        f.theta1_rad(),
        f.theta2_rad()
    );
    let target = 0.340821;
    let dt = 1e-4;
    for i in 0..30000 {
        let t = i as f64 * dt;
        f.step((target * t / 1.0).min(target));
        if i % 2000 == 0 {
            println!(
                "t {t:.2} th_a {:.6} th1 {:.6} th2 {:.6} gap {:.2e}",
                f.theta_a_rad(),
                f.theta1_rad(),
                f.theta2_rad(),
                f.loop_gap_m()
            );
        }
    }
    println!(
        "end theta_a {} th1 {} th2 {} gap {:.3e} in {:?}",
        f.theta_a_rad(),
        f.theta1_rad(),
        f.theta2_rad(),
        f.loop_gap_m(),
        t0.elapsed()
    );
    let (p, t) = linkage::free_motion_pose(1.2797).unwrap();
    println!(
        "own kinematics: th2 {} ta {} theta_a {}",
        p.theta2_rad, t, p.theta_a_rad
    );
}
