//! The board's safe-state register sequence, written once against a register-access trait so
//! that the very code the board runs (through the PAC, `board::Mmio`) also runs in a host test
//! against a register-level fake of the blocks it touches.
//!
//! What the sequence must leave (STM32F411 reference manual RM0383):
//! * TIM1 CCR1 = CCR2 = 0: no pulse on either channel even if the timer keeps running;
//! * TIM1 BDTR.MOE (bit 15) = 0: the timer's outputs disabled (OCx pins then follow their idle
//!   state, low here, and the pins are no longer the timer's anyway, below);
//! * GPIOA PA8 and PA9 (DRV8871 IN1/IN2) as general-purpose outputs (MODER field `01`), driven
//!   low (BSRR reset bits 24 and 25, ODR bits 8 and 9 clear): both inputs low is the DRV8871's
//!   coast state, all switches off, whatever the timer does;
//! * every other pin's mode unchanged (PA4 analog for the current sense, PA13/PA14 SWD).

/// The registers the sequence touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reg {
    /// TIM1 capture/compare 1 (IN1 duty).
    Tim1Ccr1,
    /// TIM1 capture/compare 2 (IN2 duty).
    Tim1Ccr2,
    /// TIM1 break and dead-time register (MOE is bit 15).
    Tim1Bdtr,
    /// GPIOA mode register (2 bits per pin).
    GpioaModer,
    /// GPIOA output data register (read back).
    GpioaOdr,
    /// GPIOA bit set/reset register (write only: bits 0–15 set, 16–31 reset).
    GpioaBsrr,
}

/// Access to the registers: the board's memory-mapped blocks, or a test's fake.
pub trait Regs {
    /// Reads a register.
    fn read(&mut self, r: Reg) -> u32;
    /// Writes a register.
    fn write(&mut self, r: Reg, v: u32);
}

/// MOE: main output enable of an advanced timer (BDTR bit 15).
pub const BDTR_MOE: u32 = 1 << 15;
/// The bridge's input pins on GPIOA: PA8 (IN1), PA9 (IN2).
pub const PINS: [u32; 2] = [8, 9];

/// Bridge to the safe state: compare values zero, main output off, then both pins taken from
/// the timer as GPIO outputs driven low (the output level is set before the mode changes, so
/// the pins never drive high in between).
pub fn safe_sequence(r: &mut impl Regs) {
    r.write(Reg::Tim1Ccr1, 0);
    r.write(Reg::Tim1Ccr2, 0);
    r.write(Reg::Tim1Bdtr, 0);
    let reset = PINS.iter().fold(0, |m, p| m | 1 << (p + 16));
    r.write(Reg::GpioaBsrr, reset);
    let field = PINS.iter().fold(0, |m, p| m | 0b11 << (2 * p));
    let output = PINS.iter().fold(0, |m, p| m | 0b01 << (2 * p));
    let moder = r.read(Reg::GpioaModer);
    r.write(Reg::GpioaModer, (moder & !field) | output);
}

/// Whether the registers show the bridge safe: MOE clear, both pins GPIO outputs, both low.
pub fn is_safe(r: &mut impl Regs) -> bool {
    let moe_off = r.read(Reg::Tim1Bdtr) & BDTR_MOE == 0;
    let moder = r.read(Reg::GpioaModer);
    let odr = r.read(Reg::GpioaOdr);
    moe_off
        && PINS
            .iter()
            .all(|p| (moder >> (2 * p)) & 0b11 == 0b01 && odr & (1 << p) == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A register-level fake of the TIM1 and GPIOA registers the sequence uses, with the
    /// hardware's semantics written from the reference manual: BSRR is write-only and acts on
    /// ODR (set bits 0–15, reset bits 16–31, set wins when both are written), a pin's level
    /// is ODR when its mode is output and the timer's output when it is alternate function
    /// with MOE set (a pulse while CCRx > 0).
    #[derive(Debug, Default)]
    struct Fake {
        ccr1: u32,
        ccr2: u32,
        bdtr: u32,
        moder: u32,
        odr: u32,
        writes: Vec<(Reg, u32)>,
    }

    impl Regs for Fake {
        fn read(&mut self, r: Reg) -> u32 {
            match r {
                Reg::Tim1Ccr1 => self.ccr1,
                Reg::Tim1Ccr2 => self.ccr2,
                Reg::Tim1Bdtr => self.bdtr,
                Reg::GpioaModer => self.moder,
                Reg::GpioaOdr => self.odr,
                Reg::GpioaBsrr => 0,
            }
        }
        fn write(&mut self, r: Reg, v: u32) {
            self.writes.push((r, v));
            match r {
                Reg::Tim1Ccr1 => self.ccr1 = v & 0xFFFF,
                Reg::Tim1Ccr2 => self.ccr2 = v & 0xFFFF,
                Reg::Tim1Bdtr => self.bdtr = v,
                Reg::GpioaModer => self.moder = v,
                Reg::GpioaOdr => self.odr = v & 0xFFFF,
                Reg::GpioaBsrr => {
                    let set = v & 0xFFFF;
                    let reset = v >> 16;
                    self.odr = (self.odr & !reset) | set;
                }
            }
        }
    }

    impl Fake {
        /// The board while driving: PA8/PA9 alternate function 1 (TIM1), PA4 analog, PA13/14
        /// SWD (AF), MOE on, IN1 at 40 % duty, ODR with stale high bits on both pins.
        fn driving() -> Fake {
            let moder = (0b10 << 16) | (0b10 << 18) | (0b11 << 8) | (0b10 << 26) | (0b10 << 28);
            Fake {
                ccr1: 1000,
                ccr2: 0,
                bdtr: BDTR_MOE | 0x1F,
                moder,
                odr: (1 << 8) | (1 << 9) | (1 << 3),
                writes: Vec::new(),
            }
        }

        /// Whether pin `p` can drive high: output with ODR high, or the timer's channel
        /// with the main output on and a pulse programmed.
        fn can_drive_high(&self, p: u32) -> bool {
            let mode = (self.moder >> (2 * p)) & 0b11;
            let ccr = if p == 8 { self.ccr1 } else { self.ccr2 };
            match mode {
                0b01 => self.odr & (1 << p) != 0,
                0b10 => self.bdtr & BDTR_MOE != 0 && ccr > 0,
                _ => false,
            }
        }
    }

    #[test]
    fn the_sequence_leaves_both_bridge_inputs_low_and_the_other_pins_alone() {
        let mut f = Fake::driving();
        assert!(f.can_drive_high(8) && !is_safe(&mut f));
        let before = f.moder;
        safe_sequence(&mut f);
        assert_eq!((f.ccr1, f.ccr2), (0, 0), "compare values");
        assert_eq!(f.bdtr & (1 << 15), 0, "TIM1 main output still enabled");
        assert_eq!((f.moder >> 16) & 0b11, 0b01, "PA8 not a GPIO output");
        assert_eq!((f.moder >> 18) & 0b11, 0b01, "PA9 not a GPIO output");
        assert_eq!(f.odr & ((1 << 8) | (1 << 9)), 0, "PA8/PA9 driven high");
        // Only the two pins' fields changed (PA4 analog, SWD on PA13/PA14 stay).
        assert_eq!(f.moder & !(0xF << 16), before & !(0xF << 16));
        // Other outputs keep their level.
        assert_eq!(f.odr & (1 << 3), 1 << 3);
        assert!(!f.can_drive_high(8) && !f.can_drive_high(9));
        assert!(is_safe(&mut f));
    }

    /// At no point of the sequence does a pin go from the timer to a GPIO output that drives
    /// high (the level is cleared before the mode switches).
    #[test]
    fn no_pin_drives_high_in_between() {
        let writes = {
            let mut f = Fake::driving();
            safe_sequence(&mut f);
            f.writes
        };
        let mut f = Fake::driving();
        for (k, (r, v)) in writes.iter().enumerate() {
            f.write(*r, *v);
            for p in PINS {
                if (f.moder >> (2 * p)) & 0b11 == 0b01 {
                    assert!(!f.can_drive_high(p), "PA{p} high after write {k}");
                }
            }
        }
    }

    /// The read-back recognises each way the bridge can still be on.
    #[test]
    fn the_read_back_catches_each_missing_step() {
        let safe = || {
            let mut f = Fake::driving();
            safe_sequence(&mut f);
            f
        };
        let mut f = safe();
        f.bdtr |= BDTR_MOE;
        assert!(!is_safe(&mut f), "MOE on");
        let mut f = safe();
        f.moder = (f.moder & !(0b11 << 18)) | (0b10 << 18);
        assert!(!is_safe(&mut f), "PA9 back on the timer");
        let mut f = safe();
        f.odr |= 1 << 8;
        assert!(!is_safe(&mut f), "PA8 high");
    }
}
