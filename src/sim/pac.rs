//! The smallest "device crate" RTIC needs for QEMU's mps2-an386 (ARM AN386 FPGA image):
//! the external interrupt numbers, the NVIC priority bits and the vector table entries.
//! No peripheral registers are used: the simulated board is crates/plant, the sampling task is
//! driven by SysTick (which pends the `ADC` line) and the dispatchers are software-pended interrupts.
#![allow(
    non_camel_case_types,
    missing_docs,
    dead_code,
    clippy::upper_case_acronyms
)]

/// Number of priority bits of the NVIC (Cortex-M4 in QEMU implements 8; AN386 documents 3,
/// the smaller value keeps RTIC's priority mapping valid on both).
pub const NVIC_PRIO_BITS: u8 = 3;

/// External interrupts of the AN386 image (subset, numbering of the application note).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Interrupt {
    /// UART0's receive interrupt (AN386 IRQ 0), under the name of the board's USB interrupt:
    /// device mode's host-link task binds one name on both builds (RTIC takes the name
    /// literally), and on both it is the interrupt of the link to the host.
    OTG_FS = 0,
    UART0TX = 1,
    UART1RX = 2,
    UART1TX = 3,
    UART2RX = 4,
    UART2TX = 5,
    GPIO0 = 6,
    GPIO1 = 7,
    TIMER0 = 8,
    TIMER1 = 9,
    DUALTIMER = 10,
    SPI0 = 11,
    /// Not an AN386 peripheral: the line the firmware binds its sampling task to (the real
    /// board's ADC end-of-conversion); src/sim pends it from SysTick.
    ADC = 16,
}

/// RTIC names the interrupt enum `interrupt` (svd2rust convention).
pub use self::Interrupt as interrupt;

// SAFETY: every variant is a valid external interrupt number of the device (< 32).
unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
    #[inline(always)]
    fn number(self) -> u16 {
        self as u16
    }
}

extern "C" {
    fn OTG_FS();
    fn UART0TX();
    fn UART1RX();
    fn UART1TX();
    fn UART2RX();
    fn UART2TX();
    fn GPIO0();
    fn GPIO1();
    fn TIMER0();
    fn TIMER1();
    fn DUALTIMER();
    fn SPI0();
    fn ADC();
}

/// One entry of the interrupt vector table.
#[doc(hidden)]
pub union Vector {
    _handler: unsafe extern "C" fn(),
    _reserved: u32,
}

/// The external part of the vector table (cortex-m-rt `device` feature; defaults in device.x).
#[doc(hidden)]
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
pub static __INTERRUPTS: [Vector; 17] = [
    Vector { _handler: OTG_FS },
    Vector { _handler: UART0TX },
    Vector { _handler: UART1RX },
    Vector { _handler: UART1TX },
    Vector { _handler: UART2RX },
    Vector { _handler: UART2TX },
    Vector { _handler: GPIO0 },
    Vector { _handler: GPIO1 },
    Vector { _handler: TIMER0 },
    Vector { _handler: TIMER1 },
    Vector {
        _handler: DUALTIMER,
    },
    Vector { _handler: SPI0 },
    Vector { _reserved: 0 },
    Vector { _reserved: 0 },
    Vector { _reserved: 0 },
    Vector { _reserved: 0 },
    Vector { _handler: ADC },
];
