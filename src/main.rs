//! Firmware entry point (placeholder until the RTIC app lands).
fn main() {
    println!("finger-fw: build for thumbv7em-none-eabihf to get the firmware");
}
