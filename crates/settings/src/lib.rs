//! A settings store on NOR flash that survives power loss at any point of a write.
//!
//! The payload is opaque bytes (callers serialize their settings value, e.g. with postcard).
//! Two slots, A and B, each one or more erase units, hold one record each. A store never
//! touches the slot that holds the newest valid record: it erases the other slot, writes the
//! new record there with the next sequence number, and commits it by programming the
//! record's first unit (the magic number) last. Until that last program completes, the
//! newest record is the old one; after it, the new one. A load takes the valid record with
//! the newest sequence number (serial-number arithmetic, so the counter may wrap).
//!
//! # Record layout
//! Little-endian, at the start of a slot:
//!
//! | bytes            | field                                                      |
//! |------------------|------------------------------------------------------------|
//! | 0..4             | magic [`MAGIC`] (programmed last: the commit)              |
//! | 4..6             | format version [`FORMAT_VERSION`]                          |
//! | 6..8             | reserved, `0xFFFF`                                         |
//! | 8..12            | sequence number                                            |
//! | 12..16           | payload length `n` (bytes)                                 |
//! | 16..16+n         | payload                                                    |
//! | 16+n..20+n       | CRC-32 ([`crc::CRC_32_ISO_HDLC`]) of bytes 4..16+n          |
//!
//! then `0xFF` up to the flash's write size. A slot whose first word reads `0xFFFF_FFFF`
//! holds no record (never written, or a store that lost power before its commit).
//! Future formats keep the magic and the version at bytes 0..6, so this one can recognise
//! them ([`LoadStatus::Foreign`]) instead of calling them corrupt.
#![no_std]

#[cfg(feature = "sim")]
extern crate alloc;

#[cfg(feature = "sim")]
pub mod sim;

use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// Magic number of a committed record (`"FSET"` read as a little-endian `u32`).
pub const MAGIC: u32 = u32::from_le_bytes(*b"FSET");
/// The record format this crate writes and loads.
pub const FORMAT_VERSION: u16 = 1;
/// Bytes before the payload (magic, version, reserved, sequence, length).
pub const HEADER_LEN: usize = 16;
/// Bytes after the payload (its CRC-32).
pub const TRAILER_LEN: usize = 4;

/// The CRC of the records: CRC-32/ISO-HDLC (the zlib/Ethernet CRC-32), bitwise: a record is
/// a few hundred bytes, and a lookup table would cost 1 KiB of the firmware's flash.
const CRC: crc::Crc<u32, crc::NoTable> = crc::Crc::<u32, crc::NoTable>::new(&crc::CRC_32_ISO_HDLC);
/// Staging buffer for reads and writes (bytes): writes and reads go through it in pieces.
const CHUNK: usize = 64;
/// First word of an erased slot.
const ERASED_WORD: u32 = 0xFFFF_FFFF;

/// One of the two slots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Slot {
    /// The first slot.
    A,
    /// The second slot.
    B,
}

/// Why a slot's content is not a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Corruption {
    /// The first word is neither [`MAGIC`] nor erased.
    Magic {
        /// The word found.
        found: u32,
    },
    /// The stored payload length does not fit the slot.
    Length {
        /// The stored length (bytes).
        len: u32,
        /// The largest payload the slot holds (bytes).
        max: u32,
    },
    /// The CRC-32 does not match the record.
    Crc {
        /// The CRC stored in the record.
        stored: u32,
        /// The CRC of the record as read.
        computed: u32,
    },
}

/// What a slot holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotState {
    /// No record: erased, or a store that lost power before its commit.
    Blank,
    /// A valid record of this format.
    Valid {
        /// Its sequence number.
        sequence: u32,
        /// Its payload length (bytes).
        len: u32,
    },
    /// A committed record of another format version.
    Foreign {
        /// The format version found.
        version: u16,
    },
    /// Neither blank nor a valid record.
    Corrupt(Corruption),
}

/// The outcome of [`Store::load`]. Everything but `Loaded` means the caller's defaults apply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoadStatus {
    /// The newest valid record's payload is in the caller's buffer.
    Loaded {
        /// Its sequence number.
        sequence: u32,
        /// Payload length (bytes): the loaded payload is `buf[..len]`.
        len: usize,
        /// The slot it came from.
        slot: Slot,
    },
    /// No record in either slot (a new device, or only interrupted stores).
    Empty,
    /// No valid record, and at least one slot holds something that is not one: defaults.
    Corrupt {
        /// The first corrupt slot.
        slot: Slot,
        /// What is wrong with it.
        why: Corruption,
    },
    /// No valid record of this format, but a record of another format version: defaults.
    Foreign {
        /// The other format's version.
        version: u16,
    },
}

impl LoadStatus {
    /// The loaded payload in `buf` (the buffer given to [`Store::load`]), if any.
    pub fn payload<'b>(&self, buf: &'b [u8]) -> Option<&'b [u8]> {
        match *self {
            LoadStatus::Loaded { len, .. } => buf.get(..len),
            _ => None,
        }
    }
}

/// The flash operation that failed, as the generic NOR flash error kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashError {
    /// Arguments not aligned to the flash's read, write or erase size.
    NotAligned,
    /// Outside the flash.
    OutOfBounds,
    /// Anything else the driver reported (including a write that did not complete).
    Other,
}

impl FlashError {
    fn of<E: NorFlashError>(e: E) -> Self {
        match e.kind() {
            NorFlashErrorKind::NotAligned => FlashError::NotAligned,
            NorFlashErrorKind::OutOfBounds => FlashError::OutOfBounds,
            _ => FlashError::Other,
        }
    }
}

/// Errors of the store (the caller's layout or buffers, or the flash driver); never about the
/// flash's content, which [`LoadStatus`] reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// A slot offset is not a multiple of the flash's erase size (bytes).
    SlotMisaligned {
        /// The slot's offset in the flash (bytes).
        offset: u32,
        /// The alignment required: the erase size (bytes).
        align: u32,
    },
    /// The slot length is shorter than an empty record (20 bytes) or not a multiple of the
    /// erase size (bytes).
    SlotLength {
        /// The slot length given (bytes).
        len: u32,
        /// The erase size it must be a non-zero multiple of (bytes).
        erase_size: u32,
    },
    /// A slot ends beyond the flash.
    SlotOutOfFlash {
        /// End of the slot (bytes from the start of the flash).
        end: u64,
        /// The flash's capacity (bytes).
        capacity: u64,
    },
    /// The two slots overlap.
    SlotsOverlap {
        /// Slot A's offset (bytes).
        a: u32,
        /// Slot B's offset (bytes).
        b: u32,
        /// Slot length (bytes).
        len: u32,
    },
    /// The flash's read or write size is not supported: it must divide 16 (read) or 64
    /// (write) bytes.
    Granularity {
        /// The flash's read size (bytes).
        read_size: u32,
        /// The flash's write size (bytes).
        write_size: u32,
    },
    /// The payload does not fit a slot.
    PayloadTooLarge {
        /// The payload's length (bytes).
        len: usize,
        /// The largest payload a slot holds (bytes).
        max: usize,
    },
    /// The newest valid record does not fit the caller's buffer.
    BufferTooSmall {
        /// The record's payload length (bytes).
        needed: usize,
        /// The buffer's length (bytes).
        available: usize,
    },
    /// The flash driver failed.
    Flash(FlashError),
    /// The record read back after a store is not the one written (the flash did not take
    /// the program): the previous settings stay the newest.
    Verify {
        /// The slot written.
        slot: Slot,
        /// What it holds instead.
        found: SlotState,
    },
}

/// Two slots on a NOR flash. Holds only the layout: the flash is passed to each call, so a
/// read-only driver can load and a writable one store.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Store {
    a: u32,
    b: u32,
    len: u32,
}

fn round_up(x: usize, to: usize) -> usize {
    x.div_ceil(to.max(1)).saturating_mul(to.max(1))
}

impl Store {
    /// Two slots of `slot_len` bytes at the flash offsets `slot_a` and `slot_b` (bytes from
    /// the start of the flash). The alignment to a particular flash is checked by each call.
    pub fn new(slot_a: u32, slot_b: u32, slot_len: u32) -> Result<Self, StoreError> {
        let (lo, hi) = if slot_a <= slot_b {
            (slot_a, slot_b)
        } else {
            (slot_b, slot_a)
        };
        if u64::from(lo) + u64::from(slot_len) > u64::from(hi) {
            return Err(StoreError::SlotsOverlap {
                a: slot_a,
                b: slot_b,
                len: slot_len,
            });
        }
        Ok(Store {
            a: slot_a,
            b: slot_b,
            len: slot_len,
        })
    }

    /// The largest payload a slot holds on a flash with these read and write sizes (bytes).
    pub fn max_payload_for(&self, read_size: usize, write_size: usize) -> usize {
        let unit = read_size.max(write_size).max(1);
        // The record, rounded up to the unit, must fit the slot (rounded down to the unit).
        let room = (self.len as usize / unit) * unit;
        room.saturating_sub(HEADER_LEN + TRAILER_LEN)
    }

    /// The largest payload a slot holds on flash `F` (bytes).
    pub fn max_payload<F: NorFlash>(&self) -> usize {
        self.max_payload_for(F::READ_SIZE, F::WRITE_SIZE)
    }

    fn base(&self, slot: Slot) -> u32 {
        match slot {
            Slot::A => self.a,
            Slot::B => self.b,
        }
    }

    /// Checks the layout against a flash that can be read (and, for `erase` = Some, erased
    /// with that erase size and written with `write`).
    fn check(
        &self,
        capacity: usize,
        read: usize,
        write: usize,
        erase: Option<usize>,
    ) -> Result<(), StoreError> {
        if read == 0 || HEADER_LEN % read != 0 || write == 0 || CHUNK % write != 0 {
            return Err(StoreError::Granularity {
                read_size: read as u32,
                write_size: write as u32,
            });
        }
        let align = erase.unwrap_or(read).max(1);
        for off in [self.a, self.b] {
            if off as usize % align != 0 {
                return Err(StoreError::SlotMisaligned {
                    offset: off,
                    align: align as u32,
                });
            }
            let end = u64::from(off) + u64::from(self.len);
            if end > capacity as u64 {
                return Err(StoreError::SlotOutOfFlash {
                    end,
                    capacity: capacity as u64,
                });
            }
        }
        if (self.len as usize) < HEADER_LEN + TRAILER_LEN || self.len as usize % align != 0 {
            return Err(StoreError::SlotLength {
                len: self.len,
                erase_size: align as u32,
            });
        }
        Ok(())
    }

    /// What `slot` holds (reads only). On a flash whose read size is `F::READ_SIZE`.
    pub fn slot_state<F: ReadNorFlash>(
        &self,
        flash: &mut F,
        slot: Slot,
    ) -> Result<SlotState, StoreError> {
        self.check(flash.capacity(), F::READ_SIZE, 1, None)?;
        self.inspect(flash, slot)
    }

    /// Reads and checks one slot. The length bound is the slot rounded to the read size
    /// only, so every record any writer of this format made on this flash is accepted.
    fn inspect<F: ReadNorFlash>(&self, flash: &mut F, slot: Slot) -> Result<SlotState, StoreError> {
        let read = F::READ_SIZE.max(1);
        let base = self.base(slot);
        let mut head = [0u8; HEADER_LEN];
        flash
            .read(base, &mut head)
            .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
        let word = |i: usize| {
            let mut w = [0u8; 4];
            w.copy_from_slice(head.get(i..i + 4).unwrap_or(&[0; 4]));
            u32::from_le_bytes(w)
        };
        let magic = word(0);
        if magic == ERASED_WORD {
            return Ok(SlotState::Blank);
        }
        if magic != MAGIC {
            return Ok(SlotState::Corrupt(Corruption::Magic { found: magic }));
        }
        let version = u16::from_le_bytes([head[4], head[5]]);
        if version != FORMAT_VERSION {
            return Ok(SlotState::Foreign { version });
        }
        let sequence = word(8);
        let len = word(12);
        let max = self.max_payload_for(read, 1);
        if len as usize > max {
            return Ok(SlotState::Corrupt(Corruption::Length {
                len,
                max: max as u32,
            }));
        }
        let mut digest = CRC.digest();
        digest.update(head.get(4..).unwrap_or(&[]));
        // Payload and CRC, in read-size-aligned pieces from offset HEADER_LEN.
        let total = len as usize + TRAILER_LEN;
        let mut stored = [0u8; TRAILER_LEN];
        let mut buf = [0u8; CHUNK];
        let mut done = 0usize;
        while done < total {
            let n = (total - done).min(CHUNK);
            let nr = round_up(n, read).min(CHUNK);
            let piece = buf.get_mut(..nr).unwrap_or(&mut []);
            flash
                .read(base + (HEADER_LEN + done) as u32, piece)
                .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
            for (i, &byte) in piece.iter().take(n).enumerate() {
                let at = done + i;
                if at < len as usize {
                    digest.update(&[byte]);
                } else if let Some(s) = stored.get_mut(at - len as usize) {
                    *s = byte;
                }
            }
            done += n;
        }
        let computed = digest.finalize();
        let stored = u32::from_le_bytes(stored);
        if stored != computed {
            return Ok(SlotState::Corrupt(Corruption::Crc { stored, computed }));
        }
        Ok(SlotState::Valid { sequence, len })
    }

    /// Both slots' states and the newest valid one (slot, sequence, length).
    #[allow(clippy::type_complexity)]
    fn scan<F: ReadNorFlash>(
        &self,
        flash: &mut F,
    ) -> Result<([SlotState; 2], Option<(Slot, u32, u32)>), StoreError> {
        let sa = self.inspect(flash, Slot::A)?;
        let sb = self.inspect(flash, Slot::B)?;
        let newest = match (sa, sb) {
            (
                SlotState::Valid {
                    sequence: qa,
                    len: la,
                },
                SlotState::Valid {
                    sequence: qb,
                    len: lb,
                },
            ) => {
                if newer(qb, qa) {
                    Some((Slot::B, qb, lb))
                } else {
                    Some((Slot::A, qa, la))
                }
            }
            (SlotState::Valid { sequence, len }, _) => Some((Slot::A, sequence, len)),
            (_, SlotState::Valid { sequence, len }) => Some((Slot::B, sequence, len)),
            _ => None,
        };
        Ok(([sa, sb], newest))
    }

    /// Loads the newest valid record into `buf` (its payload is `buf[..len]`), or says why
    /// there is none: [`LoadStatus::Empty`], [`LoadStatus::Corrupt`] or
    /// [`LoadStatus::Foreign`], on which the caller uses its defaults. Never panics,
    /// whatever the flash holds.
    pub fn load<F: ReadNorFlash>(
        &self,
        flash: &mut F,
        buf: &mut [u8],
    ) -> Result<LoadStatus, StoreError> {
        self.check(flash.capacity(), F::READ_SIZE, 1, None)?;
        let (states, newest) = self.scan(flash)?;
        if let Some((slot, sequence, len)) = newest {
            let len = len as usize;
            let Some(dst) = buf.get_mut(..len) else {
                return Err(StoreError::BufferTooSmall {
                    needed: len,
                    available: buf.len(),
                });
            };
            self.read_payload(flash, slot, dst)?;
            return Ok(LoadStatus::Loaded {
                sequence,
                len,
                slot,
            });
        }
        let slots = [Slot::A, Slot::B];
        if let Some(version) = states.iter().find_map(|s| match s {
            SlotState::Foreign { version } => Some(*version),
            _ => None,
        }) {
            return Ok(LoadStatus::Foreign { version });
        }
        for (s, slot) in states.iter().zip(slots) {
            if let SlotState::Corrupt(why) = s {
                return Ok(LoadStatus::Corrupt { slot, why: *why });
            }
        }
        Ok(LoadStatus::Empty)
    }

    /// Reads a payload checked by `inspect` into `dst` (its exact length), in pieces aligned
    /// to the read size.
    fn read_payload<F: ReadNorFlash>(
        &self,
        flash: &mut F,
        slot: Slot,
        dst: &mut [u8],
    ) -> Result<(), StoreError> {
        let base = self.base(slot) + HEADER_LEN as u32;
        let read = F::READ_SIZE.max(1);
        let whole = dst.len() / read * read;
        let (body, tail) = dst.split_at_mut(whole);
        if !body.is_empty() {
            flash
                .read(base, body)
                .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
        }
        if !tail.is_empty() {
            let mut buf = [0u8; HEADER_LEN];
            let piece = buf.get_mut(..read).unwrap_or(&mut []);
            flash
                .read(base + whole as u32, piece)
                .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
            for (d, s) in tail.iter_mut().zip(piece.iter()) {
                *d = *s;
            }
        }
        Ok(())
    }

    /// Stores `payload` as the new newest record, reads it back, and returns its sequence
    /// number. Power lost at any point leaves the previous newest record (or none) or this
    /// one loadable.
    pub fn store<F: NorFlash>(&self, flash: &mut F, payload: &[u8]) -> Result<u32, StoreError> {
        self.check(
            flash.capacity(),
            F::READ_SIZE,
            F::WRITE_SIZE,
            Some(F::ERASE_SIZE),
        )?;
        let max = self.max_payload::<F>();
        if payload.len() > max {
            return Err(StoreError::PayloadTooLarge {
                len: payload.len(),
                max,
            });
        }
        let (_, newest) = self.scan(flash)?;
        let (target, sequence) = match newest {
            Some((Slot::A, q, _)) => (Slot::B, q.wrapping_add(1)),
            Some((Slot::B, q, _)) => (Slot::A, q.wrapping_add(1)),
            None => (Slot::A, 1),
        };
        let base = self.base(target);
        flash
            .erase(base, base + self.len)
            .map_err(|e| StoreError::Flash(FlashError::of(e)))?;

        let mut head = [0xFFu8; HEADER_LEN];
        head[..4].copy_from_slice(&MAGIC.to_le_bytes());
        head[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        head[8..12].copy_from_slice(&sequence.to_le_bytes());
        head[12..16].copy_from_slice(&(payload.len() as u32).to_le_bytes());
        let mut digest = CRC.digest();
        digest.update(&head[4..]);
        digest.update(payload);
        let crc = digest.finalize().to_le_bytes();
        let record = Record {
            head: &head,
            payload,
            crc: &crc,
        };
        let w = F::WRITE_SIZE;
        let total = round_up(record.len(), w);
        // The commit unit: the first write-size unit(s) holding the magic, written last.
        let commit = round_up(4, w);
        let mut buf = [0u8; CHUNK];
        let mut at = commit;
        while at < total {
            let n = (total - at).min(CHUNK);
            let piece = buf.get_mut(..n).unwrap_or(&mut []);
            record.fill(at, piece);
            flash
                .write(base + at as u32, piece)
                .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
            at += n;
        }
        let piece = buf.get_mut(..commit.min(total)).unwrap_or(&mut []);
        record.fill(0, piece);
        flash
            .write(base, piece)
            .map_err(|e| StoreError::Flash(FlashError::of(e)))?;
        // Read back: a program the flash silently did not take must not pass for a store.
        match self.inspect(flash, target)? {
            SlotState::Valid { sequence: q, len }
                if q == sequence && len as usize == payload.len() =>
            {
                Ok(sequence)
            }
            found => Err(StoreError::Verify {
                slot: target,
                found,
            }),
        }
    }
}

/// Serial-number order (RFC 1982): `a` is newer than `b` when it is ahead by less than 2³¹.
pub fn newer(a: u32, b: u32) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < 0x8000_0000
}

/// A record as a byte stream: header, payload, CRC, then `0xFF` padding.
struct Record<'a> {
    head: &'a [u8; HEADER_LEN],
    payload: &'a [u8],
    crc: &'a [u8; TRAILER_LEN],
}

impl Record<'_> {
    fn len(&self) -> usize {
        HEADER_LEN + self.payload.len() + TRAILER_LEN
    }

    /// Copies the record's bytes `at..at + dst.len()` into `dst` (padding beyond its end).
    fn fill(&self, at: usize, dst: &mut [u8]) {
        let p = self.payload.len();
        for (i, d) in dst.iter_mut().enumerate() {
            let k = at + i;
            *d = if k < HEADER_LEN {
                self.head.get(k).copied().unwrap_or(0xFF)
            } else if k < HEADER_LEN + p {
                self.payload.get(k - HEADER_LEN).copied().unwrap_or(0xFF)
            } else {
                self.crc.get(k - HEADER_LEN - p).copied().unwrap_or(0xFF)
            };
        }
    }
}
