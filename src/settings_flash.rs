//! Where the settings store (crates/settings) lives on each build, and the boot-time load.
//!
//! * Board: the STM32F411CE's own flash, sectors 6 and 7 (128 KiB each, the last 256 KiB of
//!   the 512 KiB), which memory-stm32f411ce.x keeps out of the linker's FLASH region. An
//!   erase of a 128 KiB sector stalls every fetch from flash for seconds, the 10 kHz loop
//!   included: [`Settings::store`] stretches the independent watchdog around it and may be
//!   called only with the bridge off.
//! * QEMU: a RAM-backed NOR flash in `.uninit` (not zeroed at reset, like the fault latch),
//!   so stored settings survive a reset inside a run; a marker word tells a power-on (RAM
//!   content meaningless: the "chip" starts erased) from a reset.

use core::sync::atomic::{AtomicBool, Ordering};

use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};
use settings::{LoadStatus, Store, StoreError};

/// Largest settings payload the firmware loads (bytes).
pub const MAX_PAYLOAD: usize = 256;

/// Set once the flash has been handed out (it has one owner).
static TAKEN: AtomicBool = AtomicBool::new(false);

/// The settings store on this build's flash.
pub struct Settings {
    flash: imp::Flash,
    store: Store,
}

/// What the boot-time load found.
// The command interface (issue 18) reads the fields: the payload to decode, the store for
// later stores; init only logs the status so far.
#[allow(dead_code)]
pub struct Boot {
    /// The store, for later stores (None: the layout does not fit this flash, logged).
    pub settings: Option<Settings>,
    /// The load's outcome: anything but `Ok(Loaded)` means the build's defaults apply.
    pub status: Result<LoadStatus, StoreError>,
    /// The loaded payload (empty unless `Loaded`).
    pub payload: heapless::Vec<u8, MAX_PAYLOAD>,
}

impl Settings {
    /// The store on this build's flash; `None` after the first call (one owner).
    pub fn open() -> Option<Result<Self, StoreError>> {
        if TAKEN.swap(true, Ordering::SeqCst) {
            return None;
        }
        let flash = imp::Flash::take();
        Some(
            Store::new(imp::SLOT_A, imp::SLOT_B, imp::SLOT_LEN)
                .map(|store| Settings { flash, store }),
        )
    }

    /// Loads the newest valid settings into `buf` (see [`settings::Store::load`]).
    pub fn load(&mut self, buf: &mut [u8]) -> Result<LoadStatus, StoreError> {
        self.store.load(&mut self.flash, buf)
    }

    /// Stores `payload` as the new settings; returns its sequence number. Board: blocks for
    /// the sector erase (seconds) with the watchdog stretched; call with the bridge off.
    pub fn store(&mut self, payload: &[u8]) -> Result<u32, StoreError> {
        imp::around_store(|| self.store.store(&mut self.flash, payload))
    }
}

/// Test settings stored by the `settings@0` injection (test command only).
pub const INJECTED_PAYLOAD: &[u8] = b"settings stored by the test command";
/// The word the `settings-corrupt@0` injection programs at slot A (test command only).
pub const INJECTED_DAMAGE: u32 = 0x1234_5678;

/// Loads the store once at boot and logs what it found (`SETTINGS status=...`).
pub fn boot() -> Boot {
    let mut buf = [0u8; MAX_PAYLOAD];
    let mut payload = heapless::Vec::new();
    let (mut settings, status) = match Settings::open() {
        Some(Ok(mut s)) => {
            let st = s.load(&mut buf);
            (Some(s), st)
        }
        Some(Err(e)) => (None, Err(e)),
        None => (None, Err(StoreError::Flash(settings::FlashError::Other))),
    };
    match &status {
        Ok(st @ LoadStatus::Loaded { sequence, len, .. }) => {
            if let Some(p) = st.payload(&buf) {
                // `len` ≤ MAX_PAYLOAD = buf's length, so this always fits.
                let _ = payload.extend_from_slice(p);
                if matches!(crate::config::INJECT, Some(("settings", _))) {
                    defmt::info!("SETTINGS payload_matches={=bool}", p == INJECTED_PAYLOAD);
                }
            }
            defmt::info!(
                "SETTINGS status=loaded sequence={=u32} len={=usize} {}",
                sequence,
                len,
                st
            );
        }
        Ok(LoadStatus::Empty) => defmt::info!("SETTINGS status=empty (build defaults)"),
        Ok(st @ LoadStatus::Corrupt { .. }) => {
            defmt::warn!("SETTINGS status=corrupt (build defaults) {}", st)
        }
        Ok(st @ LoadStatus::Foreign { .. }) => {
            defmt::warn!("SETTINGS status=foreign (build defaults) {}", st)
        }
        Err(e) => defmt::error!("SETTINGS status=error (build defaults) {}", e),
    }
    // The test command's round trips: a first boot that finds no settings stores test
    // settings (FINGER_FW_INJECT=settings@0) or damages the store (settings-corrupt@0) and
    // resets; the next boot must load them, or fall back to the defaults and say why.
    if let (Some((kind @ ("settings" | "settings-corrupt"), _)), Ok(LoadStatus::Empty), Some(s)) =
        (crate::config::INJECT, &status, &mut settings)
    {
        if kind == "settings" {
            match s.store(INJECTED_PAYLOAD) {
                Ok(q) => defmt::info!(
                    "SETTINGS stored sequence={=u32} len={=usize}, resetting",
                    q,
                    INJECTED_PAYLOAD.len()
                ),
                Err(e) => defmt::error!("SETTINGS store failed {}", e),
            }
        } else {
            // Not a record: a word that is neither the magic nor erased, at slot A.
            let r = s.flash.write(imp::SLOT_A, &INJECTED_DAMAGE.to_le_bytes());
            defmt::info!(
                "SETTINGS damaged ok={=bool} word={=u32:#x}, resetting",
                r.is_ok(),
                INJECTED_DAMAGE
            );
        }
        cortex_m::peripheral::SCB::sys_reset();
    }
    Boot {
        settings,
        status,
        payload,
    }
}

/// Board: the MCU's flash.
#[cfg(not(feature = "qemu"))]
mod imp {
    use super::*;
    use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
    use stm32f4xx_hal::pac;

    /// Sector 6: 0x0804_0000 (offset 256 KiB).
    pub const SLOT_A: u32 = 0x4_0000;
    /// Sector 7: 0x0806_0000 (offset 384 KiB).
    pub const SLOT_B: u32 = 0x6_0000;
    /// One 128 KiB sector per slot.
    pub const SLOT_LEN: u32 = 0x2_0000;
    /// Where the flash is mapped.
    const BASE: usize = 0x0800_0000;

    /// The flash: reads memory-mapped (bounds-checked, never a panic), erases and programs
    /// through the HAL's `UnlockedFlash`.
    pub struct Flash {
        locked: LockedFlash,
    }

    impl Flash {
        pub fn take() -> Self {
            // SAFETY: `board::init` never uses the FLASH block (the clock set-up writes its
            // latency before this runs), and `Settings::open` hands this out once.
            let flash = unsafe { pac::FLASH::steal() };
            Flash {
                locked: LockedFlash::new(flash),
            }
        }
    }

    impl ErrorType for Flash {
        type Error = NorFlashErrorKind;
    }

    impl ReadNorFlash for Flash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_read(self, offset, bytes.len())?;
            for (i, b) in bytes.iter_mut().enumerate() {
                // SAFETY: inside the flash (checked against its capacity above).
                *b = unsafe { core::ptr::read_volatile((BASE + offset as usize + i) as *const u8) };
            }
            Ok(())
        }

        fn capacity(&self) -> usize {
            self.locked.len()
        }
    }

    impl NorFlash for Flash {
        const WRITE_SIZE: usize = 1;
        const ERASE_SIZE: usize = 128 * 1024;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_erase(self, from, to)?;
            let r = NorFlash::erase(&mut self.locked.unlocked(), from, to);
            reset_data_cache();
            r.map_err(|e| embedded_storage::nor_flash::NorFlashError::kind(&e))
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_write(self, offset, bytes.len())?;
            let r = NorFlash::write(&mut self.locked.unlocked(), offset, bytes);
            reset_data_cache();
            r.map_err(|e| embedded_storage::nor_flash::NorFlashError::kind(&e))
        }
    }

    /// The ART data cache may hold bytes of the erased or programmed sector: reset it
    /// (FLASH_ACR: DCEN off, DCRST pulse, DCEN back as it was).
    fn reset_data_cache() {
        // SAFETY: read-modify-write of FLASH_ACR's cache bits only.
        let flash = unsafe { &*pac::FLASH::ptr() };
        let acr = flash.acr().read().bits();
        const DCEN: u32 = 1 << 10;
        const DCRST: u32 = 1 << 12;
        flash.acr().write(|w| unsafe { w.bits(acr & !DCEN) });
        flash
            .acr()
            .write(|w| unsafe { w.bits((acr & !DCEN) | DCRST) });
        flash.acr().write(|w| unsafe { w.bits(acr & !DCRST) });
    }

    /// Runs a store with the IWDG stretched to its longest timeout (prescaler /256, reload
    /// 4095: ≥ 22 s at the fastest LSI, 47 kHz), then puts its prescaler and reload back
    /// (the datasheet's 128 KiB sector erase takes up to 4 s at 8-bit parallelism).
    pub fn around_store<T>(f: impl FnOnce() -> T) -> T {
        // SAFETY: IWDG key, prescaler and reload registers, written in the documented
        // order (0x5555 unlocks PR/RLR; 0xAAAA reloads the counter).
        let iwdg = unsafe { &*pac::IWDG::ptr() };
        let (pr, rlr) = (iwdg.pr().read().bits(), iwdg.rlr().read().bits());
        let set = |pr: u16, rlr: u16| {
            iwdg.kr().write(|w| unsafe { w.bits(0xAAAA) });
            iwdg.kr().write(|w| unsafe { w.bits(0x5555) });
            iwdg.pr().write(|w| unsafe { w.bits(pr) });
            iwdg.rlr().write(|w| unsafe { w.bits(rlr) });
            // PVU/RVU: the update reaches the watchdog's clock domain (a few LSI periods,
            // ~0.3 ms). Bounded: with the watchdog not started the LSI may be off.
            let mut n = 0u32;
            while iwdg.sr().read().bits() & 0b11 != 0 && n < 1_000_000 {
                n += 1;
            }
            iwdg.kr().write(|w| unsafe { w.bits(0xAAAA) });
        };
        set(6, 0xFFF);
        let r = f();
        set(pr, rlr);
        r
    }
}

/// QEMU: RAM that survives a reset.
#[cfg(feature = "qemu")]
mod imp {
    use super::*;
    use core::mem::MaybeUninit;

    /// Slot A at the start of the area.
    pub const SLOT_A: u32 = 0;
    /// Slot B after it.
    pub const SLOT_B: u32 = SLOT_LEN;
    /// One 1 KiB erase unit per slot.
    pub const SLOT_LEN: u32 = 1024;
    const CAPACITY: usize = 2 * SLOT_LEN as usize;
    /// Marks the area as formatted since the last power-on (with its complement).
    const MARKER: u32 = 0x5345_5454;

    /// The two slots and the marker (two words) after them.
    #[link_section = ".uninit.SETTINGS_FLASH"]
    static mut AREA: MaybeUninit<[u32; CAPACITY / 4 + 2]> = MaybeUninit::uninit();

    fn word(i: usize) -> *mut u32 {
        // SAFETY: only the address is computed; callers stay below CAPACITY / 4 + 2.
        unsafe { core::ptr::addr_of_mut!(AREA).cast::<u32>().add(i) }
    }

    /// A NOR flash in RAM: erase to 0xFF in 1 KiB units, program clears bits in 4-byte
    /// words (as the trait states; a word that is not erased only loses bits).
    pub struct Flash;

    impl Flash {
        pub fn take() -> Self {
            let m = CAPACITY / 4;
            // SAFETY: words of AREA, this module's only user (one owner, `Settings::open`).
            unsafe {
                if word(m).read_volatile() != MARKER || word(m + 1).read_volatile() != !MARKER {
                    // A power-on: RAM holds nothing; the "chip" comes erased.
                    for i in 0..m {
                        word(i).write_volatile(u32::MAX);
                    }
                    word(m).write_volatile(MARKER);
                    word(m + 1).write_volatile(!MARKER);
                }
            }
            Flash
        }
    }

    impl ErrorType for Flash {
        type Error = NorFlashErrorKind;
    }

    impl ReadNorFlash for Flash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_read(self, offset, bytes.len())?;
            for (i, b) in bytes.iter_mut().enumerate() {
                let at = offset as usize + i;
                // SAFETY: at < CAPACITY (checked above); a byte of a word of AREA.
                let w = unsafe { word(at / 4).read_volatile() };
                *b = w.to_le_bytes()[at % 4];
            }
            Ok(())
        }

        fn capacity(&self) -> usize {
            CAPACITY
        }
    }

    impl NorFlash for Flash {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = SLOT_LEN as usize;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_erase(self, from, to)?;
            for i in from as usize / 4..to as usize / 4 {
                // SAFETY: i < CAPACITY / 4 (checked above).
                unsafe { word(i).write_volatile(u32::MAX) };
            }
            Ok(())
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            embedded_storage::nor_flash::check_write(self, offset, bytes.len())?;
            for (k, c) in bytes.chunks_exact(4).enumerate() {
                let i = offset as usize / 4 + k;
                let Ok(v) = <[u8; 4]>::try_from(c).map(u32::from_le_bytes) else {
                    return Err(NorFlashErrorKind::NotAligned);
                };
                // SAFETY: i < CAPACITY / 4 (checked above).
                unsafe { word(i).write_volatile(word(i).read_volatile() & v) };
            }
            Ok(())
        }
    }

    /// Nothing to stretch on QEMU (no watchdog).
    pub fn around_store<T>(f: impl FnOnce() -> T) -> T {
        f()
    }
}
