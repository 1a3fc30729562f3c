//! Last-resort handlers: a panic or a HardFault puts the H-bridge in its safe state first,
//! latches the fault in RAM that survives a reset ([`latch`]), then reports (QEMU: exits
//! non-zero through semihosting; board: halts, the IWDG resets, and the next boot finds the
//! latch and waits for a power cycle instead of moving).

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
    latch::set(
        latch::PANIC,
        crate::telemetry::TICKS.load(Ordering::Relaxed),
    );
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

// The HardFault entry. With flip-link a stack overflow runs into the start of RAM, and the
// exception frame itself cannot be stacked: a handler that pushed onto that stack (as
// cortex-m-rt's trampoline + a Rust handler do) would fault again inside HardFault and lock
// the core up with the bridge still driven. So this entry first takes the stacked PC while
// the frame lies in RAM (else reports an overflow), then moves MSP to the top of the stack
// (the handler never returns, so nothing below it is needed) and only then enters Rust.
core::arch::global_asm!(
    ".section .HardFault.user, \"ax\"",
    ".global HardFault",
    ".type HardFault,%function",
    ".thumb_func",
    "HardFault:",
    "    mov r0, lr",
    "    movs r1, #4",
    "    tst r0, r1",
    "    ite eq",
    "    mrseq r0, MSP",
    "    mrsne r0, PSP",
    "    ldr r1, =_stack_end",
    "    cmp r0, r1",
    "    bhs 1f",
    // The frame is below the stack's end: an overflow; no PC to read.
    "    movs r0, #0",
    "    movs r1, #1",
    "    b 2f",
    "1:",
    "    ldr r0, [r0, #24]",
    "    movs r1, #0",
    "2:",
    "    ldr r2, =_stack_start",
    "    msr MSP, r2",
    "    b finger_fw_hard_fault",
    ".ltorg",
    ".size HardFault, . - HardFault",
);

/// The HardFault handler proper, on a fresh stack: `pc` is the faulting instruction's
/// address, or 0 with `overflow` = 1 when the stack overflowed (the frame was never stored).
#[no_mangle]
extern "C" fn finger_fw_hard_fault(pc: u32, overflow: u32) -> ! {
    platform::safe_state();
    let overflow = overflow != 0;
    latch::set(
        if overflow {
            latch::STACK_OVERFLOW
        } else {
            latch::HARDFAULT
        },
        pc,
    );
    if !REPORTING.swap(true, Ordering::SeqCst) {
        if overflow {
            defmt::error!(
                "HARDFAULT stack_overflow=true bridge_safe={=bool}",
                platform::bridge_safe_now()
            );
        } else {
            defmt::error!(
                "HARDFAULT pc={=u32:#x} bridge_safe={=bool}",
                pc,
                platform::bridge_safe_now()
            );
        }
    }
    platform::halt(STATUS_HARDFAULT)
}

/// Fault injection for the test command (`FINGER_FW_INJECT=panic|hardfault|reset|stackoverflow@TICK`
/// at build time; never set in a normal build): checks that the handlers above reach the safe state.
#[inline(always)]
pub fn inject(tick: u32) {
    match crate::config::INJECT {
        Some(("panic", at)) if at == tick => panic!("injected panic at tick {}", tick),
        Some(("reset", at)) if at == tick => {
            // A fault that resets the MCU mid-grasp (as the watchdog does after a halt).
            platform::safe_state();
            latch::set(latch::INJECTED, tick);
            cortex_m::peripheral::SCB::sys_reset();
        }
        Some(("stackoverflow", at)) if at == tick => {
            // Unbounded recursion: the stack runs into the start of RAM (flip-link).
            core::hint::black_box(recurse(0));
        }
        Some(("hardfault", at)) if at == tick => {
            // A read from unmapped memory: BusFault, escalated to HardFault (not enabled).
            // SAFETY: deliberately faulting; the handler never returns.
            let v = unsafe { core::ptr::read_volatile(0xFFFF_FFF0 as *const u32) };
            core::hint::black_box(v);
        }
        _ => {}
    }
}

/// Recursion without a bound the compiler can see (256 bytes of stack per level): the
/// stack-overflow injection.
#[inline(never)]
fn recurse(depth: u32) -> u32 {
    let frame = core::hint::black_box([depth; 64]);
    if core::hint::black_box(depth) == u32::MAX {
        return 0;
    }
    recurse(depth + 1).wrapping_add(frame[(depth % 64) as usize])
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

/// A fault that caused a reset, kept across it: four words in `.uninit` (not zeroed at
/// reset) with a magic number and a checksum, so that RAM's random content after a power-on
/// is not taken for a latch. A power-on (or brown-out) reset clears it.
pub mod latch {
    use core::mem::MaybeUninit;

    const MAGIC: u32 = 0x4C41_5443;
    /// A panic.
    pub const PANIC: u32 = 1;
    /// A HardFault (the second word is its PC).
    pub const HARDFAULT: u32 = 2;
    /// A reset injected by the test command.
    pub const INJECTED: u32 = 3;
    /// A stack overflow (HardFault with the stack below the start of RAM).
    pub const STACK_OVERFLOW: u32 = 4;

    #[link_section = ".uninit.FAULT_LATCH"]
    static mut LATCH: MaybeUninit<[u32; 4]> = MaybeUninit::uninit();

    fn check(code: u32, info: u32) -> u32 {
        MAGIC ^ code.rotate_left(7) ^ info.rotate_left(19) ^ 0xA5A5_5A5A
    }

    fn words() -> *mut u32 {
        // SAFETY: only the address is taken.
        core::ptr::addr_of_mut!(LATCH).cast::<u32>()
    }

    /// At boot: a fault that caused the last reset (a latch, or the watchdog) is reported and
    /// the MCU does not move, waiting for a power cycle with the bridge off (the encoder would
    /// be zeroed wherever the finger stopped). A power-on clears the latch.
    pub fn check_at_boot() {
        let (cause, power_on) = crate::platform::reset_cause();
        let latched = get();
        let (code, info) = latched.unwrap_or((0, 0));
        defmt::info!(
            "RESET cause={=str} latched_code={=u32} latched_info={=u32}",
            cause,
            code,
            info
        );
        if power_on {
            clear();
        } else if latched.is_some() || cause == "independent_watchdog" {
            defmt::error!(
                "LATCHED fault (code {=u32}) from before the {=str} reset: bridge off, waiting for a power cycle",
                code,
                cause
            );
            crate::platform::wait_latched();
        }
    }

    /// Latches a fault (code, tick or PC).
    pub fn set(code: u32, info: u32) {
        let w = words();
        // SAFETY: four words of a static reserved for this; volatile so the stores happen
        // before a reset.
        unsafe {
            w.write_volatile(MAGIC);
            w.add(1).write_volatile(code);
            w.add(2).write_volatile(info);
            w.add(3).write_volatile(check(code, info));
        }
    }

    /// The latched fault, if the four words hold a valid one.
    pub fn get() -> Option<(u32, u32)> {
        let w = words();
        // SAFETY: reads of the same four words (whatever they hold, every bit pattern is a
        // valid u32).
        let [m, code, info, c] = unsafe {
            [
                w.read_volatile(),
                w.add(1).read_volatile(),
                w.add(2).read_volatile(),
                w.add(3).read_volatile(),
            ]
        };
        (m == MAGIC && c == check(code, info)).then_some((code, info))
    }

    /// Clears the latch (a power cycle: the operator's acknowledgement).
    pub fn clear() {
        // SAFETY: as in `set`.
        unsafe { words().write_volatile(0) }
    }
}
