//! Calibration acceptance (issue #17).

use pts_cli::calibrate::identify;
use pts_cli::sweep::{drive_truth, record, Perturbation, Post, SweepPlan};

#[test]
fn dev_identify() {
    let nominal = pts_cli::load_finger(None).unwrap();
    let pert =
        Perturbation::parse("k1=1.25,k2=0.75,theta01_deg=3,theta02_deg=-3,friction=2,inertia=3")
            .unwrap();
    let scene = pert.scene(plant::Scene::DEFAULT, &nominal).unwrap();
    let t0 = std::time::Instant::now();
    let sweep = record(&scene, &nominal, &SweepPlan::DEFAULT, None).unwrap();
    let post = Post {
        theta1_rad: nominal.finger.theta01 + 0.45,
        k1_m: 0.07,
    };
    let touch = record(&scene, &nominal, &SweepPlan::DEFAULT, Some(post)).unwrap();
    eprintln!("record {:?}", t0.elapsed());
    let mut f = std::fs::File::create("/tmp/calib/sweep.csv").unwrap();
    pts_cli::trace::write_csv(&sweep, &mut f).unwrap();
    let mut f = std::fs::File::create("/tmp/calib/touch.csv").unwrap();
    pts_cli::trace::write_csv(&touch, &mut f).unwrap();
    let c = identify(&sweep, None, &nominal).unwrap();
    eprintln!("{c}");
    let c = identify(&sweep, Some((&touch, post)), &nominal).unwrap();
    eprintln!("{c}");
    let truth = pert.apply_to_file(&nominal);
    let g = 1.0 + scene.sensors.gain_error;
    eprintln!(
        "true k1 {} k2 {} t01 {} t02 {} (scaled k {} {})",
        truth.finger.k1,
        truth.finger.k2,
        truth.finger.theta01,
        truth.finger.theta02,
        truth.finger.k1 * g,
        truth.finger.k2 * g
    );
    eprintln!("drive truth {:?}", drive_truth(&scene, &nominal));
    eprintln!("total {:?}", t0.elapsed());
}
