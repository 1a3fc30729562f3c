//! The real board: STM32F411CEU6 "Black Pill" (25 MHz HSE, core at [`SYSCLK_HZ`]), RE10 motor with a
//! quadrature encoder, DRV8871 H-bridge, shunt + amplifier on an ADC input. The only module
//! of the workspace that touches registers.
//!
//! | signal                    | pin  | peripheral                     | notes                              |
//! |---------------------------|------|--------------------------------|------------------------------------|
//! | encoder A                 | PB6  | TIM4_CH1 (AF2), encoder mode ×4 | 5 V-tolerant (FT) input            |
//! | encoder B                 | PB7  | TIM4_CH2 (AF2)                 |                                    |
//! | DRV8871 IN1 (flex)        | PA8  | TIM1_CH1 (AF1), 20 kHz centre-aligned PWM | 10 kΩ pull-down on the board |
//! | DRV8871 IN2 (extend)      | PA9  | TIM1_CH2 (AF1)                 | 10 kΩ pull-down                    |
//! | shunt amplifier output    | PA4  | ADC1_IN4, injected, TIM1_TRGO  | mid-scale (1.65 V) at 0 A          |
//! | watchdog                  | —    | IWDG, 10 ms                    | started at the end of init; fed by the sampling task while the supervisor checks in |
//! | USB D− / D+ (device mode) | PA11 / PA12 | OTG_FS (AF10), CDC-ACM [`usb`] | the Black Pill's USB-C socket |
//!
//! Clocks: the core runs at 100 MHz, or at 96 MHz in device mode, where the OTG FS block needs
//! an exact 48 MHz: from the 25 MHz HSE the one PLL makes both 96 and 48 MHz (VCO 384 MHz,
//! P = 4, Q = 8) but no 100 MHz together with 48 MHz (100·P = 48·Q has no solution for the
//! even P ≤ 8 the PLL allows). Every timer constant below derives from [`SYSCLK_HZ`].
//!
//! Timing: TIM1 runs centre-aligned at 20 kHz (ARR = [`PWM_ARR`]); its repetition counter
//! (RCR = 3 for the controller's dt = 100 µs) makes an update event every second PWM period, at the counter underflow, i.e. in
//! the middle of the active pulse, away from the switching edges. The update is TIM1_TRGO,
//! which starts the injected ADC conversion; its end (JEOC) raises the ADC interrupt: the
//! sampling task at 10 kHz, with the current sampled in step with the PWM.

#[cfg(feature = "device")]
pub mod usb;

use core::sync::atomic::{AtomicBool, Ordering};

use grasp::{Hardware, DUTY_MAX};
use stm32f4xx_hal::{
    pac,
    prelude::*,
    rcc::{self, Enable, Reset},
    watchdog::IndependentWatchdog,
};

use crate::bridge_regs::{is_safe, safe_sequence, Reg, Regs};
use crate::telemetry::{PlantEvent, Truth};

/// Name of this board in the log.
pub const NAME: &str = "stm32f411ceu6";

/// Core clock (Hz): 96 MHz in device mode (the USB clock needs the PLL's 48 MHz output
/// exact), 100 MHz (the part's maximum) otherwise. TIM1 runs at this rate (APB2 undivided).
#[cfg(feature = "device")]
pub const SYSCLK_HZ: u32 = 96_000_000;
/// Core clock (Hz): 96 MHz in device mode (the USB clock needs the PLL's 48 MHz output
/// exact), 100 MHz (the part's maximum) otherwise. TIM1 runs at this rate (APB2 undivided).
#[cfg(not(feature = "device"))]
pub const SYSCLK_HZ: u32 = 100_000_000;

/// PWM frequency (Hz).
const PWM_HZ: f64 = 20_000.0;
/// PWM period in timer ticks, centre-aligned (counts up then down): SYSCLK / (2 × 20 kHz),
/// 2500 at 100 MHz, 2400 at 96 MHz.
pub const PWM_ARR: u32 = SYSCLK_HZ / (2 * PWM_HZ as u32);
// The PWM frequency is exact at either clock (the ARR is a whole number of ticks).
const _: () = assert!(PWM_ARR * 2 * PWM_HZ as u32 == SYSCLK_HZ);

/// Repetition counter for one update (→ ADC trigger → sampling task) per control period:
/// RCR + 1 half PWM periods. 10 kHz (dt = 100 µs) → 4 half periods → RCR = 3. An odd RCR
/// keeps every update on the same (underflow) extremum.
fn pwm_rcr(dt_s: f64) -> u32 {
    let half_periods = (dt_s * 2.0 * PWM_HZ + 0.5) as u32;
    let rcr = half_periods.clamp(2, 256) - 1;
    rcr | 1
}

/// Latched by [`safe_state`].
static BRIDGE_SAFE: AtomicBool = AtomicBool::new(false);

/// The board's drivers.
pub struct Board {
    adc_code: u16,
    /// The last encoder count handed to the controller (for telemetry).
    last_count: u16,
    off: bool,
    wdg: IndependentWatchdog,
    /// Cycle stamp when the watchdog was started.
    wdg_start: u32,
}

/// Why the MCU last reset, from RCC_CSR (the flags are cleared for the next boot). `true`
/// with it when the reset was a power-on or brown-out (RAM content is then meaningless).
pub fn reset_cause() -> (&'static str, bool) {
    // SAFETY: a read of RCC_CSR and a write of its RMVF bit (clears the reset flags only).
    let rcc = unsafe { &*pac::RCC::ptr() };
    let csr = rcc.csr().read().bits();
    rcc.csr()
        .modify(|r, w| unsafe { w.bits(r.bits() | (1 << 24)) });
    let cause = if csr & (1 << 25) != 0 {
        "brown_out"
    } else if csr & (1 << 27) != 0 {
        "power_on"
    } else if csr & (1 << 29) != 0 {
        "independent_watchdog"
    } else if csr & (1 << 30) != 0 {
        "window_watchdog"
    } else if csr & (1 << 28) != 0 {
        "software"
    } else if csr & (1 << 31) != 0 {
        "low_power"
    } else if csr & (1 << 26) != 0 {
        "pin"
    } else {
        "unknown"
    };
    (cause, csr & ((1 << 25) | (1 << 27)) != 0)
}

/// After a latched fault: bridge safe, nothing runs; the MCU waits for a power cycle.
pub fn wait_latched() -> ! {
    safe_state();
    loop {
        cortex_m::asm::wfi();
    }
}

/// Clocks, pins, PWM, encoder timer, ADC and watchdog; the first sample interrupt comes one
/// control period later.
#[cfg(not(feature = "device"))]
pub fn init(
    core: rtic::export::Peripherals,
    dp: pac::Peripherals,
) -> (Board, grasp::ControllerConfig) {
    let (board, cfg, ()) = setup(core, dp);
    (board, cfg)
}

/// Device mode: as the power-up build's `init`, plus the OTG FS block and its pins for the
/// host link ([`usb::init`]), the PLL's 48 MHz output checked.
#[cfg(feature = "device")]
pub fn init(
    core: rtic::export::Peripherals,
    dp: pac::Peripherals,
) -> (Board, grasp::ControllerConfig, stm32f4xx_hal::otg_fs::USB) {
    setup(core, dp)
}

/// What `setup` hands on besides the drivers: the USB block in device mode.
#[cfg(feature = "device")]
type Spare = stm32f4xx_hal::otg_fs::USB;
/// What `setup` hands on besides the drivers: nothing without device mode.
#[cfg(not(feature = "device"))]
type Spare = ();

fn setup(
    mut core: rtic::export::Peripherals,
    dp: pac::Peripherals,
) -> (Board, grasp::ControllerConfig, Spare) {
    // APB1 at its 50 MHz maximum or below, APB2 (TIM1, ADC) at the core clock.
    let clocks = rcc::Config::hse(25.MHz())
        .sysclk(SYSCLK_HZ.Hz())
        .pclk1((SYSCLK_HZ / 2).Hz())
        .pclk2(SYSCLK_HZ.Hz());
    // The HAL asserts (at init, before anything drives) that the 48 MHz clock is within the
    // USB specification's ±0.25 %; with 96 MHz it is exact (see the module doc).
    #[cfg(feature = "device")]
    let clocks = clocks.require_pll48clk();
    let mut rcc = dp.RCC.freeze(clocks);

    // Cycle counter for the work measurements.
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();

    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let _in1 = gpioa.pa8.into_alternate::<1>();
    let _in2 = gpioa.pa9.into_alternate::<1>();
    let _ia = gpioa.pa4.into_analog();
    let _enc_a = gpiob.pb6.into_alternate::<2>();
    let _enc_b = gpiob.pb7.into_alternate::<2>();

    pac::TIM1::enable(&mut rcc);
    pac::TIM1::reset(&mut rcc);
    pac::TIM4::enable(&mut rcc);
    pac::TIM4::reset(&mut rcc);
    pac::ADC1::enable(&mut rcc);
    pac::ADC1::reset(&mut rcc);

    // SAFETY (all register blocks below): this function owns the peripherals (taken from
    // `dp`); bit patterns follow RM0383.
    let tim4 = dp.TIM4;
    unsafe {
        // Encoder mode 3 (count on both edges of both inputs: ×4), inputs TI1/TI2 with an
        // 8-sample filter, full 16-bit range. Zero at power-up: the finger must be at rest.
        tim4.ccmr1_input()
            .write(|w| w.bits((0b01) | (0b0011 << 4) | (0b01 << 8) | (0b0011 << 12)));
        tim4.ccer().write(|w| w.bits(0));
        tim4.smcr().write(|w| w.bits(0b011));
        tim4.arr().write(|w| w.bits(0xFFFF));
        tim4.cnt().write(|w| w.bits(0));
        tim4.cr1().write(|w| w.bits(1));
    }

    let adc = dp.ADC1;
    unsafe {
        // ADC clock = PCLK2 / 4 = 25 MHz (24 MHz in device mode); one injected conversion of IN4 (JL = 0 → JSQ4),
        // 28-cycle sampling, triggered by TIM1_TRGO (JEXTSEL = 0001) on the rising edge,
        // interrupt at the end of the injected conversion.
        dp.ADC_COMMON.ccr().write(|w| w.bits(0b01 << 16));
        adc.smpr2().write(|w| w.bits(0b010 << 12));
        adc.jsqr().write(|w| w.bits(4 << 15));
        adc.cr1().write(|w| w.bits(1 << 7));
        adc.cr2()
            .write(|w| w.bits(1 | (0b0001 << 16) | (0b01 << 20)));
    }

    let drive = crate::ctl::board_drive();
    let rcr = pwm_rcr(drive.dt_s);
    let tim1 = dp.TIM1;
    unsafe {
        // 20 kHz centre-aligned PWM on CH1/CH2 (PWM mode 1, preload), both outputs low,
        // update every second period → TRGO → ADC.
        tim1.psc().write(|w| w.bits(0));
        tim1.arr().write(|w| w.bits(PWM_ARR));
        tim1.rcr().write(|w| w.bits(rcr));
        tim1.ccr1().write(|w| w.bits(0));
        tim1.ccr2().write(|w| w.bits(0));
        tim1.ccmr1_output()
            .write(|w| w.bits((0b110 << 4) | (1 << 3) | (0b110 << 12) | (1 << 11)));
        tim1.ccer().write(|w| w.bits(1 | (1 << 4)));
        tim1.cr2().write(|w| w.bits(0b010 << 4));
        tim1.bdtr().write(|w| w.bits(1 << 15));
        tim1.egr().write(|w| w.bits(1));
        tim1.cr1().write(|w| w.bits(1 | (0b01 << 5) | (1 << 7)));
    }

    // Started by `start_watchdog` at the end of init, after the long work there.
    let wdg = IndependentWatchdog::new(dp.IWDG);

    #[cfg(feature = "device")]
    let spare = stm32f4xx_hal::otg_fs::USB::new(
        (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        (gpioa.pa11, gpioa.pa12),
        &rcc.clocks,
    );
    #[cfg(not(feature = "device"))]
    let spare = ();

    (
        Board {
            adc_code: 2048,
            last_count: 0,
            off: true,
            wdg,
            wdg_start: 0,
        },
        crate::ctl::config(drive),
        spare,
    )
}

impl Board {
    /// The encoder count and ADC code the controller read last.
    pub fn raw(&self) -> (u16, u16) {
        (self.last_count, self.adc_code)
    }

    /// Acknowledges the end of the injected conversion and latches the current sample.
    pub fn ack_sample(&mut self) {
        // SAFETY: the sampling task is the only user of ADC1 after init; reading JDR1 and
        // clearing JEOC (write 0 to bit 2, 1 elsewhere: rc_w0 bits).
        let adc = unsafe { &*pac::ADC1::ptr() };
        self.adc_code = (adc.jdr1().read().bits() & 0x0FFF) as u16;
        adc.sr().write(|w| unsafe { w.bits(!(1 << 2)) });
    }

    /// End of the control period: nothing to advance on the real board.
    pub fn advance(&mut self) {}

    /// Starts the IWDG (10 ms nominal, 6.8–18.8 ms over the LSI's tolerance); it cannot be
    /// stopped again.
    pub fn start_watchdog(&mut self) {
        self.wdg.start(10.millis());
        self.wdg_start = stamp();
    }

    /// Feeds the IWDG.
    pub fn feed_watchdog(&mut self) {
        self.wdg.feed();
    }

    /// Cycle stamps since the watchdog was started.
    pub fn watchdog_age(&self) -> u32 {
        stamp().wrapping_sub(self.wdg_start)
    }

    /// True when the bridge is off.
    pub fn is_safe(&self) -> bool {
        self.off || BRIDGE_SAFE.load(Ordering::Relaxed)
    }

    /// No ground truth on the real finger.
    pub fn truth(&self, _at: &'static str) -> Option<Truth> {
        None
    }

    /// No plant events on the real finger.
    pub fn poll_plant_event(&mut self) -> Option<PlantEvent> {
        None
    }
}

fn tim1() -> &'static pac::tim1::RegisterBlock {
    // SAFETY: TIM1 is only written by the sampling task (duty) and by `safe_state`, which
    // writes values that are safe whatever the interleaving (zeros, MOE off).
    unsafe { &*pac::TIM1::ptr() }
}

impl Hardware for Board {
    fn encoder_count(&mut self) -> u16 {
        // SAFETY: read of TIM4's counter.
        self.last_count = (unsafe { &*pac::TIM4::ptr() }.cnt().read().bits() & 0xFFFF) as u16;
        self.last_count
    }
    fn current_raw(&mut self) -> u16 {
        self.adc_code
    }
    fn set_duty(&mut self, duty: i16) {
        if BRIDGE_SAFE.load(Ordering::Relaxed) {
            return;
        }
        let d = i32::from(duty.clamp(-DUTY_MAX, DUTY_MAX));
        let ticks = (d.unsigned_abs() * PWM_ARR) / DUTY_MAX as u32;
        let (c1, c2) = if d >= 0 { (ticks, 0) } else { (0, ticks) };
        let t = tim1();
        // SAFETY: compare values within ARR.
        unsafe {
            t.ccr1().write(|w| w.bits(c1));
            t.ccr2().write(|w| w.bits(c2));
        }
        self.off = false;
    }
    fn bridge_off(&mut self) {
        let t = tim1();
        // SAFETY: both inputs low = DRV8871 coast (all switches off).
        unsafe {
            t.ccr1().write(|w| w.bits(0));
            t.ccr2().write(|w| w.bits(0));
        }
        self.off = true;
    }
}

/// Device mode's link to the host: USB CDC-ACM.
#[cfg(feature = "device")]
pub const LINK_NAME: &str = "USB CDC-ACM";

/// Static storage device mode's link borrows for the whole run (an RTIC init-local).
#[cfg(feature = "device")]
pub use usb::Storage as LinkStore;

/// Device mode's link to the host on the OTG FS block `usb` from [`init`].
#[cfg(feature = "device")]
pub fn open_link(
    store: &'static mut LinkStore,
    usb: stm32f4xx_hal::otg_fs::USB,
) -> crate::device::Link {
    usb::init(store, usb)
}

/// Nothing to re-arm: the timer triggers the next conversion by itself.
pub fn rearm_sampling() {}

/// CPU cycles (DWT).
#[inline(always)]
pub fn stamp() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// The TIM1 and GPIOA registers of the safe-state sequence, through the PAC.
struct Mmio;

impl Regs for Mmio {
    fn read(&mut self, r: Reg) -> u32 {
        // SAFETY: register reads.
        unsafe {
            let t = &*pac::TIM1::ptr();
            let a = &*pac::GPIOA::ptr();
            match r {
                Reg::Tim1Ccr1 => t.ccr1().read().bits(),
                Reg::Tim1Ccr2 => t.ccr2().read().bits(),
                Reg::Tim1Bdtr => t.bdtr().read().bits(),
                Reg::GpioaModer => a.moder().read().bits(),
                Reg::GpioaOdr => a.odr().read().bits(),
                // Write-only: reads as zero.
                Reg::GpioaBsrr => 0,
            }
        }
    }
    fn write(&mut self, r: Reg, v: u32) {
        // SAFETY: the safe-state sequence only ever switches the bridge off.
        unsafe {
            let t = &*pac::TIM1::ptr();
            let a = &*pac::GPIOA::ptr();
            match r {
                Reg::Tim1Ccr1 => {
                    t.ccr1().write(|w| w.bits(v));
                }
                Reg::Tim1Ccr2 => {
                    t.ccr2().write(|w| w.bits(v));
                }
                Reg::Tim1Bdtr => {
                    t.bdtr().write(|w| w.bits(v));
                }
                Reg::GpioaModer => {
                    a.moder().write(|w| w.bits(v));
                }
                Reg::GpioaOdr => {
                    a.odr().write(|w| w.bits(v));
                }
                Reg::GpioaBsrr => {
                    a.bsrr().write(|w| w.bits(v));
                }
            }
        }
    }
}

/// Bridge to the safe state from any context (panic, HardFault, refused configuration): both
/// compare values zero, main output off, and the two pins forced to GPIO outputs driven low,
/// so the DRV8871 coasts even if the timer state is corrupt (`bridge_regs::safe_sequence`, the
/// sequence the host tests run against a register-level fake).
pub fn safe_state() {
    BRIDGE_SAFE.store(true, Ordering::SeqCst);
    safe_sequence(&mut Mmio);
}

/// Whether the bridge is off, read back from the hardware: TIM1 main output disabled and both
/// pins GPIO outputs driven low.
pub fn bridge_safe_now() -> bool {
    is_safe(&mut Mmio)
}

/// End of a grasp on the real board: keep running (holding, or safe), nothing to exit to.
pub fn finish(_status: i32) {}

/// After a panic or HardFault (bridge already safe): stop here. The watchdog is no longer
/// fed, so the MCU resets after ≤ 10 ms and restarts with the bridge off (calibration).
pub fn halt(_status: i32) -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}
