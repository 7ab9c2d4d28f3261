//! Recording of bus messages, and their replay.
//!
//! # Log format (version 1, little-endian)
//!
//! ```text
//! file   = "ROVERREC" (8 bytes) · version u32 · reserved u32 (0) · record*
//! record = recv_stamp_ns u64 · topic code u8 (`Topic::code`) · 3 zero bytes
//!          · header_len u32 · payload_len u32 · header bytes · payload bytes
//!          · CRC-32 (ISO-HDLC) u32 of everything before it in the record
//! ```
//!
//! `header` is the topic's fixed-size payload struct (`ImuMsg`, …, or the user header of a slice
//! topic) as its exact `#[repr(C)]` bytes; `payload` is the slice of a slice topic (stereo pixels,
//! disparity pixels, team messages) and empty otherwise. Every length is checked against the
//! topic's type on reading, and no record may exceed [`MAX_HEADER_BYTES`] /
//! [`MAX_PAYLOAD_BYTES`], so a corrupt length cannot make the reader allocate without bound.
//!
//! The reader is total: any byte string gives records, then either a clean end (the input ends
//! on a record boundary) or one [`RecordError`], never a panic.
//!
//! # Replay
//!
//! - [`replay_into`]: publishes the recorded messages of chosen topics, in order, unchanged
//!   (exact replay of recorded outputs; pacing is the caller's).
//! - [`rerun`]: re-runs a node on the recorded inputs it subscribes to. Ticks are not recorded
//!   (the recorder sees the bus, not the processes' task releases): the node's `on_tick` is
//!   called on the grid `k · tick_period_ns` of the receive-time axis, from the first recorded
//!   stamp to the first grid time at or after the last one. Messages received at or before a
//!   tick time are handled before that tick, as in the process runner, where a release first
//!   drains its subscribers.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::Path;

use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, HazardCellsMsg,
    HeadCommandMsg, ImuMsg, MarkerMsg, StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg, WheelOdomMsg,
};
use protocol::crc::CRC32;

use crate::nodes::{Message, Node, NodeError, Outbox, Topic};

pub const MAGIC: [u8; 8] = *b"ROVERREC";
pub const VERSION: u32 = 1;
pub const FILE_HEADER_BYTES: usize = 16;
/// Stamp, topic, padding, two lengths.
pub const RECORD_PREFIX_BYTES: usize = 20;
pub const RECORD_CRC_BYTES: usize = 4;
pub const MAX_HEADER_BYTES: u32 = 4096;
/// Larger than a 4096×4096 stereo pair.
pub const MAX_PAYLOAD_BYTES: u32 = 64 << 20;

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("recording I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a rover recording (bad magic)")]
    BadMagic,
    #[error("recording version {0} is not supported (this build reads version {VERSION})")]
    UnsupportedVersion(u32),
    #[error("record at byte {offset}: truncated")]
    Truncated { offset: u64 },
    #[error("record at byte {offset}: CRC mismatch")]
    Crc { offset: u64 },
    #[error("record at byte {offset}: unknown topic code {code}")]
    UnknownTopic { offset: u64, code: u8 },
    #[error("record at byte {offset}: {reason}")]
    Malformed { offset: u64, reason: String },
    #[error("{topic:?} message cannot be recorded: {reason}")]
    Unrecordable { topic: Topic, reason: String },
}

/// A message in owned, aligned storage (a recorded or collected copy of a [`Message`]).
#[derive(Debug, Clone, PartialEq)]
pub enum OwnedMessage {
    Imu(ImuMsg),
    WheelOdom(WheelOdomMsg),
    Stereo(StereoHeader, Vec<u8>),
    Disparity(DisparityHeader, Vec<DisparityPixel>),
    VoDelta(VoDeltaMsg),
    Marker(MarkerMsg),
    FilterState(FilterStateMsg),
    FrameSwitchRequest(FrameSwitchRequestMsg),
    FrameSwitch(FrameSwitchMsg),
    ToComms(TeamHeader, Vec<u8>),
    ToMapper(TeamHeader, Vec<u8>),
    TaskStats(TaskStatsMsg),
    HeadCommand(HeadCommandMsg),
    /// Boxed: 4 KiB of cells would make every message that large.
    Hazards(Box<HazardCellsMsg>),
}

impl OwnedMessage {
    pub fn from_message(message: &Message<'_>) -> OwnedMessage {
        match *message {
            Message::Imu(m) => OwnedMessage::Imu(*m),
            Message::WheelOdom(m) => OwnedMessage::WheelOdom(*m),
            Message::Stereo(h, p) => OwnedMessage::Stereo(*h, p.to_vec()),
            Message::Disparity(h, p) => OwnedMessage::Disparity(*h, p.to_vec()),
            Message::VoDelta(m) => OwnedMessage::VoDelta(*m),
            Message::Marker(m) => OwnedMessage::Marker(*m),
            Message::FilterState(m) => OwnedMessage::FilterState(*m),
            Message::FrameSwitchRequest(m) => OwnedMessage::FrameSwitchRequest(*m),
            Message::FrameSwitch(m) => OwnedMessage::FrameSwitch(*m),
            Message::ToComms(h, p) => OwnedMessage::ToComms(*h, p.to_vec()),
            Message::ToMapper(h, p) => OwnedMessage::ToMapper(*h, p.to_vec()),
            Message::TaskStats(m) => OwnedMessage::TaskStats(*m),
            Message::HeadCommand(m) => OwnedMessage::HeadCommand(*m),
            Message::Hazards(m) => OwnedMessage::Hazards(Box::new(*m)),
        }
    }

    pub fn as_message(&self) -> Message<'_> {
        match self {
            OwnedMessage::Imu(m) => Message::Imu(m),
            OwnedMessage::WheelOdom(m) => Message::WheelOdom(m),
            OwnedMessage::Stereo(h, p) => Message::Stereo(h, p),
            OwnedMessage::Disparity(h, p) => Message::Disparity(h, p),
            OwnedMessage::VoDelta(m) => Message::VoDelta(m),
            OwnedMessage::Marker(m) => Message::Marker(m),
            OwnedMessage::FilterState(m) => Message::FilterState(m),
            OwnedMessage::FrameSwitchRequest(m) => Message::FrameSwitchRequest(m),
            OwnedMessage::FrameSwitch(m) => Message::FrameSwitch(m),
            OwnedMessage::ToComms(h, p) => Message::ToComms(h, p),
            OwnedMessage::ToMapper(h, p) => Message::ToMapper(h, p),
            OwnedMessage::TaskStats(m) => Message::TaskStats(m),
            OwnedMessage::HeadCommand(m) => Message::HeadCommand(m),
            OwnedMessage::Hazards(m) => Message::Hazards(m),
        }
    }

    pub fn topic(&self) -> Topic {
        self.as_message().topic()
    }
}

/// One record: a message and when it was received.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    /// Receive time on the recorder's time axis (the mission's sensor time in both runners).
    pub recv_stamp_ns: u64,
    pub owned: OwnedMessage,
}

impl RecordedMessage {
    pub fn from_message(recv_stamp_ns: u64, message: &Message<'_>) -> RecordedMessage {
        RecordedMessage { recv_stamp_ns, owned: OwnedMessage::from_message(message) }
    }

    pub fn message(&self) -> Message<'_> {
        self.owned.as_message()
    }

    pub fn topic(&self) -> Topic {
        self.owned.topic()
    }
}

/// The header and payload bytes of a message, checked for consistency.
fn message_bytes<'a>(message: &Message<'a>) -> Result<(&'a [u8], &'a [u8]), String> {
    use bytemuck::{bytes_of, cast_slice};
    let parts: (&[u8], &[u8]) = match *message {
        Message::Imu(m) => (bytes_of(m), &[]),
        Message::WheelOdom(m) => (bytes_of(m), &[]),
        Message::Stereo(h, p) => {
            check_image_len(h.width_px, h.height_px, 2, p.len())?;
            (bytes_of(h), p)
        }
        Message::Disparity(h, p) => {
            check_image_len(h.width_px, h.height_px, 1, p.len())?;
            (bytes_of(h), cast_slice(p))
        }
        Message::VoDelta(m) => (bytes_of(m), &[]),
        Message::Marker(m) => (bytes_of(m), &[]),
        Message::FilterState(m) => (bytes_of(m), &[]),
        Message::FrameSwitchRequest(m) => (bytes_of(m), &[]),
        Message::FrameSwitch(m) => (bytes_of(m), &[]),
        Message::ToComms(h, p) | Message::ToMapper(h, p) => (bytes_of(h), p),
        Message::TaskStats(m) => (bytes_of(m), &[]),
        Message::HeadCommand(m) => (bytes_of(m), &[]),
        Message::Hazards(m) => (bytes_of(m), &[]),
    };
    if parts.1.len() > MAX_PAYLOAD_BYTES as usize {
        return Err(format!("payload of {} bytes exceeds {MAX_PAYLOAD_BYTES}", parts.1.len()));
    }
    Ok(parts)
}

/// `elements` must be `images · width · height`.
fn check_image_len(width_px: u32, height_px: u32, images: u64, elements: usize) -> Result<(), String> {
    let expected = u64::from(width_px).checked_mul(u64::from(height_px)).and_then(|n| n.checked_mul(images));
    if expected == Some(elements as u64) {
        Ok(())
    } else {
        Err(format!("{elements} elements for {images} image(s) of {width_px}×{height_px}"))
    }
}

fn read_header<T: bytemuck::AnyBitPattern>(header: &[u8]) -> Result<T, String> {
    bytemuck::try_pod_read_unaligned(header)
        .map_err(|_| format!("header of {} bytes, the type has {}", header.len(), size_of::<T>()))
}

fn no_payload(payload: &[u8]) -> Result<(), String> {
    if payload.is_empty() { Ok(()) } else { Err(format!("unexpected payload of {} bytes", payload.len())) }
}

/// Rebuilds an owned message from its recorded bytes (copied into aligned storage).
fn decode(topic: Topic, header: &[u8], payload: &[u8]) -> Result<OwnedMessage, String> {
    let fixed = |payload: &[u8]| no_payload(payload);
    Ok(match topic {
        Topic::Imu => {
            fixed(payload)?;
            OwnedMessage::Imu(read_header(header)?)
        }
        Topic::WheelOdom => {
            fixed(payload)?;
            OwnedMessage::WheelOdom(read_header(header)?)
        }
        Topic::Stereo => {
            let h: StereoHeader = read_header(header)?;
            check_image_len(h.width_px, h.height_px, 2, payload.len())?;
            OwnedMessage::Stereo(h, payload.to_vec())
        }
        Topic::Disparity => {
            let h: DisparityHeader = read_header(header)?;
            let pixel = size_of::<DisparityPixel>();
            if !payload.len().is_multiple_of(pixel) {
                return Err(format!("disparity payload of {} bytes is not whole pixels", payload.len()));
            }
            check_image_len(h.width_px, h.height_px, 1, payload.len() / pixel)?;
            OwnedMessage::Disparity(h, bytemuck::pod_collect_to_vec(payload))
        }
        Topic::VoDelta => {
            fixed(payload)?;
            OwnedMessage::VoDelta(read_header(header)?)
        }
        Topic::Marker => {
            fixed(payload)?;
            OwnedMessage::Marker(read_header(header)?)
        }
        Topic::FilterState => {
            fixed(payload)?;
            OwnedMessage::FilterState(read_header(header)?)
        }
        Topic::FrameSwitchRequest => {
            fixed(payload)?;
            OwnedMessage::FrameSwitchRequest(read_header(header)?)
        }
        Topic::FrameSwitch => {
            fixed(payload)?;
            OwnedMessage::FrameSwitch(read_header(header)?)
        }
        Topic::ToComms => OwnedMessage::ToComms(read_header(header)?, payload.to_vec()),
        Topic::ToMapper => OwnedMessage::ToMapper(read_header(header)?, payload.to_vec()),
        Topic::TaskStats => {
            fixed(payload)?;
            OwnedMessage::TaskStats(read_header(header)?)
        }
        Topic::HeadCommand => {
            fixed(payload)?;
            OwnedMessage::HeadCommand(read_header(header)?)
        }
        Topic::Hazards => {
            fixed(payload)?;
            OwnedMessage::Hazards(Box::new(read_header(header)?))
        }
    })
}

/// Appends records to a log.
#[derive(Debug)]
pub struct Recorder<W: Write> {
    out: W,
    records: u64,
    bytes: u64,
}

impl Recorder<BufWriter<File>> {
    /// Creates (truncates) the log at `path`.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        Recorder::new(BufWriter::new(File::create(path)?))
    }
}

impl<W: Write> Recorder<W> {
    /// Writes the file header.
    pub fn new(mut out: W) -> Result<Self, RecordError> {
        out.write_all(&MAGIC)?;
        out.write_all(&VERSION.to_le_bytes())?;
        out.write_all(&0u32.to_le_bytes())?;
        Ok(Recorder { out, records: 0, bytes: FILE_HEADER_BYTES as u64 })
    }

    pub fn append(&mut self, recv_stamp_ns: u64, message: &Message<'_>) -> Result<(), RecordError> {
        let topic = message.topic();
        let (header, payload) = message_bytes(message).map_err(|reason| RecordError::Unrecordable { topic, reason })?;
        let mut prefix = [0u8; RECORD_PREFIX_BYTES];
        prefix[0..8].copy_from_slice(&recv_stamp_ns.to_le_bytes());
        prefix[8] = topic.code();
        prefix[12..16].copy_from_slice(&(header.len() as u32).to_le_bytes());
        prefix[16..20].copy_from_slice(&(payload.len() as u32).to_le_bytes());
        let mut digest = CRC32.digest();
        digest.update(&prefix);
        digest.update(header);
        digest.update(payload);
        self.out.write_all(&prefix)?;
        self.out.write_all(header)?;
        self.out.write_all(payload)?;
        self.out.write_all(&digest.finalize().to_le_bytes())?;
        self.records += 1;
        self.bytes += (RECORD_PREFIX_BYTES + header.len() + payload.len() + RECORD_CRC_BYTES) as u64;
        Ok(())
    }

    pub fn append_recorded(&mut self, record: &RecordedMessage) -> Result<(), RecordError> {
        self.append(record.recv_stamp_ns, &record.message())
    }

    pub fn records(&self) -> u64 {
        self.records
    }

    /// Bytes written, file header included.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.out.flush()?;
        Ok(())
    }

    /// Flushes and returns the writer.
    pub fn into_inner(mut self) -> Result<W, RecordError> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// Reads a log record by record; see the module docs for what it guarantees on bad input.
/// As an iterator it yields `Ok` records, then at most one `Err`, then ends.
#[derive(Debug)]
pub struct RecordReader<R: Read> {
    input: R,
    /// Bytes consumed, for error positions.
    offset: u64,
    finished: bool,
}

impl RecordReader<BufReader<File>> {
    pub fn open(path: &Path) -> Result<Self, RecordError> {
        RecordReader::new(BufReader::new(File::open(path)?))
    }
}

impl<R: Read> RecordReader<R> {
    /// Reads and checks the file header.
    pub fn new(mut input: R) -> Result<Self, RecordError> {
        let mut header = [0u8; FILE_HEADER_BYTES];
        let got = read_full(&mut input, &mut header)?;
        if got < MAGIC.len() || header[..MAGIC.len()] != MAGIC {
            return Err(RecordError::BadMagic);
        }
        if got < FILE_HEADER_BYTES {
            return Err(RecordError::Truncated { offset: 0 });
        }
        let version = u32::from_le_bytes([header[8], header[9], header[10], header[11]]);
        if version != VERSION {
            return Err(RecordError::UnsupportedVersion(version));
        }
        Ok(RecordReader { input, offset: FILE_HEADER_BYTES as u64, finished: false })
    }

    /// The next record; `Ok(None)` at a clean end. After an error the reader stays finished.
    pub fn next_record(&mut self) -> Result<Option<RecordedMessage>, RecordError> {
        if self.finished {
            return Ok(None);
        }
        let result = self.read_record();
        if !matches!(result, Ok(Some(_))) {
            self.finished = true;
        }
        result
    }

    fn read_record(&mut self) -> Result<Option<RecordedMessage>, RecordError> {
        let offset = self.offset;
        let mut prefix = [0u8; RECORD_PREFIX_BYTES];
        match read_full(&mut self.input, &mut prefix)? {
            0 => return Ok(None),
            RECORD_PREFIX_BYTES => {}
            _ => return Err(RecordError::Truncated { offset }),
        }
        let u32_at = |i: usize| u32::from_le_bytes([prefix[i], prefix[i + 1], prefix[i + 2], prefix[i + 3]]);
        let header_len = u32_at(12);
        let payload_len = u32_at(16);
        if header_len > MAX_HEADER_BYTES || payload_len > MAX_PAYLOAD_BYTES {
            return Err(RecordError::Malformed {
                offset,
                reason: format!("header {header_len} / payload {payload_len} bytes exceed the limits"),
            });
        }
        let body_len = header_len as u64 + payload_len as u64;
        // Grows with what is actually there: a truncated file claiming 64 MiB reads what it has.
        let mut body = Vec::new();
        let got = (&mut self.input).take(body_len).read_to_end(&mut body)?;
        let mut crc_bytes = [0u8; RECORD_CRC_BYTES];
        if (got as u64) < body_len || read_full(&mut self.input, &mut crc_bytes)? < RECORD_CRC_BYTES {
            return Err(RecordError::Truncated { offset });
        }
        let mut digest = CRC32.digest();
        digest.update(&prefix);
        digest.update(&body);
        if digest.finalize() != u32::from_le_bytes(crc_bytes) {
            return Err(RecordError::Crc { offset });
        }
        let code = prefix[8];
        let topic = Topic::from_code(code).ok_or(RecordError::UnknownTopic { offset, code })?;
        let (header, payload) = body.split_at(header_len as usize);
        let owned = decode(topic, header, payload).map_err(|reason| RecordError::Malformed { offset, reason })?;
        let recv_stamp_ns = u64::from_le_bytes([
            prefix[0], prefix[1], prefix[2], prefix[3], prefix[4], prefix[5], prefix[6], prefix[7],
        ]);
        self.offset += (RECORD_PREFIX_BYTES + body.len() + RECORD_CRC_BYTES) as u64;
        Ok(Some(RecordedMessage { recv_stamp_ns, owned }))
    }
}

impl<R: Read> Iterator for RecordReader<R> {
    type Item = Result<RecordedMessage, RecordError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_record().transpose()
    }
}

/// Reads until `buf` is full or the input ends; returns the bytes read.
fn read_full(input: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match input.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error(transparent)]
    Node(#[from] NodeError),
    /// Receive stamps jump by more than [`MAX_TICKS_PER_GAP`] tick periods: ticking through it
    /// would not end in reasonable time.
    #[error("receive stamps jump from {from_ns} ns to {to_ns} ns")]
    StampGap { from_ns: u64, to_ns: u64 },
}

pub const MAX_TICKS_PER_GAP: u64 = 10_000_000;

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplayCounts {
    /// Messages published ([`replay_into`]) or handed to the node ([`rerun`]).
    pub delivered: u64,
    /// Records of topics outside the filter (or outside the node's subscriptions in [`rerun`]).
    pub skipped: u64,
    /// `on_tick` calls ([`rerun`] only).
    pub ticks: u64,
}

/// Publishes every recorded message whose topic is in `topics` (all topics if it is empty),
/// in recorded order, unchanged.
pub fn replay_into<R: Read>(
    reader: RecordReader<R>,
    out: &mut dyn Outbox,
    topics: &[Topic],
) -> Result<ReplayCounts, ReplayError> {
    let mut counts = ReplayCounts::default();
    for record in reader {
        let record = record?;
        if topics.is_empty() || topics.contains(&record.topic()) {
            out.publish(record.message())?;
            counts.delivered += 1;
        } else {
            counts.skipped += 1;
        }
    }
    Ok(counts)
}

/// An outbox that keeps owned copies of what is published, stamped with `now_ns`.
#[derive(Debug, Default)]
pub struct CollectingOutbox {
    /// Receive stamp given to the next published messages.
    pub now_ns: u64,
    pub messages: Vec<RecordedMessage>,
}

impl Outbox for CollectingOutbox {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        self.messages.push(RecordedMessage::from_message(self.now_ns, &message));
        Ok(())
    }
}

/// Re-runs `node` on the recorded messages of its subscriptions (tick rule in the module docs)
/// and returns what it published, stamped with the time it was published at (the message's
/// receive stamp, or the tick time).
pub fn rerun<R: Read>(
    node: &mut dyn Node,
    reader: RecordReader<R>,
    tick_period_ns: u64,
) -> Result<(Vec<RecordedMessage>, ReplayCounts), ReplayError> {
    let period = tick_period_ns.max(1);
    let subscriptions = node.subscriptions();
    let mut out = CollectingOutbox::default();
    let mut counts = ReplayCounts::default();
    let mut next_tick_ns: Option<u64> = None;
    for record in reader {
        let record = record?;
        if !subscriptions.contains(&record.topic()) {
            counts.skipped += 1;
            continue;
        }
        let t = record.recv_stamp_ns;
        let tick = next_tick_ns.get_or_insert(t.div_ceil(period).saturating_mul(period));
        if t.saturating_sub(*tick) / period > MAX_TICKS_PER_GAP {
            return Err(ReplayError::StampGap { from_ns: *tick, to_ns: t });
        }
        while *tick < t {
            out.now_ns = *tick;
            node.on_tick(*tick, &mut out)?;
            counts.ticks += 1;
            *tick = tick.saturating_add(period);
        }
        out.now_ns = t;
        node.on_message(record.message(), &mut out)?;
        counts.delivered += 1;
    }
    if let Some(tick) = next_tick_ns {
        out.now_ns = tick;
        node.on_tick(tick, &mut out)?;
        counts.ticks += 1;
    }
    Ok((out.messages, counts))
}
