//! Writes the open-loop CSV trace of a scene (built-in name or TOML file) to stdout.
//! `cargo run -p plant --features std --example trace_csv -- table2 [decimate] > table2.csv`
fn main() {
    let arg = std::env::args().nth(1).unwrap_or_else(|| "table2".into());
    let decimate: u32 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let scene = if arg.ends_with(".toml") {
        match plant::toml_scene::from_toml_file(std::path::Path::new(&arg)) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{arg}: {e}");
                std::process::exit(2);
            }
        }
    } else {
        match plant::scenes::by_name(&arg) {
            Some(s) => s,
            None => {
                eprintln!(
                    "unknown scene {arg}; built-in: {}",
                    plant::scenes::NAMES.join(", ")
                );
                std::process::exit(2);
            }
        }
    };
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    match plant::trace::run_scene_csv(&scene, &mut out, decimate) {
        Ok(rows) => eprintln!("{rows} rows"),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    }
}
