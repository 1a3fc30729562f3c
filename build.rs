//! Build script of the firmware package.
//!
//! * Linker arguments only for the target binary (`target_os = "none"`), as
//!   `rustc-link-arg-bins`, so host builds, tests and clippy are unaffected.
//! * The memory map of the selected board (`board` or `qemu` feature) is copied to
//!   `OUT_DIR/fw-memory.x`, which `memory.x` includes; the QEMU build also gets the
//!   `device.x` of its small interrupt table (src/sim/pac.rs).
//! * The finger description becomes `const` data (`OUT_DIR/fw_config.rs`): the TOML file named
//!   by `FINGER_TOML` (parsed with `pts::config`), else the paper's prototype, with the two-point
//!   estimate's free-motion table for it. The target does no parsing. The QEMU scene is chosen by `FINGER_FW_SCENE` (a scene name or a TOML file), set by
//!   `cargo xtask demo --scene`; default `table2`.
use std::{env, fmt::Write as _, fs, path::PathBuf};

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-stm32f411ce.x");
    println!("cargo:rerun-if-changed=memory-mps2-an386.x");
    println!("cargo:rerun-if-env-changed=FINGER_TOML");
    println!("cargo:rerun-if-env-changed=FINGER_FW_SCENE");
    println!("cargo:rerun-if-env-changed=FINGER_FW_INJECT");
    println!("cargo:rerun-if-env-changed=FINGER_FW_ESTIMATOR");
    println!("cargo:rerun-if-env-changed=FINGER_FW_DELTA_TA_NM");
    println!("cargo:rerun-if-env-changed=FINGER_FW_REST_CHECK");

    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let qemu = env::var_os("CARGO_FEATURE_QEMU").is_some();
    let board = env::var_os("CARGO_FEATURE_BOARD").is_some();
    let target_none = env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none");

    if target_none {
        if qemu == board {
            panic!("finger-fw: enable exactly one of the features `board` (default) and `qemu` (use --no-default-features --features qemu)");
        }
        let map = if qemu {
            "memory-mps2-an386.x"
        } else {
            "memory-stm32f411ce.x"
        };
        fs::copy(map, out.join("fw-memory.x")).expect("copy the memory map");
        if qemu {
            fs::write(out.join("device.x"), DEVICE_X).expect("write device.x");
        }
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
        println!("cargo:rustc-link-arg-bins=--nmagic");
    }

    let mut src = String::new();
    finger_consts(&mut src);
    scene_consts(&mut src);
    inject_consts(&mut src);
    estimator_consts(&mut src);
    rest_check_consts(&mut src);
    fs::write(out.join("fw_config.rs"), src).expect("write fw_config.rs");
}

/// Weak defaults for the QEMU interrupt table (names of src/sim/pac.rs).
const DEVICE_X: &str = "\
PROVIDE(OTG_FS = DefaultHandler);
PROVIDE(UART0TX = DefaultHandler);
PROVIDE(UART1RX = DefaultHandler);
PROVIDE(UART1TX = DefaultHandler);
PROVIDE(UART2RX = DefaultHandler);
PROVIDE(UART2TX = DefaultHandler);
PROVIDE(GPIO0 = DefaultHandler);
PROVIDE(GPIO1 = DefaultHandler);
PROVIDE(TIMER0 = DefaultHandler);
PROVIDE(TIMER1 = DefaultHandler);
PROVIDE(DUALTIMER = DefaultHandler);
PROVIDE(SPI0 = DefaultHandler);
PROVIDE(ADC = DefaultHandler);
";

fn finger_consts(src: &mut String) {
    let given = env::var("FINGER_TOML").ok().filter(|p| !p.is_empty());
    let file = match &given {
        Some(path) => {
            println!("cargo:rerun-if-changed={path}");
            let text = fs::read_to_string(path)
                .unwrap_or_else(|e| fail(&format!("FINGER_TOML={path}: cannot read: {e}")));
            pts::config::FingerFile::from_toml_str(&text)
                .unwrap_or_else(|e| fail(&format!("FINGER_TOML={path}: {e}")))
        }
        None => pts::config::FingerFile::paper(),
    };
    // The controller's own check (the one `pts finger` runs): a file it refuses is a build
    // error here, not a halt at boot on the board.
    let cfg = grasp::ControllerConfig::DEFAULT
        .with_finger_file(&file, grasp::DriveConfig::DEFAULT.dt_s)
        .unwrap_or_else(|e| {
            fail(&format!(
                "FINGER_TOML={}: {e}",
                given.as_deref().unwrap_or("(paper prototype)")
            ))
        });
    let f = file.finger;
    let _ = writeln!(
        src,
        "/// Drive, motor, encoder and current-sense constants of a finger file.\n\
         #[derive(Clone, Copy, Debug)]\n\
         pub struct DriveConsts {{ pub gear_ratio: f64, pub efficiency: f64, pub kt_nm_per_a: f64, \
         pub resistance_ohm: f64, pub supply_v: f64, pub counts_per_rev: f64, \
         pub amps_per_count: f64, pub zero_count: f64, pub max_current_a: f64, \
         pub inertia_kgm2: f64, pub backlash_rad: f64, pub priors: pathfit::FitPriors }}"
    );
    if given.is_some() {
        let _ = writeln!(
            src,
            "/// From the finger file given at build time.\n\
             pub const FINGER_DRIVE: Option<DriveConsts> = Some(DriveConsts {{ gear_ratio: {:?}, \
             efficiency: {:?}, kt_nm_per_a: {:?}, resistance_ohm: {:?}, supply_v: {:?}, \
             counts_per_rev: {:?}, amps_per_count: {:?}, zero_count: {:?}, max_current_a: {:?}, \
             inertia_kgm2: {:?}, backlash_rad: {:?}, priors: pathfit::{:?} }});",
            file.drive.gear_ratio,
            file.drive.efficiency,
            file.motor.kt_nm_per_a,
            file.motor.resistance_ohm,
            file.motor.supply_v,
            f64::from(file.encoder.counts_per_rev),
            file.current_sense.amps_per_count,
            f64::from(file.current_sense.zero_count),
            file.motor.max_current_a,
            file.drive.inertia_kgm2,
            file.drive.backlash_rad,
            cfg.drive.priors
        );
    } else {
        let _ = writeln!(
            src,
            "/// No finger file: the controller's default drive.\n\
             pub const FINGER_DRIVE: Option<DriveConsts> = None;"
        );
    }
    let _ = writeln!(
        src,
        "/// Name of the finger description this firmware was built for.\n\
         pub const FINGER_NAME: &str = {:?};",
        file.name
    );
    let _ = writeln!(
        src,
        "/// Geometry and springs (SI), from the finger description at build time.\n\
         pub const FINGER: pts::Finger = pts::Finger {{ l1: {:?}, l2: {:?}, a: {:?}, b: {:?}, c: {:?}, \
         phi2: {:?}, theta01: {:?}, theta02: {:?}, k1: {:?}, k2: {:?} }};",
        f.l1, f.l2, f.a, f.b, f.c, f.phi2, f.theta01, f.theta02, f.k1, f.k2
    );
    let _ = writeln!(
        src,
        "/// θa at the finger's rest pose (rad), where the encoder is zeroed.\n\
         pub const FINGER_THETA_A_REST_RAD: f64 = {:?};",
        cfg.drive.theta_a_rest_rad
    );
    let _ = writeln!(
        src,
        "/// The finger with its rest angle, checked here by the controller's own check.\n\
         pub const FINGER_REST: grasp::FingerRest = \
         grasp::FingerRest::checked_at_build(FINGER, FINGER_THETA_A_REST_RAD);"
    );
    let st = file.stops;
    let _ = writeln!(
        src,
        "/// The finger's extension stops, from the finger description at build time.\n\
         pub const FINGER_STOPS: pts::Stops = pts::Stops {{ theta1_min_rad: {:?}, \
         theta2_min_rad: {:?}, stiffness_nm_per_rad: {:?} }};",
        st.theta1_min_rad, st.theta2_min_rad, st.stiffness_nm_per_rad
    );
    rest_check_const(src, &file, &cfg.drive);
    free_table_const(src, &f);
    path_table_const(src, &f, &cfg.drive);
}

/// The rest check for the finger, its drive and its stops (`sim_board::finger_rest_check`: the
/// stop's pose and the springs' torque there from the geometry) as a constant: the board links
/// no kinematics for it. A finger whose stop pose the model cannot solve is a build error.
fn rest_check_const(src: &mut String, file: &pts::config::FingerFile, drive: &grasp::DriveConfig) {
    let Some(c) = sim_board::finger_rest_check(&file.finger, drive, &file.stops) else {
        fail(
            "FINGER_TOML: the finger's rest or open-stop pose cannot be solved for the rest check",
        );
    };
    let _ = writeln!(
        src,
        "/// The rest check for [`FINGER`] against [`FINGER_STOPS`] (built at build time).\n\
         pub const FINGER_REST_CHECK: grasp::RestCheck = grasp::RestCheck {{ \
         open_torque_nm: {:?}, return_torque_nm: {:?}, stop_from_rest_rad: {:?}, \
         stop_spring_nm: {:?}, friction_nm: {:?}, stop_compliance_rad_per_nm: {:?}, \
         backlash_rad: {:?}, still_s: {:?}, still_rad: {:?}, timeout_s: {:?}, \
         max_travel_rad: {:?}, return_band_rad: {:?} }};",
        c.open_torque_nm,
        c.return_torque_nm,
        c.stop_from_rest_rad,
        c.stop_spring_nm,
        c.friction_nm,
        c.stop_compliance_rad_per_nm,
        c.backlash_rad,
        c.still_s,
        c.still_rad,
        c.timeout_s,
        c.max_travel_rad,
        c.return_band_rad
    );
}

/// The two-point estimate's free-motion table for the finger (`pts::table::FreeTable`, Q32.32,
/// built here from the f64 model) as a constant: in flash, and the firmware links neither
/// the table's builder nor the f64 model. `None` when the finger is outside the table.
fn free_table_const(src: &mut String, f: &pts::Finger) {
    let table = pts::table::FreeTable::<pts::fixed::Fx32>::new(f).ok();
    let expr = match table.map(|t| t.to_raw()) {
        Some(r) => format!(
            "Some(pts::table::FreeTable::from_raw(&pts::table::FreeTableRaw {{ finger: FINGER, \
             model: {:?}, scalars: {:?}, small: {:?}, seg: {:?} }}))",
            r.model, r.scalars, r.small, r.seg
        ),
        None => "None".to_string(),
    };
    let _ = writeln!(
        src,
        "/// The two-point estimate's free-motion table for [`FINGER`] (built at build time).\n\
         pub static FREE_TABLE: Option<pts::table::FreeTable<pts::fixed::Fx32>> = {expr};"
    );
}

/// The path fit's table for the finger, its drive's measurement model (inertia, backlash) and
/// the board's control period (`grasp::path_table`, what init would build with
/// `DriveConfig::DEFAULT.dt_s`, the period of every board build) as a constant: in flash, and
/// the board's firmware links no table builder. `None` when the finger is outside the table's
/// formats. The simulated board (QEMU, the host runner) builds its table at init for its
/// scene's period instead.
fn path_table_const(src: &mut String, f: &pts::Finger, drive: &grasp::DriveConfig) {
    let dt_ns = (grasp::DriveConfig::DEFAULT.dt_s * 1e9) as u32;
    let expr = match grasp::path_table(f, drive, dt_ns).ok().map(|t| t.to_raw()) {
        Some(r) => format!(
            "Some(pathfit::q::PathTable::from_raw(&pathfit::q::PathTableRaw {{ finger: FINGER, \
             model: {:?}, consts: {:?}, fit_contact_angle: {:?}, object: pathfit::ObjectModel::{:?}, \
             theta2_0: {:?}, segs: {:?}, seg: {:?}, theta_a_free: {:?}, q: {:?}, samples: {:?}, \
             approach_urad_q16: {:?}, drop_plateaus: {:?}, tick_s_bits: {:?}, tick_ns: {:?} }}))",
            r.model,
            r.consts,
            r.fit_contact_angle,
            r.object,
            r.theta2_0,
            r.segs,
            r.seg,
            r.theta_a_free,
            r.q,
            r.samples,
            r.approach_urad_q16,
            r.drop_plateaus,
            r.tick_s_bits,
            r.tick_ns
        ),
        None => "None".to_string(),
    };
    let _ = writeln!(
        src,
        "/// The path fit's table for [`FINGER`] at the board's control period (built at build time).\n\
         pub static PATH_TABLE: Option<pathfit::q::PathTable> = {expr};"
    );
}

/// A build-time mistake: one clear line (cargo shows a build script's stderr on failure) and a
/// failed build, instead of a panic's backtrace hint.
fn fail(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(1)
}

/// A scene file turned into a constant Rust expression of `plant::Scene` (checked by the
/// plant's own TOML reader, written out with full paths by `to_rust_expr`).
fn scene_file_const(path: &str) -> String {
    let scene = plant::toml_scene::from_toml_file(std::path::Path::new(path))
        .unwrap_or_else(|e| fail(&format!("FINGER_FW_SCENE={path}: {e}")));
    plant::toml_scene::to_rust_expr(&scene)
}

/// `FINGER_FW_INJECT=panic@TICK`, `hardfault@TICK`, `reset@TICK` or `stackoverflow@TICK`: a
/// fault injected by the test command to check the last-resort handlers; `telstall@TICK`: the
/// telemetry task stops taking messages at TICK for a while (src/telemetry.rs); `settings@0` / `settings-corrupt@0`:
/// init stores test settings / damages the store and resets once (the store across a reset). Unset in every normal build.
fn inject_consts(src: &mut String) {
    let inject = match env::var("FINGER_FW_INJECT") {
        Ok(v) if !v.is_empty() => {
            let (kind, at) = v
                .split_once('@')
                .unwrap_or_else(|| fail(&format!("FINGER_FW_INJECT={v}: expected KIND@TICK")));
            let at: u32 = at
                .parse()
                .unwrap_or_else(|_| fail(&format!("FINGER_FW_INJECT={v}: TICK must be a number")));
            if !matches!(
                kind,
                "panic"
                    | "hardfault"
                    | "reset"
                    | "stackoverflow"
                    | "telstall"
                    | "settings"
                    | "settings-corrupt"
            ) {
                fail(&format!(
                    "FINGER_FW_INJECT={v}: KIND is panic, hardfault, reset, stackoverflow, telstall, settings or settings-corrupt"
                ));
            }
            format!("Some(({kind:?}, {at}))")
        }
        _ => "None".to_string(),
    };
    let _ = writeln!(
        src,
        "/// Fault injection (test command only).\npub const INJECT: Option<(&str, u32)> = {inject};"
    );
}

/// The estimator linked into the firmware: the Cargo feature `path-fit` selects the path fit;
/// `FINGER_FW_ESTIMATOR=two-point|path-fit` chooses too (default: the path fit, the
/// controller's default; `two-point` builds the smaller firmware with the paper's method only).
/// Both map to the same cfg; a conflict is an error.
fn estimator_consts(src: &mut String) {
    // `fw_path_fit`: the path fit's table slot exists only in that build (3.6 KB of RAM).
    println!("cargo::rustc-check-cfg=cfg(fw_path_fit)");
    let feature = env::var_os("CARGO_FEATURE_PATH_FIT").is_some();
    let path_fit = "Some(grasp::Estimator::PathFit)";
    let e = match env::var("FINGER_FW_ESTIMATOR").as_deref() {
        // The host tool's former spelling (`pathfit`) is accepted too.
        Ok("two-point" | "twopoint") if feature => fail(
            "FINGER_FW_ESTIMATOR=two-point contradicts the feature `path-fit`; use one of them",
        ),
        Ok("two-point" | "twopoint") => "Some(grasp::Estimator::TwoPoint)",
        Ok("path-fit" | "pathfit") => path_fit,
        // The controller's default estimator, the path fit.
        Ok("") | Err(_) => path_fit,
        Ok(other) => fail(&format!(
            "FINGER_FW_ESTIMATOR={other}: not an estimator; allowed: two-point, path-fit"
        )),
    };
    if e == path_fit {
        println!("cargo:rustc-cfg=fw_path_fit");
    }
    let _ = writeln!(
        src,
        "/// Estimator chosen at build time (None: the controller's default).\n\
         pub const ESTIMATOR: Option<grasp::Estimator> = {e};"
    );
    let dta = match env::var("FINGER_FW_DELTA_TA_NM") {
        Ok(v) if !v.is_empty() => {
            let x: f64 = v.parse().unwrap_or_else(|_| {
                fail(&format!("FINGER_FW_DELTA_TA_NM={v}: not a number (N·m)"))
            });
            if !(x > 0.0 && x < 5.0) {
                fail(&format!(
                    "FINGER_FW_DELTA_TA_NM={v}: outside the allowed (0, 5) N·m"
                ));
            }
            format!("Some({x:?})")
        }
        _ => "None".to_string(),
    };
    let _ = writeln!(
        src,
        "/// ΔT_a chosen at build time (N·m; None: the firmware default).\n\
         pub const DELTA_TA_NM: Option<f64> = {dta};"
    );
}

/// `FINGER_FW_REST_CHECK=on|off`: the rest check before the approach (grasp::rest); unset,
/// the build's default (on for the board, off on the simulated board).
fn rest_check_consts(src: &mut String) {
    let v = match env::var("FINGER_FW_REST_CHECK").as_deref() {
        Ok("on") => "Some(true)",
        Ok("off") => "Some(false)",
        Ok("") | Err(_) => "None",
        Ok(other) => fail(&format!("FINGER_FW_REST_CHECK={other}: expected on or off")),
    };
    let _ = writeln!(
        src,
        "/// Rest check chosen at build time (None: the build's default).\n\
         pub const REST_CHECK: Option<bool> = {v};"
    );
}

fn scene_consts(src: &mut String) {
    let scene = env::var("FINGER_FW_SCENE")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "table2".to_string());
    let _ = writeln!(
        src,
        "/// The QEMU build's scene (name or file), chosen at build time by FINGER_FW_SCENE.\n\
         pub const SCENE: &str = {scene:?};"
    );
    if scene.ends_with(".toml") {
        println!("cargo:rerun-if-changed={scene}");
        let code = scene_file_const(&scene);
        let _ = writeln!(
            src,
            "/// The scene file, as const data.\npub const SCENE_CONST: Option<plant::Scene> = Some({code});"
        );
    } else {
        if !plant::scenes::NAMES.contains(&scene.as_str()) {
            fail(&format!(
                "FINGER_FW_SCENE={scene}: no such scene; built-in scenes: {}",
                plant::scenes::NAMES.join(", ")
            ));
        }
        let _ = writeln!(
            src,
            "/// A built-in scene (by name).\npub const SCENE_CONST: Option<plant::Scene> = None;"
        );
    }
}
