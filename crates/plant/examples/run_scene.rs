//! Runs a built-in scene open-loop and prints a decimated summary (and every event).
//! `cargo run -p plant --example run_scene -- table2`
use plant::scenes;

fn main() {
    let name = std::env::args().nth(1).unwrap_or_else(|| "table2".into());
    let Some(scene) = scenes::by_name(&name) else {
        eprintln!("unknown scene {name}; known: {:?}", scenes::NAMES);
        std::process::exit(2);
    };
    let mut p = match plant::Plant::new(&scene) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let n = (scene.duration_s / scene.dt_s) as u64;
    let t0 = std::time::Instant::now();
    for i in 0..n {
        p.step_scene();
        while let Some(e) = p.poll_event() {
            println!(
                "EVENT t={:.4} θa={:.6} T={:.4} {:?}",
                e.t_s, e.theta_a_rad, e.torque_nm, e.kind
            );
        }
        if i % (n / 20).max(1) == 0 {
            let t = p.truth();
            println!(
                "t={:.3} θa={:.5} meas={:.5} T={:.4} Tmeas={:.4} i={:.4} w={:.1} {} k={:.5} enc={} adc={}",
                t.t_s, t.theta_a_rad, p.measured_theta_a_rad(), t.torque_a_nm, p.measured_torque_nm(),
                t.current_a, t.motor_speed_rad_s, t.contact.name(), t.k_m, p.encoder_count(), p.current_adc()
            );
        }
    }
    let el = t0.elapsed();
    println!(
        "{} steps in {:?}: {:.0} ns/step",
        n,
        el,
        el.as_nanos() as f64 / n as f64
    );
}
