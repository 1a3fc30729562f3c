//! A simulated NOR flash that can lose power after any primitive step (feature `sim`).
//!
//! Semantics as the [`NorFlash`] trait states them: reads, writes and erases aligned to
//! `R`, `W` and `E` bytes; an erase sets a unit's bytes to `0xFF`; a program can only clear
//! bits, and programming a byte that is not erased is refused (the store never needs it, so
//! it is a bug). One primitive step is the erase of one `E`-byte unit or the program of one
//! `W`-byte unit. A planned [`Cut`] stops the power at a given step, which is then not done,
//! done, or torn (some of the bits it would change changed, chosen by a seed); every
//! operation after it fails until [`SimFlash::power_on`].

use alloc::vec;
use alloc::vec::Vec;
use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashError, NorFlashErrorKind,
    ReadNorFlash,
};

/// What happens to the step at which the power is lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tear {
    /// The step has no effect.
    Before,
    /// The step completes, then the power is lost.
    After,
    /// Part of the step's effect (a torn word, a partially erased unit), chosen by this seed.
    Partial(u64),
}

/// A planned power loss.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cut {
    /// Index of the step (counted from 0 since the last power-on) at which power is lost.
    pub at: u64,
    /// What that step does.
    pub tear: Tear,
}

/// Errors of the simulated flash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimError {
    /// Alignment or bounds, as the trait's checks report them.
    Check(NorFlashErrorKind),
    /// The power is off (lost during this or an earlier operation).
    PowerLost,
    /// A program of a byte that is not erased, at this offset (bytes).
    NotErased(u32),
}

impl NorFlashError for SimError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimError::Check(k) => *k,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The simulated flash: read size `R`, write size `W`, erase size `E` (bytes).
#[derive(Clone, Debug)]
pub struct SimFlash<const R: usize, const W: usize, const E: usize> {
    mem: Vec<u8>,
    steps: u64,
    cut: Option<Cut>,
    off: bool,
}

/// xorshift64*: the torn bits, reproducible from a seed.
fn next(state: &mut u64) -> u64 {
    let mut x = *state | 1;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    *state = x;
    x.wrapping_mul(0x2545_F491_4F6C_DD1D)
}

impl<const R: usize, const W: usize, const E: usize> SimFlash<R, W, E> {
    /// An erased flash of `capacity` bytes (a multiple of `E`).
    pub fn new(capacity: usize) -> Self {
        Self::from_bytes(vec![0xFF; capacity])
    }

    /// A flash holding these bytes (as found on a device: any content).
    pub fn from_bytes(mem: Vec<u8>) -> Self {
        SimFlash {
            mem,
            steps: 0,
            cut: None,
            off: false,
        }
    }

    /// The content.
    pub fn bytes(&self) -> &[u8] {
        &self.mem
    }

    /// The content, for planting data or damage.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        &mut self.mem
    }

    /// Primitive steps since the last power-on.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Plans a power loss.
    pub fn cut(&mut self, cut: Cut) {
        self.cut = Some(cut);
    }

    /// Power back on: the step counter restarts, no cut is planned.
    pub fn power_on(&mut self) {
        self.steps = 0;
        self.cut = None;
        self.off = false;
    }

    /// Whether the power is off.
    pub fn is_off(&self) -> bool {
        self.off
    }

    /// Runs one primitive step on `range` of the memory: `full` gives the step's effect on a
    /// byte, `torn` a partial effect from a random byte.
    fn step(
        &mut self,
        start: usize,
        new: &dyn Fn(usize, u8) -> u8,
        torn: &dyn Fn(usize, u8, u8) -> u8,
        len: usize,
    ) -> Result<(), SimError> {
        if self.off {
            return Err(SimError::PowerLost);
        }
        let index = self.steps;
        self.steps += 1;
        let cut = self.cut.filter(|c| c.at == index);
        let region = self
            .mem
            .get_mut(start..start + len)
            .ok_or(SimError::Check(NorFlashErrorKind::OutOfBounds))?;
        match cut.map(|c| c.tear) {
            None | Some(Tear::After) => {
                for (i, b) in region.iter_mut().enumerate() {
                    *b = new(i, *b);
                }
            }
            Some(Tear::Before) => {}
            Some(Tear::Partial(seed)) => {
                let mut s = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
                // A prefix completes, the rest gets random parts of its effect.
                let done = (next(&mut s) % (len as u64 + 1)) as usize;
                for (i, b) in region.iter_mut().enumerate() {
                    *b = if i < done {
                        new(i, *b)
                    } else {
                        torn(i, *b, next(&mut s) as u8)
                    };
                }
            }
        }
        if cut.is_some() {
            self.off = true;
            return Err(SimError::PowerLost);
        }
        Ok(())
    }
}

impl<const R: usize, const W: usize, const E: usize> ErrorType for SimFlash<R, W, E> {
    type Error = SimError;
}

impl<const R: usize, const W: usize, const E: usize> ReadNorFlash for SimFlash<R, W, E> {
    const READ_SIZE: usize = R;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimError> {
        check_read(self, offset, bytes.len()).map_err(SimError::Check)?;
        if self.off {
            return Err(SimError::PowerLost);
        }
        let at = offset as usize;
        let src = self
            .mem
            .get(at..at + bytes.len())
            .ok_or(SimError::Check(NorFlashErrorKind::OutOfBounds))?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl<const R: usize, const W: usize, const E: usize> NorFlash for SimFlash<R, W, E> {
    const WRITE_SIZE: usize = W;
    const ERASE_SIZE: usize = E;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), SimError> {
        check_erase(self, from, to).map_err(SimError::Check)?;
        for unit in (from as usize..to as usize).step_by(E) {
            // Erasing sets bits; a torn erase sets some of them.
            self.step(unit, &|_, _| 0xFF, &|_, old, r| old | r, E)?;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimError> {
        check_write(self, offset, bytes.len()).map_err(SimError::Check)?;
        let at = offset as usize;
        if let Some(i) = self
            .mem
            .get(at..at + bytes.len())
            .and_then(|m| m.iter().position(|&b| b != 0xFF))
        {
            return Err(SimError::NotErased((at + i) as u32));
        }
        for (k, unit) in bytes.chunks(W).enumerate() {
            // Programming clears bits; a torn program clears some of them.
            self.step(
                at + k * W,
                &|i, old| old & unit[i],
                &|i, old, r| old & (unit[i] | !r),
                W,
            )?;
        }
        Ok(())
    }
}
