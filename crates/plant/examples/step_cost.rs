//! Host cost of one `Plant::step` (median over batches), per scene and phase.
//! `cargo run --release -p plant --example step_cost`
use std::time::Instant;

fn main() {
    for name in [
        "free",
        "table2",
        "vertex_k2_10",
        "large_cyl_second_contact",
        "hard_stop_stall",
    ] {
        let Some(s) = plant::scenes::by_name(name) else {
            continue;
        };
        let Ok(mut p) = plant::Plant::new(&s) else {
            continue;
        };
        let steps = (s.duration_s / s.dt_s) as usize;
        let batch = 100;
        let mut per_step = Vec::with_capacity(steps / batch);
        let mut i = 0;
        while i + batch <= steps {
            let t0 = Instant::now();
            for _ in 0..batch {
                p.step_scene();
            }
            per_step.push(t0.elapsed().as_nanos() as f64 / batch as f64);
            while p.poll_event().is_some() {}
            i += batch;
        }
        per_step.sort_by(f64::total_cmp);
        let med = per_step[per_step.len() / 2];
        let p99 = per_step[per_step.len() * 99 / 100];
        let max = per_step[per_step.len() - 1];
        println!(
            "{name:28} {steps:6} steps  median {med:6.0} ns/step  p99 {p99:6.0}  max {max:6.0}  end: {}",
            p.truth().contact.name()
        );
    }
}
