//! The simulated board for QEMU (mps2-an386): the finger plant runs inside the firmware.
//!
//! The sampling task is driven by SysTick. Each period the controller reads the plant's
//! encoder and ADC codes, sets a duty, and the plant is advanced by one control period of
//! *simulated* time. A plant step costs far more instructions than the real loop (the M4 FPU is
//! single precision, the plant is f64), so SysTick is restarted at the end of every sample:
//! the next sample comes one full period after this one ends, which leaves the lower-priority
//! tasks their share however long the plant takes. Wall time never enters the simulation.

pub mod pac;

use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::{syst::SystClkSource, SCB, SYST};

use crate::ctl::{Hardware, DUTY_MAX};

/// SysTick reload: 25 MHz processor clock of the AN386 image / 25 000 = 1 ms of QEMU virtual time
/// between the end of one sample and the next (simulated time is the plant's own clock).
const SYSTICK_RELOAD: u32 = 25_000 - 1;

/// Set by [`safe_state`]; once set the plant sees zero duty whatever the controller asks.
static BRIDGE_SAFE: AtomicBool = AtomicBool::new(false);

/// The simulated board.
pub struct SimBoard {
    plant: crate::ctl::Plant,
    duty: i16,
    bridge_off: bool,
}

impl SimBoard {
    /// The plant of the scene chosen at build time.
    pub fn new() -> Self {
        Self {
            plant: crate::ctl::new_plant(),
            duty: 0,
            bridge_off: false,
        }
    }

    /// Advances the plant by one control period with the duty last set.
    pub fn advance(&mut self) {
        let off = self.bridge_off || BRIDGE_SAFE.load(Ordering::Relaxed);
        let duty = if off {
            0.0
        } else {
            f64::from(self.duty) / f64::from(DUTY_MAX)
        };
        self.plant.step(duty);
    }

    /// True once the bridge was switched off.
    pub fn is_safe(&self) -> bool {
        self.bridge_off || BRIDGE_SAFE.load(Ordering::Relaxed)
    }
}

impl Hardware for SimBoard {
    fn encoder_count(&mut self) -> u16 {
        self.plant.encoder_count()
    }
    fn current_raw(&mut self) -> u16 {
        self.plant.current_adc()
    }
    fn set_duty(&mut self, duty: i16) {
        self.duty = duty.clamp(-DUTY_MAX, DUTY_MAX);
    }
    fn bridge_off(&mut self) {
        self.duty = 0;
        self.bridge_off = true;
    }
}

/// SysTick stands for the board's PWM timer + ADC: it pends the `ADC` line the sampling task
/// is bound to.
#[cortex_m_rt::exception]
fn SysTick() {
    cortex_m::peripheral::NVIC::pend(pac::Interrupt::ADC);
}

/// Starts the sampling interrupt (SysTick).
pub fn start_sampling(mut syst: SYST) {
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
}

/// Bridge to the safe state from any context (panic, HardFault): the plant sees zero duty.
pub fn safe_state() {
    BRIDGE_SAFE.store(true, Ordering::SeqCst);
}

/// Ends the QEMU run with this status (semihosting SYS_EXIT_EXTENDED).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

/// Name of this board in the log.
pub const NAME: &str = "qemu-mps2-an386";

/// The board: the simulated plant.
pub type Board = SimBoard;

/// Brings up the simulated board and starts the sampling interrupt.
pub fn init(core: rtic::export::Peripherals) -> Board {
    start_sampling(core.SYST);
    SimBoard::new()
}

impl SimBoard {
    /// Nothing to acknowledge: SysTick clears itself.
    pub fn ack_sample(&mut self) {}

    /// The plant's true θa (µrad).
    pub fn truth_theta_a_urad(&mut self) -> i32 {
        (self.plant.theta_a() * 1e6) as i32
    }
}

/// Stops the sampling interrupt (the run is over).
pub fn stop_sampling() {
    // SAFETY: clears SysTick's enable bits; no other user.
    unsafe { (*SYST::PTR).csr.write(0) };
}

/// End of the run: exit QEMU with the firmware's status.
pub fn finish(status: i32) -> ! {
    exit(status)
}

/// After a panic or HardFault (bridge already safe): exit QEMU with this status.
pub fn halt(status: i32) -> ! {
    exit(status)
}
