//! The simulated board for QEMU (mps2-an386): the finger plant (crates/plant) runs inside the
//! firmware and stands in for the motor, the encoder and the current ADC.
//!
//! SysTick plays the PWM timer + ADC of the real board: it pends the `ADC` line the sampling
//! task is bound to. Each period the controller reads the plant's encoder and ADC codes and
//! sets a duty, then the plant is advanced by one control period of *simulated* time
//! (`scene.dt_s`). A plant step costs far more than the real loop (the M4 FPU is single
//! precision, the plant is f64), so SysTick is restarted at the end of every sample: the next
//! one comes a full period after this one ends, which leaves the lower-priority tasks their
//! share however long the plant takes. Wall time never enters the simulation.
//!
//! CMSDK APB TIMER0 (0x4000_0000) runs free as the cycle stamp for the work measurements: with
//! `qemu-system-arm -icount shift=0` one 25 MHz tick is exactly 40 instructions.

pub mod pac;

use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::{syst::SystClkSource, SCB, SYST};

use grasp::Hardware;

use crate::telemetry::{PlantEvent, Truth};

/// Name of this board in the log.
pub const NAME: &str = "qemu-mps2-an386";

/// SysTick reload: 250 ticks of the 25 MHz clock = 10 000 instructions at `-icount shift=0`
/// between the end of one sample and the next: what a 100 MHz MCU has per 10 kHz period. The
/// lower priorities (estimate, telemetry) thus get about the share of CPU they get on the
/// board, so the estimate arrives a realistic number of control ticks after the request.
/// Simulated time is the plant's own clock and is not affected.
const SYSTICK_RELOAD: u32 = 250 - 1;

/// CMSDK APB timer 0 registers (CTRL, VALUE, RELOAD).
const TIMER0_CTRL: *mut u32 = 0x4000_0000 as *mut u32;
const TIMER0_VALUE: *mut u32 = 0x4000_0004 as *mut u32;
const TIMER0_RELOAD: *mut u32 = 0x4000_0008 as *mut u32;

/// Set by [`safe_state`]; once set the plant sees the bridge off whatever the controller asks.
static BRIDGE_SAFE: AtomicBool = AtomicBool::new(false);

/// The board: the simulated plant.
pub type Board = SimBoard;

/// The simulated board.
pub struct SimBoard {
    /// The plant behind grasp's Hardware trait (the adapter the host runs use too).
    hw: sim_board::PlantBoard,
    /// Work stamp when the (modelled) watchdog was started.
    wdg_start: u32,
    /// The last encoder count and ADC code handed to the controller (for telemetry).
    raw: (u16, u16),
}

/// Brings up the simulated board for the build's scene and starts the sampling interrupt.
pub fn init(core: rtic::export::Peripherals) -> (Board, grasp::ControllerConfig) {
    let Some(scene) = crate::ctl::scene() else {
        defmt::error!("SCENE {=str} unknown", crate::config::SCENE);
        exit(3)
    };
    let plant = match plant::Plant::new(&scene) {
        Ok(p) => p,
        Err(_) => {
            defmt::error!("SCENE {=str} does not build a plant", crate::config::SCENE);
            exit(3)
        }
    };
    // SAFETY: TIMER0 is not used by anything else; free-running down-counter from 2³²−1.
    unsafe {
        TIMER0_RELOAD.write_volatile(u32::MAX);
        TIMER0_VALUE.write_volatile(u32::MAX);
        TIMER0_CTRL.write_volatile(1);
    }
    start_sampling(core.SYST);
    let cfg = crate::ctl::with_scene_rest_check(
        crate::ctl::config(crate::ctl::scene_drive(&scene)),
        &scene,
    );
    (
        SimBoard {
            hw: sim_board::PlantBoard::new(plant),
            wdg_start: 0,
            raw: (0, 0),
        },
        cfg,
    )
}

impl SimBoard {
    /// QEMU's mps2-an386 has no watchdog: the start is recorded so the window to the first
    /// feed can be measured (`WDG` line) against the board's timeout.
    pub fn start_watchdog(&mut self) {
        self.wdg_start = stamp();
    }

    /// No watchdog to feed on QEMU.
    pub fn feed_watchdog(&mut self) {}

    /// Work stamps since [`SimBoard::start_watchdog`].
    pub fn watchdog_age(&self) -> u32 {
        stamp().wrapping_sub(self.wdg_start)
    }

    /// A fresh plant (device mode: the scene the host selected, the finger back at its rest
    /// pose for the next grasp); the bridge starts off.
    #[cfg(feature = "device")]
    pub fn reset_plant(&mut self, plant: plant::Plant) {
        self.hw = sim_board::PlantBoard::new(plant);
    }

    /// The encoder count and ADC code the controller read last.
    pub fn raw(&self) -> (u16, u16) {
        self.raw
    }

    /// Nothing to acknowledge: SysTick pended the line.
    pub fn ack_sample(&mut self) {}

    /// Advances the plant by one control period with what the controller commanded.
    pub fn advance(&mut self) {
        if BRIDGE_SAFE.load(Ordering::Relaxed) {
            // A panic or HardFault made the bridge safe behind the controller's back.
            self.hw.bridge_off();
        }
        self.hw.advance();
    }

    /// True when the bridge is off.
    pub fn is_safe(&self) -> bool {
        self.hw.is_off() || BRIDGE_SAFE.load(Ordering::Relaxed)
    }

    /// The plant's truth now.
    pub fn truth(&self, at: &'static str) -> Option<Truth> {
        Some(Truth::of(&self.hw.plant, at))
    }

    /// The next plant event (first contact, loss, second contact, joint limit, ...).
    pub fn poll_plant_event(&mut self) -> Option<PlantEvent> {
        self.hw.plant.poll_event().map(|e| PlantEvent::of(&e))
    }
}

impl Hardware for SimBoard {
    fn encoder_count(&mut self) -> u16 {
        self.raw.0 = self.hw.encoder_count();
        self.raw.0
    }
    fn current_raw(&mut self) -> u16 {
        self.raw.1 = self.hw.current_raw();
        self.raw.1
    }
    fn set_duty(&mut self, duty: i16) {
        self.hw.set_duty(duty);
    }
    fn bridge_off(&mut self) {
        self.hw.bridge_off();
    }
}

/// SysTick stands for the board's PWM timer + ADC: it pends the `ADC` line the sampling task
/// is bound to.
#[cortex_m_rt::exception]
fn SysTick() {
    cortex_m::peripheral::NVIC::pend(pac::Interrupt::ADC);
}

fn start_sampling(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYSTICK_RELOAD);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    // From here on SysTick is only touched through its registers (rearm/stop below).
}

/// Called at the end of every sample: restart the SysTick period and drop a tick that became
/// pending while the plant was stepping, so the next sample is one full period away.
pub fn rearm_sampling() {
    // SAFETY: single writes to SysTick's current-value register and to ICSR.PENDSTCLR; the
    // sampling task is the only user of SysTick after init.
    unsafe {
        (*SYST::PTR).cvr.write(0);
        (*SCB::PTR).icsr.write(1 << 25);
    }
    cortex_m::peripheral::NVIC::unpend(pac::Interrupt::ADC);
}

/// Device mode's link to the host: the CMSDK UART0 (QEMU's first `-serial`).
#[cfg(feature = "device")]
pub const LINK_NAME: &str = "UART0";

/// Static storage device mode's link borrows (an RTIC init-local): none for the UART.
#[cfg(feature = "device")]
pub struct LinkStore;

#[cfg(feature = "device")]
impl LinkStore {
    /// The (empty) storage.
    pub const fn new() -> Self {
        LinkStore
    }
}

/// Device mode's link to the host: UART0, its receive interrupt on.
#[cfg(feature = "device")]
pub fn open_link(_store: &'static mut LinkStore) -> crate::device::Link {
    crate::device::uart::init()
}

/// Why the MCU last reset: QEMU has no reset flags. A fresh QEMU start is a power-on; a reset
/// from inside the run (SYSRESETREQ) keeps RAM, which the latch's checksum tells apart.
pub fn reset_cause() -> (&'static str, bool) {
    if crate::fault::latch::get().is_some() {
        ("software", false)
    } else {
        ("power_on", true)
    }
}

/// After a latched fault: bridge safe; QEMU exits with [`STATUS_LATCHED`] (the board waits
/// for a power cycle).
pub fn wait_latched() -> ! {
    safe_state();
    exit(STATUS_LATCHED)
}

/// Exit status of a boot that found a latched fault and did not move.
pub const STATUS_LATCHED: i32 = 5;

/// A free-running cycle stamp (TIMER0 ticks, 40 instructions each at `-icount shift=0`).
#[inline(always)]
pub fn stamp() -> u32 {
    // SAFETY: read of a timer value register.
    !unsafe { TIMER0_VALUE.read_volatile() }
}

/// Bridge to the safe state from any context (panic, HardFault): the plant sees it off.
pub fn safe_state() {
    BRIDGE_SAFE.store(true, Ordering::SeqCst);
}

/// Whether the bridge is latched off (read back, for the fault reports).
pub fn bridge_safe_now() -> bool {
    BRIDGE_SAFE.load(Ordering::SeqCst)
}

/// End of the run: exit QEMU with the firmware's status.
pub fn finish(status: i32) -> ! {
    exit(status)
}

/// After a panic or HardFault (bridge already safe): exit QEMU with this status.
pub fn halt(status: i32) -> ! {
    exit(status)
}

/// Ends the QEMU run with this status (semihosting SYS_EXIT_EXTENDED).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}
