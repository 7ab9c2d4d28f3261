//! Framing for byte streams (serial radios): COBS with a CRC-32, delimited by `0x00`.
//!
//! ```text
//! frame = 0x00 | COBS(packet | crc32(packet) as u32 LE) | 0x00
//! crc32 = CRC-32/ISO-HDLC (the Ethernet/zlib CRC)
//! ```
//!
//! The leading delimiter costs one byte and keeps line noise on an idle link (or the tail of a
//! write cut short) from merging with the next frame and losing it too; the decoder ignores the
//! empty frame between two delimiters.
//!
//! COBS removes every `0x00` from the payload, so `0x00` can only be a delimiter: a receiver that
//! joins mid-stream, or loses bytes to noise, resynchronises at the next delimiter and loses at
//! most the frame it was in. The cost is one byte per 254 payload bytes (at least one).
//!
//! COBS block encoding: a code byte `c` (1..=255) is followed by `c - 1` non-zero data bytes; a
//! block with `c < 255` stands for its data followed by a zero, except at the end of the frame,
//! where that zero is the implicit end of data. When the data ends exactly after a full
//! (`c = 255`) block, the empty block that would otherwise follow is omitted.
//!
//! The CRC is what makes a frame trustworthy: serial radios deliver bit errors, and COBS alone
//! would turn most of them into a well-formed but wrong packet.

use super::FrameError;
use crate::crc::CRC32;

/// Frame delimiter; COBS guarantees it occurs nowhere else.
pub const DELIMITER: u8 = 0x00;
/// Bytes of the CRC-32 appended to each packet.
pub const CRC_BYTES: usize = 4;

/// Longest run of non-zero bytes one COBS block carries (its code byte is then `0xFF`).
const MAX_BLOCK_DATA: usize = 254;
/// The code byte of a full block, which implies no zero after its data.
const FULL_BLOCK_CODE: u8 = 0xFF;

/// Exact worst case of the COBS encoding of `data_len` bytes (without delimiter): one code byte
/// per started run of 254 bytes, and one for empty data. Reached when no byte is zero.
pub const fn cobs_max_len(data_len: usize) -> usize {
    if data_len == 0 { 1 } else { data_len.saturating_add(data_len.div_ceil(MAX_BLOCK_DATA)) }
}

/// Exact worst case of the frame of a `packet_len`-byte packet: CRC, COBS overhead and both
/// delimiters included. Size encode buffers with it; it is also what the token bucket charges.
pub const fn max_frame_len(packet_len: usize) -> usize {
    cobs_max_len(packet_len.saturating_add(CRC_BYTES)).saturating_add(2)
}

/// Writes a COBS encoding into a caller's buffer, one byte at a time, so the packet and its CRC
/// need not be copied together first.
struct CobsWriter<'a> {
    out: &'a mut [u8],
    /// Next position to write a data byte at.
    pos: usize,
    /// Position reserved for the code byte of the open block.
    code_pos: usize,
    /// Code of the open block: 1 + its data bytes so far.
    code: u8,
    /// Whether the previous block was closed because it was full rather than by a zero; an
    /// empty final block after it carries no information and is omitted.
    after_full_block: bool,
}

impl<'a> CobsWriter<'a> {
    fn new(out: &'a mut [u8]) -> Self {
        CobsWriter { out, pos: 1, code_pos: 0, code: 1, after_full_block: false }
    }

    fn put(&mut self, at: usize, byte: u8) -> Result<(), FrameError> {
        let slot = self.out.get_mut(at).ok_or(FrameError::BufferTooSmall)?;
        *slot = byte;
        Ok(())
    }

    fn close_block(&mut self, full: bool) -> Result<(), FrameError> {
        self.put(self.code_pos, self.code)?;
        self.code_pos = self.pos;
        // Reserved, not written: an exactly sized buffer must not fail on a code byte that the
        // final block turns out not to need.
        self.pos += 1;
        self.code = 1;
        self.after_full_block = full;
        Ok(())
    }

    fn push(&mut self, byte: u8) -> Result<(), FrameError> {
        if byte == 0 {
            return self.close_block(false);
        }
        self.put(self.pos, byte)?;
        self.pos += 1;
        self.code += 1;
        if self.code == FULL_BLOCK_CODE {
            self.close_block(true)?;
        }
        Ok(())
    }

    /// Closes the encoding and returns its length.
    fn finish(mut self) -> Result<usize, FrameError> {
        if self.code == 1 && self.after_full_block {
            self.pos -= 1;
        } else {
            self.put(self.code_pos, self.code)?;
        }
        Ok(self.pos)
    }
}

/// Encodes `packet` as one frame into `out` and returns the frame length (delimiter included).
/// `out` of [`max_frame_len`]`(packet.len())` bytes always suffices.
pub fn encode_frame(packet: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let crc = CRC32.checksum(packet).to_le_bytes();
    let Some((leading, body)) = out.split_first_mut() else {
        return Err(FrameError::BufferTooSmall);
    };
    *leading = DELIMITER;
    let mut writer = CobsWriter::new(body);
    for &byte in packet.iter().chain(crc.iter()) {
        writer.push(byte)?;
    }
    let len = writer.finish()?;
    let delimiter = body.get_mut(len).ok_or(FrameError::BufferTooSmall)?;
    *delimiter = DELIMITER;
    Ok(len + 2)
}

/// Counters of a [`StreamDecoder`]. They wrap never in practice (u64) and saturate if they did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Frames delivered as packets.
    pub frames_ok: u64,
    /// Frames whose CRC did not match, or too short to hold one.
    pub crc_errors: u64,
    /// Frames that ended inside a COBS block.
    pub cobs_errors: u64,
    /// Frames longer than the decoder buffer.
    pub overflows: u64,
}

/// Incremental decoder of a byte stream into packets. `N` bounds a decoded frame, CRC included,
/// so the largest packet it accepts is `N - 4` bytes.
///
/// It decodes COBS as bytes arrive instead of buffering the encoded frame, so it needs only `N`
/// bytes, not the encoded worst case, and never looks back at earlier input.
pub struct StreamDecoder<const N: usize> {
    buf: [u8; N],
    /// Decoded bytes of the current frame.
    len: usize,
    /// Data bytes still due in the current COBS block; 0 means the next byte is a code byte.
    block_left: u8,
    /// Whether the current block ends in an implied zero, written only once another block
    /// follows (at the end of the frame it is the end of data instead).
    zero_pending: bool,
    /// Whether any byte of the current frame has arrived (consecutive delimiters are no frame).
    in_frame: bool,
    /// Skipping the rest of an overlong frame, which has already been reported.
    discarding: bool,
    stats: StreamStats,
}

impl<const N: usize> StreamDecoder<N> {
    /// Starts out of any frame: bytes before the first delimiter make a frame of their own,
    /// which fails its check unless the stream really started at a frame boundary.
    pub const fn new() -> Self {
        StreamDecoder {
            buf: [0; N],
            len: 0,
            block_left: 0,
            zero_pending: false,
            in_frame: false,
            discarding: false,
            stats: StreamStats { frames_ok: 0, crc_errors: 0, cobs_errors: 0, overflows: 0 },
        }
    }

    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// Decodes `bytes`, which may hold any part of any number of frames, and calls `on_packet`
    /// once per frame completed by them: with the packet, or with why the frame was dropped.
    /// The packet slice is only valid during the call.
    pub fn feed(&mut self, mut bytes: &[u8], mut on_packet: impl FnMut(Result<&[u8], FrameError>)) {
        while let Some((&byte, rest)) = bytes.split_first() {
            if byte != DELIMITER && (self.discarding || self.block_left > 0) {
                // Fast path: the data bytes of a block (or a discarded frame) up to the next
                // delimiter are copied (or skipped) in one go instead of byte by byte.
                let limit = if self.discarding { bytes.len() } else { usize::from(self.block_left).min(bytes.len()) };
                let window = bytes.get(..limit).unwrap_or_default();
                let run = window.iter().position(|&b| b == DELIMITER).unwrap_or(limit);
                let (data, after) = bytes.split_at(run);
                if self.discarding {
                    bytes = after;
                    continue;
                }
                if let Some(slot) = self.buf.get_mut(self.len..self.len + run) {
                    slot.copy_from_slice(data);
                    self.len += run;
                    // `run <= block_left`, which is a u8.
                    self.block_left -= run as u8;
                    bytes = after;
                    continue;
                }
                // Does not fit: the byte-wise path below reports the overflow.
            }
            bytes = rest;
            if byte == DELIMITER {
                if self.in_frame && !self.discarding {
                    match self.check_frame() {
                        Ok(packet_len) => {
                            self.stats.frames_ok = self.stats.frames_ok.saturating_add(1);
                            on_packet(Ok(self.buf.get(..packet_len).unwrap_or_default()));
                        }
                        Err(error) => on_packet(Err(error)),
                    }
                }
                self.reset();
                continue;
            }
            if self.discarding {
                continue;
            }
            self.in_frame = true;
            let accepted = if self.block_left == 0 {
                // `byte` is a code byte; the block before it, if it implied a zero, was not the
                // last, so its zero is data.
                let ok = !self.zero_pending || self.store(0);
                self.block_left = byte - 1;
                self.zero_pending = byte != FULL_BLOCK_CODE;
                ok
            } else {
                self.block_left -= 1;
                self.store(byte)
            };
            if !accepted {
                self.stats.overflows = self.stats.overflows.saturating_add(1);
                on_packet(Err(FrameError::Overflow));
                self.reset();
                self.discarding = true;
            }
        }
    }

    /// Appends a decoded byte; false when the buffer is full.
    fn store(&mut self, byte: u8) -> bool {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = byte;
                self.len += 1;
                true
            }
            None => false,
        }
    }

    /// Checks the frame just ended by a delimiter and returns its packet length.
    fn check_frame(&mut self) -> Result<usize, FrameError> {
        if self.block_left != 0 {
            self.stats.cobs_errors = self.stats.cobs_errors.saturating_add(1);
            return Err(FrameError::Cobs);
        }
        let decoded = self.buf.get(..self.len).unwrap_or_default();
        let Some(packet_len) = decoded.len().checked_sub(CRC_BYTES) else {
            self.stats.crc_errors = self.stats.crc_errors.saturating_add(1);
            return Err(FrameError::Crc);
        };
        let (packet, crc) = decoded.split_at(packet_len);
        let expected = CRC32.checksum(packet).to_le_bytes();
        if crc != expected.as_slice() {
            self.stats.crc_errors = self.stats.crc_errors.saturating_add(1);
            return Err(FrameError::Crc);
        }
        Ok(packet_len)
    }

    fn reset(&mut self) {
        self.len = 0;
        self.block_left = 0;
        self.zero_pending = false;
        self.in_frame = false;
        self.discarding = false;
    }
}

impl<const N: usize> Default for StreamDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> core::fmt::Debug for StreamDecoder<N> {
    // The buffer holds a partial frame of no use in a log; its fill level is.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StreamDecoder")
            .field("capacity", &N)
            .field("buffered", &self.len)
            .field("discarding", &self.discarding)
            .field("stats", &self.stats)
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cobs(data: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
        let mut writer = CobsWriter::new(out);
        for &byte in data {
            writer.push(byte)?;
        }
        writer.finish()
    }

    /// Published COBS examples (Cheshire and Baker's scheme as commonly tabulated).
    #[test]
    fn cobs_matches_reference_vectors() -> Result<(), FrameError> {
        let mut out = [0u8; 300];
        let cases: [(&[u8], &[u8]); 5] = [
            (&[], &[0x01]),
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
        ];
        for (data, expected) in cases {
            let len = cobs(data, &mut out)?;
            assert_eq!(&out[..len], expected);
        }

        // 254 non-zero bytes: one full block, no trailing empty block.
        let data: [u8; 254] = core::array::from_fn(|i| (i + 1) as u8);
        let len = cobs(&data, &mut out)?;
        assert_eq!(len, 255);
        assert_eq!(out[0], 0xFF);
        assert_eq!(&out[1..255], &data[..]);

        // 0x00 then 254 non-zero bytes.
        let mut data = [0u8; 255];
        for (i, byte) in data.iter_mut().enumerate().skip(1) {
            *byte = i as u8;
        }
        let len = cobs(&data, &mut out)?;
        assert_eq!(len, 256);
        assert_eq!(&out[..2], &[0x01, 0xFF]);

        // 255 non-zero bytes: a full block and a block of one.
        let data: [u8; 255] = core::array::from_fn(|i| (i % 255 + 1) as u8);
        let len = cobs(&data, &mut out)?;
        assert_eq!(len, 257);
        assert_eq!(out[0], 0xFF);
        assert_eq!(&out[255..257], &[0x02, 0xFF]);
        Ok(())
    }

    #[test]
    fn cobs_worst_case_is_exact() -> Result<(), FrameError> {
        let mut out = [0u8; 1200];
        let data = [0x5Au8; 1100];
        for n in 0..=data.len() {
            let len = cobs(&data[..n], &mut out)?;
            assert_eq!(len, cobs_max_len(n), "n = {n}");
            // Zeros never cost more than non-zero bytes.
            let mut with_zeros = [0x5Au8; 1100];
            for byte in with_zeros.iter_mut().step_by(7) {
                *byte = 0;
            }
            assert!(cobs(&with_zeros[..n], &mut out)? <= cobs_max_len(n));
        }
        Ok(())
    }

    #[test]
    fn crc_is_iso_hdlc() {
        assert_eq!(CRC32.checksum(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn exact_buffer_suffices_and_one_less_does_not() -> Result<(), FrameError> {
        let packet = [0x42u8; 300];
        let mut out = [0u8; 400];
        let len = encode_frame(&packet, &mut out)?;
        let mut exact = [0u8; 400];
        assert_eq!(encode_frame(&packet, &mut exact[..len])?, len);
        assert_eq!(encode_frame(&packet, &mut exact[..len - 1]), Err(FrameError::BufferTooSmall));
        Ok(())
    }
}
