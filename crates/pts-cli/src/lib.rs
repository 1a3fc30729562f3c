//! The `pts` host tool as a library: each subcommand is a module with plain functions, so the
//! integration tests call the same code the binary runs.

/// `println!` that ends the process quietly (status 141, as after SIGPIPE) when stdout is
/// gone, e.g. `pts sim --sweep | head`, instead of panicking.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if writeln!(std::io::stdout(), $($arg)*).is_err() {
            std::process::exit(141);
        }
    }};
}

pub mod board;
pub mod calibrate;
pub mod estimate_cmd;
pub mod eval;
pub mod linalg;
pub mod method;
pub mod offline;
pub mod path;
pub mod plot;
pub mod replay;
pub mod sim;
pub mod sim_cmd;
pub mod sweep;
pub mod trace;
pub mod watch;

use pts::config::FingerFile;
use std::path::Path;

/// The numeric type `pts eval --numeric fixed` runs: the firmware's back end.
pub type FixedReal = pts::FirmwareReal;

/// Loads a finger description for the model alone (`pts eval`, `pts plot kc`): the file's own
/// checks, not the controller's, so a linkage no controller could run (say one that stops
/// closing when flexed) can still be evaluated. The paper's prototype when no file is given.
pub fn load_finger_model(path: Option<&Path>) -> Result<FingerFile, String> {
    let Some(path) = path else {
        return Ok(FingerFile::paper());
    };
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read finger file {}: {e}", path.display()))?;
    FingerFile::from_toml_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// What the firmware derives from a finger description, as TOML comments (`pts finger`
/// prints them under the file, which still reads back as the same file): the rest pose, the
/// open stop the rest check homes against and the springs' torque there, and the stiffnesses
/// the contact detection tells apart.
pub fn finger_derived(file: &FingerFile) -> Result<String, String> {
    let cfg = replay::controller_config(file, grasp::DriveConfig::DEFAULT.dt_s)?;
    let rest = cfg.drive.theta_a_rest_rad;
    let check = sim_board::finger_rest_check(&file.finger, &cfg.drive, &file.stops)
        .ok_or("the rest or open-stop pose cannot be solved")?;
    let d = cfg.detection_stiffness(&file.finger)?;
    let thr = cfg.detect_stiffness_nm_per_rad;
    Ok(format!(
        "# Derived by the firmware's build (comments, not read back):\n\
         #   rest pose θa = {rest:.5} rad; open stop {:.5} rad from it, the springs holding \
         {:.4} N·m there (the rest check)\n\
         #   contact detection at {thr} N·m/rad: free motion up to {:.3} N·m/rad over the \
         approach (allowed: up to {:.3}), softest contact {:.3} N·m/rad, {} (allowed: from \
         {thr})\n\
         #   contact.mu_max = {mu}: `pts estimate` on a recording widens σ(k2,c) over a contact \
         friction µ from 0 to {mu}; the firmware's estimate is fitted at µ = 0 and its σ does \
         not carry µ",
        check.stop_from_rest_rad,
        check.stop_spring_nm,
        d.free_max_nm_per_rad,
        0.5 * thr,
        d.contact_min_nm_per_rad,
        d.softest,
        mu = file.contact.mu_max,
    ))
}

/// Loads a finger description, or the paper's prototype when no file is given, checked as the
/// controller checks it (drive, limits, both estimators' tables).
pub fn load_finger(path: Option<&Path>) -> Result<FingerFile, String> {
    let file = load_finger_model(path)?;
    let Some(path) = path else {
        return Ok(file);
    };
    // The controller's own check, the one the firmware's build runs: a file accepted here is
    // accepted by the board built from it.
    replay::controller_config(&file, grasp::DriveConfig::DEFAULT.dt_s)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(file)
}
