//! Build the QEMU firmware for a scene, run it in qemu-system-arm and decode its defmt stream.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::util::{self, on_path, Res};

/// The firmware target.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// Longest a QEMU run may take (wall time) before it is killed as hung.
const RUN_TIMEOUT: Duration = Duration::from_secs(600);
/// `-icount shift=0`: the virtual clock advances 1 ns per instruction, so SysTick (25 MHz)
/// counts one tick per 40 instructions and the firmware can measure its work in instructions;
/// `sleep=off` lets WFI skip straight to the next timer instead of waiting in wall time.
pub const ICOUNT: &str = "shift=0,align=off,sleep=off";
/// Instructions per SysTick tick at [`ICOUNT`] (1 ns per instruction, 40 ns per 25 MHz tick).
pub const INSTR_PER_TICK: u64 = 40;

/// Makes sure qemu-system-arm is there: installs it with apt-get when it is missing and this
/// is a Debian machine where we are root; otherwise says exactly what to do.
pub fn ensure_qemu() -> Res {
    if on_path("qemu-system-arm") {
        return Ok(());
    }
    let root = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    if !on_path("apt-get") {
        return Err(
            "qemu-system-arm is not installed and there is no apt-get here: install \
                    QEMU's ARM system emulator (Debian/Ubuntu: `apt-get install qemu-system-arm`, \
                    macOS: `brew install qemu`) and run again"
                .into(),
        );
    }
    let sudo = if root {
        None
    } else if on_path("sudo") {
        Some("sudo")
    } else {
        return Err(
            "qemu-system-arm is not installed: run `apt-get install -y qemu-system-arm` \
                    as root, then run again"
                .into(),
        );
    };
    eprintln!(
        "qemu-system-arm not found: installing it with apt-get (Debian package qemu-system-arm)"
    );
    for args in [
        &["apt-get", "update", "-qq"][..],
        &["apt-get", "install", "-y", "-qq", "qemu-system-arm"][..],
    ] {
        let mut cmd = match sudo {
            Some(s) => {
                let mut c = Command::new(s);
                c.args(args);
                c
            }
            None => {
                let mut c = Command::new(args[0]);
                c.args(&args[1..]);
                c
            }
        };
        cmd.env("DEBIAN_FRONTEND", "noninteractive");
        util::run(&mut cmd).map_err(|e| {
            format!("{e}\ncould not install qemu-system-arm: install it by hand (`apt-get install qemu-system-arm`) and run again")
        })?;
    }
    if on_path("qemu-system-arm") {
        Ok(())
    } else {
        Err("apt-get finished but qemu-system-arm is still not on PATH".into())
    }
}

/// The value given to the firmware's build script for a `--scene` argument: a file path is
/// made absolute (the build runs in the workspace root), a name is passed as is.
pub fn scene_arg(scene: &str) -> Res<String> {
    let p = Path::new(scene);
    if scene.ends_with(".toml") || p.components().count() > 1 {
        let abs = std::fs::canonicalize(p).map_err(|e| format!("scene file {scene}: {e}"))?;
        Ok(abs.to_string_lossy().into_owned())
    } else {
        Ok(scene.to_string())
    }
}

/// Builds the QEMU firmware (release) for a scene; returns the ELF.
pub fn build(scene: &str) -> Res<PathBuf> {
    build_with(scene, None)
}

/// Builds the QEMU firmware with an injected fault (`panic@TICK`, `hardfault@TICK`).
pub fn build_with(scene: &str, inject: Option<&str>) -> Res<PathBuf> {
    let mut cmd = util::cargo();
    cmd.args([
        "build",
        "--release",
        "-p",
        "finger-fw",
        "--target",
        TARGET,
        "--no-default-features",
        "--features",
        "qemu",
    ])
    .env("FINGER_FW_SCENE", scene_arg(scene)?)
    .env("FINGER_FW_INJECT", inject.unwrap_or(""));
    util::run(&mut cmd)?;
    Ok(util::root()
        .join("target")
        .join(TARGET)
        .join("release")
        .join("finger-fw"))
}

/// One decoded defmt frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Timestamp in control ticks (100 µs each), when the frame has one.
    pub ts: Option<u64>,
    /// Level (`INFO`, `ERROR`, ...).
    pub level: String,
    /// The formatted message.
    pub msg: String,
}

impl Frame {
    /// A decoded defmt frame: timestamp back in ticks, level, formatted message.
    fn from_decoded(frame: &defmt_decoder::Frame<'_>) -> Frame {
        Frame {
            ts: frame
                .display_timestamp()
                .and_then(|t| ticks_from_seconds(t.to_string().trim())),
            level: frame
                .level()
                .map(|l| l.as_str().to_uppercase())
                .unwrap_or_else(|| "PRINT".into()),
            msg: frame.display_message().to_string(),
        }
    }
}

/// The firmware's control period, µs (src/telemetry.rs `TICK_US`).
const TICK_US: u64 = 100;

/// The firmware's `{=u64:us}` timestamp as decoded ("12.345600" s) back into control ticks.
fn ticks_from_seconds(text: &str) -> Option<u64> {
    let (whole, frac) = text.split_once('.')?;
    if frac.len() != 6 {
        return None;
    }
    let us = whole.parse::<u64>().ok()?.checked_mul(1_000_000)? + frac.parse::<u64>().ok()?;
    Some(us / TICK_US)
}

/// A finished QEMU run.
pub struct Run {
    /// Every frame, in order.
    pub frames: Vec<Frame>,
    /// QEMU's exit status (the firmware's semihosting exit code).
    pub status: i32,
    /// Wall time.
    pub wall: Duration,
}

/// Runs the ELF in QEMU mps2-an386, decodes defmt from semihosting stdout, calls `live` on
/// every frame as it arrives.
pub fn run(elf: &Path, live: &mut dyn FnMut(&Frame)) -> Res<Run> {
    ensure_qemu()?;
    let bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let table = defmt_decoder::Table::parse(&bytes)
        .map_err(|e| format!("defmt table of {}: {e}", elf.display()))?
        .ok_or_else(|| format!("{} has no defmt table", elf.display()))?;
    let mut cmd = machine("null");
    cmd.arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    eprintln!("$ {}", util::show(&cmd));
    let start = Instant::now();
    let mut child = cmd
        .spawn()
        .map_err(|e| format!("cannot start qemu-system-arm: {e}"))?;
    let mut stdout = child.stdout.take().ok_or("no stdout from qemu")?;
    // Watchdog: kill QEMU if the firmware hangs.
    let pid = child.id();
    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    let watchdog = std::thread::spawn(move || {
        if done_rx.recv_timeout(RUN_TIMEOUT).is_err() {
            let _ = Command::new("kill").arg(pid.to_string()).status();
            true
        } else {
            false
        }
    });
    let mut decoder = table.new_stream_decoder();
    let mut frames = Vec::new();
    let mut buf = [0u8; 4096];
    let mut malformed = 0usize;
    loop {
        let n = stdout
            .read(&mut buf)
            .map_err(|e| format!("reading qemu stdout: {e}"))?;
        if n == 0 {
            break;
        }
        decoder.received(&buf[..n]);
        loop {
            match decoder.decode() {
                Ok(frame) => {
                    let f = Frame::from_decoded(&frame);
                    live(&f);
                    frames.push(f);
                }
                Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                Err(defmt_decoder::DecodeError::Malformed) => {
                    malformed += 1;
                    if table.encoding().can_recover() {
                        continue;
                    }
                    return Err("malformed defmt frame (unrecoverable encoding)".into());
                }
            }
        }
    }
    let status = child.wait().map_err(|e| format!("waiting for qemu: {e}"))?;
    let _ = done_tx.send(());
    let killed = watchdog.join().unwrap_or(false);
    if killed {
        return Err(format!(
            "QEMU did not finish within {} s: the firmware hung",
            RUN_TIMEOUT.as_secs()
        ));
    }
    if malformed > 0 {
        return Err(format!("{malformed} malformed defmt frame(s) in the log"));
    }
    Ok(Run {
        frames,
        status: status.code().unwrap_or(-1),
        wall: start.elapsed(),
    })
}

/// qemu-system-arm as every run uses it: the mps2-an386 Cortex-M4, no display or monitor,
/// instruction counting (`ICOUNT`), semihosting on, UART0 to `serial`.
fn machine(serial: &str) -> Command {
    let mut cmd = Command::new("qemu-system-arm");
    cmd.args([
        "-cpu",
        "cortex-m4",
        "-machine",
        "mps2-an386",
        "-display",
        "none",
        "-monitor",
        "none",
        "-serial",
        serial,
        "-icount",
        ICOUNT,
        "-semihosting-config",
        "enable=on,target=native",
    ]);
    cmd
}

/// Starts the device-mode firmware in QEMU with UART0 on a TCP server socket at
/// 127.0.0.1:`port`; its defmt stream (semihosting stdout) goes to `log`. The caller kills it.
pub fn spawn_device(elf: &Path, port: u16, log: &Path) -> Res<std::process::Child> {
    ensure_qemu()?;
    let out = std::fs::File::create(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let mut cmd = machine(&format!("tcp:127.0.0.1:{port},server=on,wait=off"));
    cmd.arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(Stdio::inherit());
    eprintln!("$ {}", util::show(&cmd));
    cmd.spawn()
        .map_err(|e| format!("cannot start qemu-system-arm: {e}"))
}

/// Decodes a defmt stream captured in a file (what [`spawn_device`] wrote so far).
pub fn decode_file(elf: &Path, log: &Path) -> Res<Vec<Frame>> {
    let bytes = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let table = defmt_decoder::Table::parse(&bytes)
        .map_err(|e| format!("defmt table of {}: {e}", elf.display()))?
        .ok_or_else(|| format!("{} has no defmt table", elf.display()))?;
    let data = std::fs::read(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let mut decoder = table.new_stream_decoder();
    decoder.received(&data);
    let mut frames = Vec::new();
    loop {
        match decoder.decode() {
            Ok(frame) => frames.push(Frame::from_decoded(&frame)),
            Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
            Err(defmt_decoder::DecodeError::Malformed) => {
                if !table.encoding().can_recover() {
                    return Err("malformed defmt frame (unrecoverable encoding)".into());
                }
            }
        }
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn us_timestamps_map_back_to_ticks() {
        // What defmt-decoder prints for `{=u64:us}` of 123 456 700 µs: 1 234 567 ticks.
        assert_eq!(ticks_from_seconds("123.456700"), Some(1_234_567));
        assert_eq!(ticks_from_seconds("0.000100"), Some(1));
        assert_eq!(ticks_from_seconds("42"), None);
        assert_eq!(ticks_from_seconds("1.5"), None);
        assert_eq!(ticks_from_seconds("x.000100"), None);
    }
}
