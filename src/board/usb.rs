//! Device mode's link to the host on the board: USB CDC-ACM (a virtual serial port, e.g.
//! `/dev/ttyACM0` on Linux) on the STM32F411's OTG FS block, with usb-device and usbd-serial
//! over stm32f4xx-hal's Synopsys OTG driver.
//!
//! The link is polled from the OTG_FS interrupt (device mode's receive task, below the
//! control loop's priority) and written from the tasks that answer the host; the bytes are
//! the crates/proto frames, exactly as on the QEMU UART.
//!
//! The Synopsys driver guards its registers with `cortex_m::interrupt::free`, i.e. it masks
//! every interrupt, the 10 kHz loop's included, for the length of one register access or one
//! FIFO copy (at most a 64-byte packet). That can delay a loop entry, never skip one: the
//! ADC conversion is triggered by TIM1 in hardware and waits in its data register.

use stm32f4xx_hal::otg_fs::{UsbBus, UsbBusType, USB};
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usbd_serial::SerialPort;

/// Words of packet memory for the OUT endpoints: control (64 bytes) and CDC data (64 bytes),
/// with room to spare.
const EP_WORDS: usize = 64;

/// The pid.codes / VOTI vendor and product ID shared by CDC-ACM serial devices (Linux binds
/// cdc_acm to it without a driver of its own).
const VID_PID: UsbVidPid = UsbVidPid(0x16c0, 0x27dd);

/// Static storage the USB stack borrows for the rest of the run: the bus allocator and the
/// endpoints' packet memory. Lives in an RTIC init-local (`'static`), in .bss.
pub struct Storage {
    bus: Option<UsbBusAllocator<UsbBusType>>,
    ep_memory: [u32; EP_WORDS],
}

impl Storage {
    /// Empty storage (a constant, for RTIC's init-locals).
    pub const fn new() -> Self {
        Self {
            bus: None,
            ep_memory: [0; EP_WORDS],
        }
    }
}

/// The CDC-ACM port and the USB device behind it.
pub struct Usb {
    dev: UsbDevice<'static, UsbBusType>,
    serial: SerialPort<'static, UsbBusType>,
}

/// Builds the USB device on the OTG FS block (it attaches to the bus at once; the host
/// enumerates it from the OTG_FS interrupt).
pub fn init(storage: &'static mut Storage, usb: USB) -> Usb {
    let Storage { bus, ep_memory } = storage;
    let bus: &'static UsbBusAllocator<UsbBusType> = bus.insert(UsbBus::new(usb, ep_memory));
    let serial = SerialPort::new(bus);
    let builder = || UsbDeviceBuilder::new(bus, VID_PID).device_class(usbd_serial::USB_CLASS_CDC);
    let strings = StringDescriptors::default()
        .manufacturer("PTS finger")
        .product("finger-fw motor controller")
        .serial_number("1");
    // One language's strings always fit; should the builder refuse them anyway, the device
    // still enumerates (as a nameless CDC-ACM port) instead of stopping here.
    let dev = match builder().strings(&[strings]) {
        Ok(b) => b.build(),
        Err(_) => {
            defmt::warn!("USB string descriptors refused: enumerating without them");
            builder().build()
        }
    };
    Usb { dev, serial }
}

impl crate::device::Transport for Usb {
    /// Services the bus (enumeration, control requests such as DTR changes, endpoint
    /// completions), then reads what the host sent. Called from the OTG_FS interrupt.
    fn read(&mut self, buf: &mut [u8]) -> usize {
        self.dev.poll(&mut [&mut self.serial]);
        // WouldBlock (nothing received) and bus errors alike leave 0 bytes; the host's
        // silence and `open` are what the caller acts on.
        self.serial.read(buf).unwrap_or(0)
    }

    fn write(&mut self, bytes: &[u8]) -> usize {
        if !self.open() {
            // Nobody reads: the bytes stay queued (or the queue drops whole frames) rather
            // than the port's buffer filling with stale frames for the next host.
            return 0;
        }
        self.serial.write(bytes).unwrap_or(0)
    }

    /// Enumerated (configured, not suspended) and a program holds the port open (DTR set).
    fn open(&self) -> bool {
        self.dev.state() == UsbDeviceState::Configured && self.serial.dtr()
    }
}
