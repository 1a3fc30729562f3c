//! Motor-controller firmware of the PTS finger: a thin RTIC 2 shell around crates/grasp.
//!
//! Target builds (`target_os = "none"`, thumbv7em-none-eabihf):
//! * feature `board` (default): STM32F411CEU6 Black Pill, drivers in `board/`, defmt over RTT;
//! * feature `qemu`: QEMU mps2-an386 with the simulated finger (crates/plant) as the board,
//!   defmt over semihosting, exits with a status;
//! * with either, feature `device`: many grasps per power-up driven by the host
//!   (`app_device.rs`, `device.rs`; USB CDC-ACM on the board, UART0 on QEMU) instead of one
//!   grasp at power-up (`app.rs`).
//!
//! On the host the package builds an inert binary (no registers, no linker scripts), so
//! `cargo build/test/clippy --workspace` stays host-only and harmless.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]
// Device mode replaces the power-up run's end report, watchdog feeding and latch handling.
#![cfg_attr(all(target_os = "none", feature = "device"), allow(dead_code))]

/// Build-time constants: the finger description and the QEMU scene (from build.rs).
// Generated data: exact decimal values from the finger file (π/2 is written out, not a typo).
#[allow(dead_code, clippy::approx_constant)]
mod config {
    include!(concat!(env!("OUT_DIR"), "/fw_config.rs"));
}

#[cfg(all(target_os = "none", not(feature = "device")))]
mod app;
#[cfg(all(target_os = "none", feature = "device"))]
mod app_device;
#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod board;
// The board's safe-state sequence: on the board, and in the host tests against a fake.
#[cfg(any(test, all(target_os = "none", not(feature = "qemu"))))]
mod bridge_regs;
mod ctl;
#[cfg(all(target_os = "none", feature = "device"))]
mod device;
#[cfg(target_os = "none")]
mod fault;
#[cfg(target_os = "none")]
mod settings_flash;
#[cfg(all(target_os = "none", feature = "qemu"))]
mod sim;
#[cfg(target_os = "none")]
mod telemetry;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
use board as platform;
#[cfg(all(target_os = "none", feature = "qemu"))]
use sim as platform;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
use defmt_rtt as _;
#[cfg(all(target_os = "none", feature = "qemu"))]
use defmt_semihosting as _;

#[cfg(not(target_os = "none"))]
mod host;

#[cfg(not(target_os = "none"))]
fn main() -> std::process::ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("simulate") {
        return match host::simulate(&args[1..]) {
            Ok(code) => std::process::ExitCode::from(code.clamp(0, 255) as u8),
            Err(e) => {
                eprintln!("error: {e}");
                std::process::ExitCode::FAILURE
            }
        };
    }
    println!(
        "finger-fw {} (finger {:?}): this is the firmware package; build it for the target:\n  \
         cargo build --release --target thumbv7em-none-eabihf            (board)\n  \
         cargo xtask demo                                               (QEMU with the simulated finger)",
        env!("CARGO_PKG_VERSION"),
        config::FINGER_NAME
    );
    println!("  finger-fw simulate [--scene NAME]                              (same control path on the host)");
    std::process::ExitCode::SUCCESS
}
