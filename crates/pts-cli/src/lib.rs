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
