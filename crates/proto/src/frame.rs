//! Framing: `COBS(version ‖ postcard body ‖ CRC-16 LE) ‖ 0x00`.
//!
//! The zero byte delimits frames, so a receiver that starts mid-stream or loses bytes
//! resynchronises at the next zero. [`Decoder`] keeps at most its buffer's bytes of one frame:
//! any byte stream yields messages or typed [`FrameError`]s, never a panic or unbounded growth.

use core::marker::PhantomData;

use serde::{de::DeserializeOwned, Serialize};

use crate::VERSION;

/// Largest frame content before COBS: version byte, body and CRC (bytes).
pub const MAX_PAYLOAD: usize = 160;
/// Largest encoded frame, delimiter included (bytes).
pub const MAX_FRAME: usize = cobs::max_encoding_length(MAX_PAYLOAD) + 1;

/// CRC-16/IBM-SDLC (the X.25 CRC) over version and body.
const CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_SDLC);

/// A message type that travels in frames; [`Message::classify`] refines a body that did not
/// decode.
pub trait Message: Serialize + DeserializeOwned {
    /// What a checksummed body that does not decode means (default: malformed).
    fn classify(_body: &[u8]) -> FrameError {
        FrameError::Malformed
    }

    /// [`decode`] for this type, which [`Decoder`] calls. A message type may implement it as
    /// `decode(frame)` so that its decoder is compiled once, in this crate (with its
    /// optimisation level), rather than in each user of [`Decoder`].
    fn decode_frame(frame: &mut [u8]) -> Result<Self, FrameError> {
        decode(frame)
    }
}

/// Why a frame was not a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// More than the buffer's bytes before a delimiter: the frame was dropped up to the next
    /// delimiter.
    Overflow {
        /// The decoder's buffer (bytes).
        max_bytes: u16,
    },
    /// Not valid COBS.
    Cobs,
    /// Too short to hold version and CRC.
    TooShort {
        /// Decoded length (bytes).
        len: u16,
    },
    /// The CRC does not match the content.
    Checksum {
        /// CRC computed over the content.
        computed: u16,
        /// CRC carried by the frame.
        received: u16,
    },
    /// The frame's protocol version is not ours.
    Version {
        /// The frame's.
        received: u8,
        /// Ours.
        supported: u8,
    },
    /// A request with a command tag this version does not know.
    UnknownCommand {
        /// The request id.
        id: u16,
        /// The tag.
        tag: u32,
    },
    /// Checksum right, but the body is not a message of this version.
    Malformed,
}

/// Why a message could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The body is longer than [`MAX_PAYLOAD`] allows.
    TooLong,
    /// The output buffer is shorter than the frame (give [`MAX_FRAME`] bytes).
    BufferTooSmall,
}

/// Encodes `msg` as one frame into `out`, delimiter included; returns the frame's length.
pub fn encode<T: Serialize>(msg: &T, out: &mut [u8]) -> Result<usize, EncodeError> {
    // Written with checked slicing only: the firmware links this and must not panic.
    let mut raw = [0u8; MAX_PAYLOAD];
    raw[0] = VERSION;
    let body_len = postcard::to_slice(msg, &mut raw[1..MAX_PAYLOAD - 2])
        .map_err(|_| EncodeError::TooLong)?
        .len();
    let end = 1 + body_len;
    let content = raw.get(..end).ok_or(EncodeError::TooLong)?;
    let crc = CRC.checksum(content).to_le_bytes();
    raw.get_mut(end..end + 2)
        .ok_or(EncodeError::TooLong)?
        .copy_from_slice(&crc);
    let framed = raw.get(..end + 2).ok_or(EncodeError::TooLong)?;
    let n = cobs::try_encode(framed, out).map_err(|_| EncodeError::BufferTooSmall)?;
    let slot = out.get_mut(n).ok_or(EncodeError::BufferTooSmall)?;
    *slot = 0;
    Ok(n + 1)
}

/// Decodes one frame's content (without the delimiter; modified in place).
pub fn decode<T: Message>(frame: &mut [u8]) -> Result<T, FrameError> {
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    let raw = frame.get(..n).ok_or(FrameError::Cobs)?;
    if n < 3 {
        return Err(FrameError::TooShort { len: n as u16 });
    }
    let Some((content, crc)) = raw.split_last_chunk::<2>() else {
        return Err(FrameError::TooShort { len: n as u16 });
    };
    let received = u16::from_le_bytes(*crc);
    let computed = CRC.checksum(content);
    if computed != received {
        return Err(FrameError::Checksum { computed, received });
    }
    let (&version, body) = content.split_first().ok_or(FrameError::Malformed)?;
    if version != VERSION {
        return Err(FrameError::Version {
            received: version,
            supported: VERSION,
        });
    }
    match postcard::from_bytes::<T>(body) {
        Ok(m) => Ok(m),
        Err(_) => Err(T::classify(body)),
    }
}

/// A streaming decoder with a fixed buffer of `N` bytes (at least [`MAX_FRAME`] to take
/// every valid frame).
pub struct Decoder<T, const N: usize> {
    buf: heapless::Vec<u8, N>,
    overflow: bool,
    _msg: PhantomData<fn() -> T>,
}

impl<T: Message, const N: usize> Default for Decoder<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Message, const N: usize> Decoder<T, N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
            overflow: false,
            _msg: PhantomData,
        }
    }

    /// Drops a partial frame (e.g. after a reconnect).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.overflow = false;
    }

    /// Bytes of the frame in progress.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Takes one byte: a message or an error when it ends a frame, `None` otherwise (empty
    /// frames, i.e. repeated delimiters, are skipped).
    pub fn push(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            if !self.overflow && self.buf.push(byte).is_err() {
                self.overflow = true;
            }
            return None;
        }
        let overflow = core::mem::replace(&mut self.overflow, false);
        if overflow {
            self.buf.clear();
            return Some(Err(FrameError::Overflow {
                max_bytes: N.min(u16::MAX as usize) as u16,
            }));
        }
        if self.buf.is_empty() {
            return None;
        }
        let r = T::decode_frame(&mut self.buf);
        self.buf.clear();
        Some(r)
    }

    /// Feeds a slice, calling `out` for every frame it completes.
    pub fn feed(&mut self, bytes: &[u8], mut out: impl FnMut(Result<T, FrameError>)) {
        for &b in bytes {
            if let Some(r) = self.push(b) {
                out(r);
            }
        }
    }
}
