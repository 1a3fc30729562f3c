//! Writes a grid of engine-simulated grasp traces: `<id>.csv` (t_s,theta_a_rad,torque_nm at 1 kHz)
//! and `<id>.json` (ground truth) per grasp, plus `index.csv` listing them.
//!
//! `dynsim --out DIR [--grid small|full|inertia|pose|protocol] [--only ID[,ID…]] [--replicas N]`;
//! progress on stderr. `--only` writes just the named cases of the grid, each given by its
//! whole id or by its number's prefix (`rap193`; an unknown id is an error), to look at one
//! grasp without simulating the rest. `--replicas N` writes each case with a realistic sensor
//! N more times as `<id>__r<i>` (i = 1…N): the same simulated grasp recorded with other draws
//! of the torque noise and of the encoder's quantiser phase, which tells an error that is the
//! sensor's draw from one the estimator makes on every draw.

use dynsim::grasp::{self, Target};
use dynsim::grid::{cases, FULL, INERTIA, POSE, PROTOCOL, SMALL};
use std::io::Write as _;
use std::path::PathBuf;

fn usage() -> ! {
    eprintln!(
        "usage: dynsim --out DIR [--grid small|full|inertia|pose|protocol] [--only ID[,ID...]] [--replicas N]"
    );
    std::process::exit(2);
}

fn main() {
    let mut out: Option<PathBuf> = None;
    let mut grid = "small".to_string();
    let mut only: Option<Vec<String>> = None;
    let mut replicas = 0u64;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = Some(args.next().unwrap_or_else(|| usage()).into()),
            "--grid" => grid = args.next().unwrap_or_else(|| usage()),
            "--only" => {
                let list = args.next().unwrap_or_else(|| usage());
                only = Some(list.split(',').map(str::to_string).collect());
            }
            "--replicas" => {
                replicas = match args.next().map(|n| n.parse::<u64>()) {
                    Some(Ok(n)) if n <= 1000 => n,
                    _ => {
                        eprintln!("--replicas: expected a count from 0 to 1000");
                        std::process::exit(2);
                    }
                }
            }
            _ => usage(),
        }
    }
    let Some(dir) = out else { usage() };
    let axes = match grid.as_str() {
        "small" => &SMALL,
        "full" => &FULL,
        "inertia" => &INERTIA,
        "pose" => &POSE,
        "protocol" => &PROTOCOL,
        _ => usage(),
    };
    std::fs::create_dir_all(&dir).expect("create the output directory");
    let mut cases = cases(axes);
    if let Some(ids) = &only {
        // `rap193` names the case whose id is `rap193_…`; a whole id names itself.
        let named = |id: &str, case: &str| {
            case == id
                || case
                    .strip_prefix(id)
                    .is_some_and(|rest| rest.starts_with('_'))
        };
        if let Some(unknown) = ids
            .iter()
            .find(|id| !cases.iter().any(|c| named(id, &c.id)))
        {
            eprintln!("--only {unknown}: no such case in the {grid} grid");
            std::process::exit(2);
        }
        cases.retain(|c| ids.iter().any(|id| named(id, &c.id)));
    }
    let start = std::time::Instant::now();
    let mut index =
        String::from("id,expected,phalanx,k2_c_m,k2_end_m,contact_losses,max_loop_gap_m\n");
    let (mut written, mut skipped) = (0, 0);
    for (i, c) in cases.iter().enumerate() {
        eprint!("\r[{}/{}] {:<60}", i + 1, cases.len(), c.id);
        let _ = std::io::stderr().flush();
        let Some(rec) = grasp::run(&c.spec) else {
            eprintln!(
                "\nskipped {}: the object cannot be placed or is never reached",
                c.id
            );
            skipped += 1;
            continue;
        };
        if rec.truth.both_phalanges {
            eprintln!("\nskipped {}: both phalanges touched", c.id);
            skipped += 1;
            continue;
        }
        // Replicas only where there is noise to draw: a perfect sensor records one trace.
        let draws = if c.sensor.is_noisy() { replicas } else { 0 };
        for r in 0..=draws {
            let (id, sensor) = c.drawn(r);
            let csv = grasp::to_csv(&rec, &sensor);
            let json = grasp::to_json(&id, c.level, &c.spec, &rec);
            std::fs::write(dir.join(format!("{id}.csv")), csv).expect("write csv");
            std::fs::write(dir.join(format!("{id}.json")), json).expect("write json");
            let f = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v:.6}"));
            index.push_str(&format!(
                "{},{},{},{},{},{},{:.3e}\n",
                id,
                match c.spec.target {
                    Target::None => "none",
                    Target::Object { distal: true, .. } => "distal",
                    Target::Object { distal: false, .. } => "proximal",
                },
                rec.truth.phalanx,
                f(rec.truth.k_c_m),
                f(rec.truth.k_end_m),
                rec.truth.contact_losses,
                rec.max_loop_gap_m
            ));
        }
        written += 1;
    }
    std::fs::write(dir.join("index.csv"), index).expect("write index");
    eprintln!(
        "\n{written} traces written to {}, {skipped} skipped, in {:.1} s",
        dir.display(),
        start.elapsed().as_secs_f64()
    );
}
