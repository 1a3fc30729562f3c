//! The text parsers the tools read: scene TOML (`plant::toml_scene::from_toml_str`), finger
//! TOML (`pts::config::FingerFile::from_toml_str`) and trace CSV
//! (`pts_cli::trace::read_csv`). Any panic is a finding; whatever parses must be usable.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(scene) = plant::toml_scene::from_toml_str(text) {
        // A parsed scene must build a plant or give a typed error, and round-trip.
        let _ = plant::Plant::new(&scene);
        let _ = plant::toml_scene::to_toml_string(&scene);
    }
    if let Ok(f) = pts::config::FingerFile::from_toml_str(text) {
        let _ = f.to_toml_string();
    }
    if let Ok(t) = pts_cli::trace::read_csv(text, &|i| i * 2.0) {
        let _ = t.rows.len();
    }
});
