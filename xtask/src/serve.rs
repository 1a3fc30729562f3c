//! `cargo xtask device [--port PORT]`: the device-mode firmware in QEMU, its UART on a TCP
//! socket for `pts board`, its defmt log shown live in the demo's words, until Ctrl-C.

use std::time::Duration;

use crate::demo::View;
use crate::util::{self, Res};
use crate::{device, qemu};

/// Parses `--port N` (default 4321, `pts board`'s default).
fn port_from_args(args: &[String]) -> Res<u16> {
    match args {
        [] => Ok(4321),
        [flag, v] if flag == "--port" => v
            .parse::<u16>()
            .ok()
            .filter(|p| *p >= 1024)
            .ok_or_else(|| format!("--port {v}: expected a TCP port in 1024..=65535")),
        _ => Err(format!(
            "unexpected arguments {args:?}; usage: cargo xtask device [--port PORT]"
        )),
    }
}

/// Entry point.
pub fn main(args: &[String]) -> Res<i32> {
    let port = port_from_args(args)?;
    qemu::ensure_qemu()?;
    let elf = device::build()?;
    let pts = util::build_pts()?;
    let log = util::root()
        .join("target")
        .join("finger-fw-device-serve.defmt");
    let mut child = qemu::spawn_device(&elf, port, &log)?;
    let pts = pts
        .strip_prefix(util::root())
        .unwrap_or(&pts)
        .display()
        .to_string();
    println!(
        "device-mode firmware running in QEMU; its UART is 127.0.0.1:{port}. In another terminal:\n  \
         {pts} board --connect 127.0.0.1:{port} hello\n  \
         {pts} board --connect 127.0.0.1:{port} set scene cyl10_k2_20\n  \
         {pts} board --connect 127.0.0.1:{port} grasp\n\
         Ctrl-C stops QEMU.\n"
    );
    let mut view = View::default();
    let mut shown = 0;
    loop {
        std::thread::sleep(Duration::from_millis(200));
        if let Ok(frames) = qemu::decode_file(&elf, &log) {
            for f in frames.iter().skip(shown) {
                view.show(f);
            }
            shown = shown.max(frames.len());
        }
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            return Ok(status.code().unwrap_or(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_argument() {
        let a = |v: &[&str]| port_from_args(&v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
        assert_eq!(a(&[]), Ok(4321));
        assert_eq!(a(&["--port", "5000"]), Ok(5000));
        assert!(a(&["--port", "80"]).is_err());
        assert!(a(&["--port", "x"]).is_err());
        assert!(a(&["--bogus"]).is_err());
    }
}
