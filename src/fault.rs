//! Last-resort handlers: a panic or a HardFault puts the H-bridge in its safe state first,
//! then reports (QEMU: exits non-zero through semihosting; board: halts, the IWDG resets).

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use crate::platform;

/// Exit status of a panic (QEMU).
pub const STATUS_PANIC: i32 = 101;
/// Exit status of a HardFault (QEMU).
pub const STATUS_HARDFAULT: i32 = 102;

/// Set by the first handler that runs: a fault inside the logger (or a second fault while
/// reporting the first) goes straight to the halt instead of recursing into defmt.
static REPORTING: AtomicBool = AtomicBool::new(false);

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    platform::safe_state();
    cortex_m::interrupt::disable();
    if !REPORTING.swap(true, Ordering::SeqCst) {
        if let Some(loc) = info.location() {
            defmt::error!(
                "PANIC at {=str}:{=u32} bridge_safe={=bool}",
                loc.file(),
                loc.line(),
                platform::bridge_safe_now()
            );
        } else {
            defmt::error!("PANIC bridge_safe={=bool}", platform::bridge_safe_now());
        }
    }
    platform::halt(STATUS_PANIC)
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    platform::safe_state();
    if !REPORTING.swap(true, Ordering::SeqCst) {
        defmt::error!(
            "HARDFAULT pc={=u32:#x} bridge_safe={=bool}",
            frame.pc(),
            platform::bridge_safe_now()
        );
    }
    platform::halt(STATUS_HARDFAULT)
}

/// Fault injection for the test command (`FINGER_FW_INJECT=panic@TICK|hardfault@TICK` at build
/// time; never set in a normal build): checks that the handlers above reach the safe state.
#[inline(always)]
pub fn inject(tick: u32) {
    match crate::config::INJECT {
        Some(("panic", at)) if at == tick => panic!("injected panic at tick {}", tick),
        Some(("hardfault", at)) if at == tick => {
            // A read from unmapped memory: BusFault, escalated to HardFault (not enabled).
            // SAFETY: deliberately faulting; the handler never returns.
            let v = unsafe { core::ptr::read_volatile(0xFFFF_FFF0 as *const u32) };
            core::hint::black_box(v);
        }
        _ => {}
    }
}

/// The supervision chain's check-ins and the watchdog's window.
///
/// The sampling task feeds the watchdog only when it runs (the loop is alive) *and* the
/// supervise task has checked in within [`SUP_WINDOW_TICKS`]: the supervise task runs at
/// least every [`SUP_HEARTBEAT_TICKS`] (spawned for each sample and, with nothing to do, as a
/// heartbeat), so a stalled, starved or locked supervisor stops the feeding and the IWDG
/// resets the MCU within `SUP_WINDOW_TICKS` + the IWDG timeout (6.8–18.8 ms over the LSI's
/// tolerance). While driving, the loop's own heartbeat check (grasp's `SupervisorStalled`)
/// switches the bridge off sooner than that.
pub mod supervision {
    use core::sync::atomic::{AtomicU32, Ordering};

    /// The sampling task spawns the supervise task at least this often (ticks), input or not.
    pub const SUP_HEARTBEAT_TICKS: u32 = 32;
    /// The watchdog is fed only while the supervise task's last check-in is at most this old
    /// (ticks): two heartbeats.
    pub const SUP_WINDOW_TICKS: u32 = 2 * SUP_HEARTBEAT_TICKS;

    /// Tick of the supervise task's last check-in (0 before the first: the first ticks are
    /// inside the window).
    static SUP_CHECKIN_TICK: AtomicU32 = AtomicU32::new(0);

    /// The supervise task is alive at `tick`.
    pub fn supervisor_check_in(tick: u32) {
        SUP_CHECKIN_TICK.store(tick, Ordering::Relaxed);
    }

    /// Whether the watchdog may be fed at `tick` (the caller, the sampling task, is the
    /// loop's own check-in).
    pub fn may_feed(tick: u32) -> bool {
        tick.wrapping_sub(SUP_CHECKIN_TICK.load(Ordering::Relaxed)) <= SUP_WINDOW_TICKS
    }
}

/// The stack's high-water mark: cortex-m-rt's `paint-stack` (QEMU builds) fills the stack with
/// a pattern at reset; the deepest word no longer holding it is the deepest the stack went.
/// With flip-link the stack grows down from `_stack_start` to `_stack_end`, the start of RAM.
#[cfg(feature = "qemu")]
pub mod stack {
    /// cortex-m-rt's paint pattern.
    const PAINT: u32 = 0xCCCC_CCCC;

    extern "C" {
        static _stack_start: u32;
        static _stack_end: u32;
    }

    /// (bytes used at most, stack size in bytes). Reads memory below the live stack pointer
    /// only; words still painted are untouched.
    pub fn high_water() -> (u32, u32) {
        // SAFETY: the linker symbols' addresses bound the stack region; reading it word by
        // word (volatile) from its far end up to the first overwritten word stays inside it.
        unsafe {
            let top = core::ptr::addr_of!(_stack_start) as usize;
            let bottom = core::ptr::addr_of!(_stack_end) as usize;
            let mut p = bottom;
            while p < top && core::ptr::read_volatile(p as *const u32) == PAINT {
                p += 4;
            }
            ((top - p) as u32, (top - bottom) as u32)
        }
    }
}
