//! The text parsers the tools read: scene TOML (`plant::toml_scene::from_toml_str`), finger
//! TOML (`pts::config::FingerFile::from_toml_str`) and trace CSV
//! (`pts_cli::trace::read_csv`, then the segmentation and estimate `pts estimate` runs on
//! it). Any panic is a finding; whatever parses must be usable.
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
        // A trace that reads is usable: rows in time order, finite, one length per column.
        assert!(!t.is_empty());
        assert_eq!(t.theta_a_rad.len(), t.len());
        assert_eq!(t.torque_nm.len(), t.len());
        assert!(t.t_s.windows(2).all(|w| w[0] <= w[1]));
        assert!(t
            .t_s
            .iter()
            .chain(&t.theta_a_rad)
            .chain(&t.torque_nm)
            .all(|v| v.is_finite()));
        // And what `pts estimate` does with it ends in contacts or typed refusals.
        let finger = pts::config::FingerFile::paper();
        let _ = pts_cli::replay::segment(&t, &finger, pts_cli::method::Method::Pathfit);
    }
});
