//! Xbus framing: `FA BID MID LEN [EXTLEN_hi EXTLEN_lo] payload CS`.
//!
//! `LEN = 0xFF` announces a two-byte big-endian extended length (payloads over 254 bytes). The
//! checksum makes every byte after the preamble, itself included, sum to 0 modulo 256.
//!
//! [`XbusDecoder`] is total: it takes any bytes in any pieces, never panics, holds at most one
//! frame of the configured maximum, and recovers after garbage. When a candidate frame fails its
//! checksum (or announces a payload over the maximum), only its preamble is dropped and the
//! search for the next preamble restarts *inside* the rejected bytes, so a stray 0xFA in garbage
//! that announces a long frame cannot swallow the real frames that follow it.

/// First byte of every frame.
pub const PREAMBLE: u8 = 0xFA;
/// Bus id of messages to and from a single device ("master").
pub const BUS_ID_MASTER: u8 = 0xFF;
/// The length byte announcing an extended length.
const LEN_EXTENDED: u8 = 0xFF;
/// Largest payload the one-byte length carries.
pub const MAX_STANDARD_PAYLOAD_BYTES: usize = 254;
/// Largest payload the extended length carries.
pub const MAX_EXTENDED_PAYLOAD_BYTES: usize = u16::MAX as usize;
/// Default decoder bound on payloads: far above any MTData2 an MTi-10 sends (a few dozen bytes
/// per output), small enough that garbage announcing 64 KiB cannot stall the decoder.
pub const DEFAULT_MAX_PAYLOAD_BYTES: usize = 2048;

/// Preamble, bus id, message id and one length byte.
const HEADER_BYTES: usize = 4;
/// The header with the extended length.
const EXTENDED_HEADER_BYTES: usize = 6;

/// Wire length of a frame carrying `payload_len` bytes.
pub fn frame_len(payload_len: usize) -> usize {
    let header = if payload_len > MAX_STANDARD_PAYLOAD_BYTES { EXTENDED_HEADER_BYTES } else { HEADER_BYTES };
    header + payload_len + 1
}

/// Why a frame could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum XbusError {
    #[error("payload of {len} bytes exceeds the Xbus limit of {max}")]
    PayloadTooLarge { len: usize, max: usize },
}

/// Appends one frame to `out`.
pub fn encode_frame(bus_id: u8, mid: u8, payload: &[u8], out: &mut Vec<u8>) -> Result<(), XbusError> {
    let len = payload.len();
    if len > MAX_EXTENDED_PAYLOAD_BYTES {
        return Err(XbusError::PayloadTooLarge { len, max: MAX_EXTENDED_PAYLOAD_BYTES });
    }
    out.reserve(frame_len(len));
    let start = out.len();
    out.extend_from_slice(&[PREAMBLE, bus_id, mid]);
    if len > MAX_STANDARD_PAYLOAD_BYTES {
        out.push(LEN_EXTENDED);
        out.extend_from_slice(&(len as u16).to_be_bytes());
    } else {
        out.push(len as u8);
    }
    out.extend_from_slice(payload);
    let sum = out.get(start + 1..).unwrap_or_default().iter().fold(0u8, |sum, &b| sum.wrapping_add(b));
    out.push(sum.wrapping_neg());
    Ok(())
}

/// A decoded frame, borrowed from the decoder until its next call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct XbusFrame<'a> {
    pub bus_id: u8,
    pub mid: u8,
    pub payload: &'a [u8],
    /// Position of the frame's preamble in everything fed to the decoder since it was created.
    pub stream_offset: u64,
}

impl XbusFrame<'_> {
    /// Length of the frame on the wire.
    pub fn wire_len(&self) -> usize {
        frame_len(self.payload.len())
    }
}

/// What the decoder saw since it was created. Saturating, never wrapping.
///
/// Every byte fed ends up in exactly one place: in an accepted frame, in `bytes_skipped`, or
/// still buffered ([`XbusDecoder::buffered_len`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct XbusCounters {
    /// Frames accepted.
    pub frames: u64,
    /// Candidate frames whose checksum failed: bit errors, or a 0xFA in garbage.
    pub checksum_errors: u64,
    /// Candidate frames announcing a payload over the decoder's maximum.
    pub oversized: u64,
    /// Candidate frames with another bus id than the decoder accepts.
    pub foreign_bus_id: u64,
    /// Bytes dropped while searching for a frame (garbage, and the preamble of every rejected
    /// candidate).
    pub bytes_skipped: u64,
}

/// What the buffered candidate still needs.
enum Needed {
    /// More header bytes, to learn the length.
    Header(usize),
    /// The whole frame is this long.
    Frame { len: usize, header: usize },
    /// The announced payload exceeds the maximum.
    TooLong,
    /// The bus id is not the one accepted.
    Foreign,
}

/// Streaming Xbus decoder; see the module documentation.
#[derive(Debug, Clone)]
pub struct XbusDecoder {
    max_payload: usize,
    bus_id: Option<u8>,
    /// The candidate frame, starting with a preamble, or bytes left to search after a rejection.
    /// Never longer than one frame of `max_payload`.
    buf: Vec<u8>,
    /// Length of the frame returned last, still at the front of `buf` while it is borrowed.
    returned: usize,
    /// Stream offset of `buf[0]`.
    buf_offset: u64,
    counters: XbusCounters,
}

impl Default for XbusDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl XbusDecoder {
    /// A decoder accepting payloads up to [`DEFAULT_MAX_PAYLOAD_BYTES`].
    pub fn new() -> Self {
        Self::with_max_payload(DEFAULT_MAX_PAYLOAD_BYTES)
    }

    /// A decoder accepting payloads up to `max_payload` bytes (at most
    /// [`MAX_EXTENDED_PAYLOAD_BYTES`]).
    pub fn with_max_payload(max_payload: usize) -> Self {
        let max_payload = max_payload.min(MAX_EXTENDED_PAYLOAD_BYTES);
        XbusDecoder {
            max_payload,
            bus_id: None,
            buf: Vec::with_capacity(frame_len(max_payload)),
            returned: 0,
            buf_offset: 0,
            counters: XbusCounters::default(),
        }
    }

    /// Accepts only frames with `bus_id`. A candidate with another one is rejected at its second
    /// byte, so 255 of 256 preambles in garbage cost nothing, where otherwise each holds the
    /// real frames behind it until its announced length has arrived (up to a maximum frame).
    pub fn only_bus_id(mut self, bus_id: u8) -> Self {
        self.bus_id = Some(bus_id);
        self
    }

    pub fn max_payload(&self) -> usize {
        self.max_payload
    }

    /// Bytes held for an incomplete candidate: at most [`frame_len`] of the maximum payload.
    pub fn buffered_len(&self) -> usize {
        self.buf.len() - self.returned
    }

    pub fn counters(&self) -> XbusCounters {
        self.counters
    }

    /// Forgets any partial frame (counting its bytes as skipped), e.g. after reopening a port.
    pub fn reset(&mut self) {
        self.release_returned();
        let len = self.buf.len();
        self.drop_front(len);
    }

    /// Feeds `bytes`, calling `on_frame` for every frame completed.
    pub fn feed(&mut self, mut bytes: &[u8], mut on_frame: impl FnMut(XbusFrame<'_>)) {
        while let Some(frame) = self.next_frame(&mut bytes) {
            on_frame(frame);
        }
    }

    /// Consumes `input` up to the end of the next complete frame and returns it; `None` once all
    /// of `input` is consumed (or buffered) without completing one. Call again with the rest of
    /// `input` until it returns `None`.
    pub fn next_frame<'s>(&'s mut self, input: &mut &[u8]) -> Option<XbusFrame<'s>> {
        self.release_returned();
        loop {
            // Bytes left from a rejected candidate come first; they must start at a preamble.
            let skip = self.buf.iter().position(|&b| b == PREAMBLE).unwrap_or(self.buf.len());
            self.drop_front(skip);
            if self.buf.is_empty() {
                // Nothing buffered: skip garbage in the input without copying it.
                let skip = input.iter().position(|&b| b == PREAMBLE).unwrap_or(input.len());
                self.skip_input(input, skip);
                if input.is_empty() {
                    return None;
                }
            }
            match self.needed() {
                Needed::TooLong => {
                    bump(&mut self.counters.oversized);
                    self.drop_front(1);
                }
                Needed::Foreign => {
                    bump(&mut self.counters.foreign_bus_id);
                    self.drop_front(1);
                }
                Needed::Header(len) => {
                    if !self.fill(input, len) {
                        return None;
                    }
                }
                Needed::Frame { len, header } => {
                    if !self.fill(input, len) {
                        return None;
                    }
                    let sum = self.buf.get(1..len).unwrap_or_default().iter().fold(0u8, |s, &b| s.wrapping_add(b));
                    if sum == 0 {
                        bump(&mut self.counters.frames);
                        self.returned = len;
                        return Some(XbusFrame {
                            bus_id: self.buf.get(1).copied().unwrap_or_default(),
                            mid: self.buf.get(2).copied().unwrap_or_default(),
                            payload: self.buf.get(header..len - 1).unwrap_or_default(),
                            stream_offset: self.buf_offset,
                        });
                    }
                    bump(&mut self.counters.checksum_errors);
                    self.drop_front(1);
                }
            }
        }
    }

    /// What the candidate in `buf` (or, with `buf` empty, at the start of the input) needs.
    fn needed(&self) -> Needed {
        if let (Some(accepted), Some(&bus_id)) = (self.bus_id, self.buf.get(1))
            && bus_id != accepted
        {
            return Needed::Foreign;
        }
        let Some(&len_byte) = self.buf.get(HEADER_BYTES - 1) else {
            return Needed::Header(HEADER_BYTES);
        };
        let (payload, header) = if len_byte == LEN_EXTENDED {
            match (self.buf.get(HEADER_BYTES), self.buf.get(HEADER_BYTES + 1)) {
                (Some(&hi), Some(&lo)) => (usize::from(u16::from_be_bytes([hi, lo])), EXTENDED_HEADER_BYTES),
                _ => return Needed::Header(EXTENDED_HEADER_BYTES),
            }
        } else {
            (usize::from(len_byte), HEADER_BYTES)
        };
        if payload > self.max_payload {
            return Needed::TooLong;
        }
        Needed::Frame { len: header + payload + 1, header }
    }

    /// Moves input into `buf` until it holds `len` bytes; false if the input ran out first.
    fn fill(&mut self, input: &mut &[u8], len: usize) -> bool {
        let take = len.saturating_sub(self.buf.len()).min(input.len());
        let (head, tail) = input.split_at(take);
        self.buf.extend_from_slice(head);
        *input = tail;
        self.buf.len() >= len
    }

    fn release_returned(&mut self) {
        if self.returned > 0 {
            let len = self.returned.min(self.buf.len());
            self.buf.drain(..len);
            self.buf_offset = self.buf_offset.saturating_add(len as u64);
            self.returned = 0;
        }
    }

    /// Drops `len` buffered bytes as skipped.
    fn drop_front(&mut self, len: usize) {
        let len = len.min(self.buf.len());
        if len > 0 {
            self.buf.drain(..len);
            self.buf_offset = self.buf_offset.saturating_add(len as u64);
            self.counters.bytes_skipped = self.counters.bytes_skipped.saturating_add(len as u64);
        }
    }

    /// Skips `len` bytes of the input (with nothing buffered).
    fn skip_input(&mut self, input: &mut &[u8], len: usize) {
        let len = len.min(input.len());
        *input = input.get(len..).unwrap_or_default();
        self.buf_offset = self.buf_offset.saturating_add(len as u64);
        self.counters.bytes_skipped = self.counters.bytes_skipped.saturating_add(len as u64);
    }
}

fn bump(counter: &mut u64) {
    *counter = counter.saturating_add(1);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(decoder: &mut XbusDecoder, bytes: &[u8]) -> Vec<(u8, u8, Vec<u8>, u64)> {
        let mut frames = Vec::new();
        decoder.feed(bytes, |f| frames.push((f.bus_id, f.mid, f.payload.to_vec(), f.stream_offset)));
        frames
    }

    #[test]
    fn extended_length_is_big_endian_and_round_trips() {
        let payload: Vec<u8> = (0..300u16).map(|i| i as u8).collect();
        let mut wire = Vec::new();
        encode_frame(BUS_ID_MASTER, 0x36, &payload, &mut wire).unwrap();
        assert_eq!(&wire[..6], &[0xFA, 0xFF, 0x36, 0xFF, 0x01, 0x2C]);
        assert_eq!(wire.len(), frame_len(300));
        let frames = decode_all(&mut XbusDecoder::new(), &wire);
        assert_eq!(frames, vec![(0xFF, 0x36, payload, 0)]);
    }

    #[test]
    fn payload_of_254_uses_the_short_length_and_255_the_extended() {
        for (len, header) in [(254usize, 4usize), (255, 6)] {
            let mut wire = Vec::new();
            encode_frame(BUS_ID_MASTER, 1, &vec![7; len], &mut wire).unwrap();
            assert_eq!(wire.len(), header + len + 1);
            assert_eq!(decode_all(&mut XbusDecoder::new(), &wire).len(), 1);
        }
        let mut wire = Vec::new();
        let error = encode_frame(BUS_ID_MASTER, 1, &vec![0; 65536], &mut wire).unwrap_err();
        assert_eq!(error, XbusError::PayloadTooLarge { len: 65536, max: 65535 });
        assert!(wire.is_empty());
    }

    #[test]
    fn oversized_announcement_is_rejected_without_buffering_it() {
        let mut decoder = XbusDecoder::with_max_payload(16);
        let mut wire = vec![0xFA, 0xFF, 0x36, 0xFF, 0x10, 0x00];
        encode_frame(BUS_ID_MASTER, 0x31, &[], &mut wire).unwrap();
        let frames = decode_all(&mut decoder, &wire);
        assert_eq!(frames, vec![(0xFF, 0x31, vec![], 6)]);
        assert_eq!(decoder.counters().oversized, 1);
        assert_eq!(decoder.counters().bytes_skipped, 6);
    }

    #[test]
    fn a_foreign_bus_id_is_rejected_at_once() {
        // A preamble in garbage announcing 200 bytes, then a real frame straight after.
        let mut wire = vec![0xFA, 0x01, 0x36, 0xC8];
        encode_frame(BUS_ID_MASTER, 0x31, &[], &mut wire).unwrap();
        let mut decoder = XbusDecoder::new().only_bus_id(BUS_ID_MASTER);
        assert_eq!(decode_all(&mut decoder, &wire), vec![(0xFF, 0x31, vec![], 4)]);
        assert_eq!(decoder.counters().foreign_bus_id, 1);
        // Without the filter the false candidate holds the frame until 200 more bytes arrive.
        let mut decoder = XbusDecoder::new();
        assert!(decode_all(&mut decoder, &wire).is_empty());
        assert_eq!(decode_all(&mut decoder, &[0; 200]), vec![(0xFF, 0x31, vec![], 4)]);
    }

    #[test]
    fn a_frame_split_byte_by_byte_is_held_and_completed() {
        let mut wire = Vec::new();
        encode_frame(BUS_ID_MASTER, 0xC1, &[0x10, 0x20, 0xFF, 0xFF], &mut wire).unwrap();
        let mut decoder = XbusDecoder::new();
        let mut frames = Vec::new();
        for byte in &wire {
            frames.extend(decode_all(&mut decoder, std::slice::from_ref(byte)));
        }
        assert_eq!(frames, vec![(0xFF, 0xC1, vec![0x10, 0x20, 0xFF, 0xFF], 0)]);
        assert_eq!(decoder.buffered_len(), 0);
    }
}
