//! Small process helpers: every command is echoed before it runs and fails loudly.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus};

/// Result of an xtask step: `Err` carries a message for the user.
pub type Res<T = ()> = Result<T, String>;

/// The workspace root (the parent of xtask/).
pub fn root() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().unwrap_or(here).to_path_buf()
}

/// `cargo` (the one running this xtask when available), in the workspace root.
pub fn cargo() -> Command {
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    c.current_dir(root());
    // Cargo runs build.rs in the repository root; a relative file given by the user means a
    // path from where they typed the command.
    for key in ["FINGER_TOML", "FINGER_FW_SCENE"] {
        if let Some(abs) = std::env::var_os(key).and_then(|v| absolute_file(&v)) {
            c.env(key, abs);
        }
    }
    if std::env::var_os(THUMB_RUSTFLAGS).is_none() {
        if let Some(flags) = cargo_home().and_then(|h| thumb_rustflags(&h)) {
            c.env(THUMB_RUSTFLAGS, flags);
        }
    }
    c
}

/// The firmware target's rustflags, as cargo reads them from the environment.
pub const THUMB_RUSTFLAGS: &str = "CARGO_TARGET_THUMBV7EM_NONE_EABIHF_RUSTFLAGS";

/// Cargo's home: `CARGO_HOME`, else `~/.cargo`.
pub fn cargo_home() -> Option<PathBuf> {
    std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cargo")))
}

/// Flags that take `cargo_home` out of the source paths rustc embeds: each registry directory
/// `<home>/registry/src/index.crates.io-<hash>` reads `/registry/src/index.crates.io`, so the
/// panic locations of registry crates in the firmware's flash are the same on every machine
/// (unremapped, each is as long as cargo's home), and shorter. `None` when there is no
/// registry yet, or a path holds whitespace (the variable is split on it).
pub fn thumb_rustflags(cargo_home: &Path) -> Option<String> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(cargo_home.join("registry").join("src"))
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    let flags: Vec<String> = dirs
        .iter()
        .filter_map(|d| {
            let name = d.file_name()?.to_str()?;
            let short = name.rsplit_once('-').map_or(name, |(index, _hash)| index);
            Some(format!(
                "--remap-path-prefix={}=/registry/src/{short}",
                d.display()
            ))
        })
        .collect();
    (!flags.is_empty() && !flags.iter().any(|f| f.contains(char::is_whitespace)))
        .then(|| flags.join(" "))
}

/// Cargo profile of the host tools xtask builds and runs (Cargo.toml's `[profile.host]`).
const HOST_PROFILE: &str = "host";

/// Builds the `pts` host tool in [`HOST_PROFILE`]; returns the binary's path.
pub fn build_pts() -> Res<PathBuf> {
    run(cargo().args([
        "build",
        "-q",
        "--profile",
        HOST_PROFILE,
        "-p",
        "pts-cli",
        "--bin",
        "pts",
    ]))?;
    Ok(root().join("target").join(HOST_PROFILE).join("pts"))
}

/// `value` made absolute against the current directory when it names a relative `.toml` file;
/// `None` when it is absolute, empty or not a file name (e.g. a built-in scene name).
fn absolute_file(value: &std::ffi::OsStr) -> Option<PathBuf> {
    let p = Path::new(value);
    let is_file = p.extension().is_some_and(|e| e == "toml");
    if !is_file || p.is_absolute() {
        return None;
    }
    std::env::current_dir().ok().map(|d| d.join(p))
}

/// Shows a command the way a user would type it.
pub fn show(cmd: &Command) -> String {
    let mut s = String::new();
    for (k, v) in cmd.get_envs() {
        // Every command carries the firmware's path remapping; it says nothing about this one.
        if k == THUMB_RUSTFLAGS {
            continue;
        }
        if let Some(v) = v {
            s.push_str(&format!("{}={} ", k.to_string_lossy(), v.to_string_lossy()));
        }
    }
    s.push_str(&cmd.get_program().to_string_lossy());
    for a in cmd.get_args() {
        s.push(' ');
        s.push_str(&a.to_string_lossy());
    }
    s
}

/// Runs a command with inherited stdio; `Err` unless it exits 0.
pub fn run(cmd: &mut Command) -> Res {
    eprintln!("$ {}", show(cmd));
    let status = cmd
        .status()
        .map_err(|e| format!("cannot start `{}`: {e}", show(cmd)))?;
    check(cmd, status)
}

/// Runs a command and captures stdout; stderr is inherited. `Err` unless it exits 0.
pub fn output(cmd: &mut Command) -> Res<String> {
    eprintln!("$ {}", show(cmd));
    let out = cmd
        .stderr(std::process::Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot start `{}`: {e}", show(cmd)))?;
    check(cmd, out.status)?;
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Runs a command and captures stdout and its exit code (any code is returned, not an error).
pub fn output_code(cmd: &mut Command) -> Res<(String, i32)> {
    eprintln!("$ {}", show(cmd));
    let out = cmd
        .stderr(std::process::Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot start `{}`: {e}", show(cmd)))?;
    Ok((
        String::from_utf8_lossy(&out.stdout).into_owned(),
        out.status.code().unwrap_or(-1),
    ))
}

fn check(cmd: &Command, status: ExitStatus) -> Res {
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{}` failed ({status})", show(cmd)))
    }
}

/// True when `prog` is on PATH.
pub fn on_path(prog: &str) -> bool {
    std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).any(|d| d.join(prog).is_file()))
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_firmware_s_paths_are_remapped_from_each_registry_directory() {
        let home = std::env::temp_dir().join(format!("xtask-cargo-home-{}", std::process::id()));
        let src = home.join("registry").join("src");
        assert_eq!(thumb_rustflags(&home), None, "no registry yet");
        for d in ["index.crates.io-1949cf8c6b5b557f", "other-registry-0123"] {
            std::fs::create_dir_all(src.join(d)).unwrap();
        }
        std::fs::write(src.join("not-a-directory"), "").unwrap();
        let flags = thumb_rustflags(&home).expect("flags");
        assert_eq!(
            flags,
            format!(
                "--remap-path-prefix={0}/index.crates.io-1949cf8c6b5b557f=/registry/src/index.crates.io \
                 --remap-path-prefix={0}/other-registry-0123=/registry/src/other-registry",
                src.display()
            )
        );
        // A home with a space cannot be passed through the whitespace-split variable.
        let spaced = home.join("a b");
        std::fs::create_dir_all(spaced.join("registry").join("src").join("x")).unwrap();
        assert_eq!(thumb_rustflags(&spaced), None);
        std::fs::remove_dir_all(&home).unwrap();
    }
}
