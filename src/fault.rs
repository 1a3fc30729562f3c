//! Last-resort handlers: a panic or a HardFault puts the H-bridge in its safe state first,
//! then reports (QEMU: exits non-zero through semihosting; board: halts, the IWDG resets).

use core::panic::PanicInfo;

use crate::platform;

/// Exit status of a panic (QEMU).
pub const STATUS_PANIC: i32 = 101;
/// Exit status of a HardFault (QEMU).
pub const STATUS_HARDFAULT: i32 = 102;

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    platform::safe_state();
    cortex_m::interrupt::disable();
    if let Some(loc) = info.location() {
        defmt::error!(
            "PANIC at {=str}:{=u32} bridge_safe=true",
            loc.file(),
            loc.line()
        );
    } else {
        defmt::error!("PANIC bridge_safe=true");
    }
    platform::halt(STATUS_PANIC)
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    platform::safe_state();
    defmt::error!("HARDFAULT pc={=u32:#x} bridge_safe=true", frame.pc());
    platform::halt(STATUS_HARDFAULT)
}
