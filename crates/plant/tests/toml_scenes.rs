//! The shipped TOML scenes equal the const built-ins; bad TOML is rejected with the key name.

use plant::toml_scene::{from_toml_file, from_toml_str, to_toml_string};
use plant::{scenes, Plant};

fn dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

#[test]
fn every_builtin_has_an_identical_toml_file() {
    for name in scenes::NAMES {
        let file = dir().join(format!("{name}.toml"));
        let s = from_toml_file(&file).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(Some(s), scenes::by_name(name), "{name}");
    }
    let n = std::fs::read_dir(dir()).unwrap().count();
    assert_eq!(
        n,
        scenes::NAMES.len(),
        "a TOML scene without a built-in twin"
    );
}

#[test]
fn round_trip_through_toml() {
    for name in scenes::NAMES {
        let s = scenes::by_name(name).unwrap();
        let back = from_toml_str(&to_toml_string(&s)).unwrap();
        assert_eq!(back, s, "{name}");
    }
}

#[test]
fn rejects_unknown_keys_and_bad_values_by_key() {
    let e = from_toml_str("dt = 1e-4").unwrap_err();
    assert_eq!(e.key, "dt");
    let e = from_toml_str("[drive]\nr_ohms = 3.0").unwrap_err();
    assert_eq!(e.key, "drive.r_ohms");
    let e = from_toml_str("name = \"x\"\n[object]\nkind = \"none\"\n\n[faults]\nshort_at = 1.0")
        .unwrap_err();
    assert_eq!(e.key, "faults.short_at");
    let e = from_toml_str("[drive]\nr_ohm = -3.0").unwrap_err();
    assert_eq!(e.key, "drive.r_ohm");
    let e = from_toml_str("[sensors]\nadc_bits = 40").unwrap_err();
    assert_eq!(e.key, "sensors.adc_bits");
    let e = from_toml_str("[sensors]\nencoder_cpt = -1").unwrap_err();
    assert_eq!(e.key, "sensors.encoder_cpt");
    let e = from_toml_str("[finger]\nl1_m = 0.0").unwrap_err();
    assert_eq!(e.key, "finger.l1_m");
    let e = from_toml_str("[object]\nkind = \"vertex\"\nradius_m = 0.1\nx_m = 0.1\ny_m = 0.1")
        .unwrap_err();
    assert_eq!(e.key, "object.radius_m");
    let e = from_toml_str("[object]\nkind = \"cylinder\"\nradius_m = 0.01\nphalanx = 3\nk_m = 0.01\ntheta1_c_rad = 1.0")
        .unwrap_err();
    assert_eq!(e.key, "object.phalanx");
    let e = from_toml_str("[object]\nkind = \"cylinder\"\nradius_m = 0.01\nphalanx = 2\nk_m = 0.5\ntheta1_c_rad = 1.0")
        .unwrap_err();
    assert_eq!(e.key, "object.k_m");
    let e = from_toml_str("[command]\nmode = \"duty\"\nto = 2.0").unwrap_err();
    assert_eq!(e.key, "command.to");
    let e = from_toml_str("dt_s = nan").unwrap_err();
    assert_eq!(e.key, "dt_s");
    assert!(from_toml_str("[drive]\nr_ohm = ").is_err());
}

#[test]
fn csv_trace_has_the_columns_and_the_contact() {
    let mut s = scenes::by_name("table2").unwrap();
    s.duration_s = 3.0;
    let mut out = Vec::new();
    let rows = plant::trace::run_scene_csv(&s, &mut out, 100).unwrap();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next().unwrap(), plant::trace::HEADER);
    assert_eq!(rows as usize, text.lines().count() - 1);
    let contact_row = text.lines().find(|l| l.ends_with("first_contact")).unwrap();
    let cols: Vec<&str> = contact_row.split(',').collect();
    assert_eq!(cols.len(), 14);
    assert_eq!(cols[8], "distal");
    let theta: f64 = cols[1].parse().unwrap();
    assert!((theta - -0.223_771).abs() < 1e-4);
    // The scene still builds a plant after the round trip through the file format.
    Plant::new(&s).unwrap();
}

#[test]
fn any_seed_round_trips() {
    let mut s = scenes::table2();
    for seed in [0, 1, u64::MAX, 1 << 63, 0x5EED_F1A6_0000_0001] {
        s.sensors.seed = seed;
        assert_eq!(
            from_toml_str(&to_toml_string(&s)).unwrap().sensors.seed,
            seed
        );
    }
}

#[test]
fn start_pose_in_toml() {
    let s = from_toml_str("start_theta_a_rad = -0.3\n[object]\nkind = \"none\"").unwrap();
    assert_eq!(s.start_theta_a_rad, Some(-0.3));
    assert_eq!(from_toml_str(&to_toml_string(&s)).unwrap(), s);
    let e = from_toml_str("start_theta_a_rad = inf").unwrap_err();
    assert_eq!(e.key, "start_theta_a_rad");
    // The Rust-expression export has no `inf` (not a Rust literal).
    let expr = plant::toml_scene::to_rust_expr(&scenes::by_name("fault_short").unwrap());
    assert!(expr.contains("f64::INFINITY") && !expr.contains(" inf"));
}

#[test]
fn power_up_offset_in_toml() {
    let s = from_toml_str("[faults]\npower_up_offset_rad = 0.45").unwrap();
    assert_eq!(s.faults.power_up_offset_rad, 0.45);
    assert_eq!(from_toml_str(&to_toml_string(&s)).unwrap(), s);
    assert!(plant::toml_scene::to_rust_expr(&s).contains("power_up_offset_rad: 0.45"));
    let e = from_toml_str("[faults]\npower_up_offset_rad = 2.0").unwrap_err();
    assert_eq!(e.key, "faults.power_up_offset_rad");
}
