//! The ground-feed log: every protocol packet a ground station received (or a mission sent to
//! it), with its receive time, so a mission can be replayed in the ground station.
//!
//! File layout (little-endian):
//!
//! ```text
//! header   b"RVFEED01"
//! record   recv_ns u64 · source u8 · len u32 · packet [len] · CRC-32 (ISO-HDLC) of the record's
//!          bytes before it
//! ```
//!
//! `recv_ns` is mission time (the sensor clock of the run) in nanoseconds; `source` is the link
//! the packet came over (the sending robot's node id where known, 0 otherwise). The reader is
//! total: a damaged record (bad CRC, impossible length, cut-off tail) ends nothing but itself;
//! the reader resynchronizes on the next record whose CRC checks and counts the bytes it skipped.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use protocol::crc::CRC32;

/// The file's first bytes.
pub const FEED_LOG_MAGIC: &[u8; 8] = b"RVFEED01";
/// Records longer than this are not packets (the protocol's largest is far smaller).
pub const MAX_FEED_PACKET_BYTES: usize = 64 * 1024;
const PREFIX_BYTES: usize = 8 + 1 + 4;
const CRC_BYTES: usize = 4;

#[derive(Debug, thiserror::Error)]
pub enum FeedLogError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("packet of {0} bytes is larger than a feed-log record may be")]
    PacketTooLarge(usize),
    #[error("{0}: not a feed log (magic bytes missing)")]
    NotAFeedLog(PathBuf),
}

/// One received packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FeedRecord {
    pub recv_ns: u64,
    pub source: u8,
    pub packet: Vec<u8>,
}

/// What [`parse_feed_log`] recovered.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FeedLog {
    pub records: Vec<FeedRecord>,
    /// Bytes that belonged to no intact record.
    pub ignored_bytes: usize,
    /// Whether the input started with [`FEED_LOG_MAGIC`].
    pub has_magic: bool,
}

/// Appends records to a feed log file.
#[derive(Debug)]
pub struct FeedLogWriter {
    path: PathBuf,
    out: BufWriter<File>,
    records: u64,
}

impl FeedLogWriter {
    /// Creates (truncates) `path` and writes the header.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, FeedLogError> {
        let path = path.as_ref().to_owned();
        let io = |source| FeedLogError::Io { path: path.clone(), source };
        let mut out = BufWriter::new(File::create(&path).map_err(io)?);
        out.write_all(FEED_LOG_MAGIC).map_err(io)?;
        Ok(FeedLogWriter { path, out, records: 0 })
    }

    pub fn append(&mut self, recv_ns: u64, source: u8, packet: &[u8]) -> Result<(), FeedLogError> {
        let len = u32::try_from(packet.len())
            .ok()
            .filter(|&l| l as usize <= MAX_FEED_PACKET_BYTES)
            .ok_or(FeedLogError::PacketTooLarge(packet.len()))?;
        let mut prefix = [0u8; PREFIX_BYTES];
        prefix[..8].copy_from_slice(&recv_ns.to_le_bytes());
        prefix[8] = source;
        prefix[9..].copy_from_slice(&len.to_le_bytes());
        let mut digest = CRC32.digest();
        digest.update(&prefix);
        digest.update(packet);
        let crc = digest.finalize();
        let io = |source| FeedLogError::Io { path: self.path.clone(), source };
        self.out.write_all(&prefix).map_err(io)?;
        self.out.write_all(packet).map_err(io)?;
        self.out.write_all(&crc.to_le_bytes()).map_err(io)?;
        self.records += 1;
        Ok(())
    }

    pub fn flush(&mut self) -> Result<(), FeedLogError> {
        let path = &self.path;
        self.out.flush().map_err(|source| FeedLogError::Io { path: path.clone(), source })
    }

    pub fn records(&self) -> u64 {
        self.records
    }
}

impl Drop for FeedLogWriter {
    fn drop(&mut self) {
        // Best effort: an explicit `flush` reports errors; a dropped writer still saves its tail.
        let _ = self.out.flush();
    }
}

/// The intact record at the start of `bytes`, with its length in bytes.
fn record_at(bytes: &[u8]) -> Option<(FeedRecord, usize)> {
    let prefix = bytes.get(..PREFIX_BYTES)?;
    let mut stamp = [0u8; 8];
    stamp.copy_from_slice(&prefix[..8]);
    let mut len = [0u8; 4];
    len.copy_from_slice(&prefix[9..]);
    let len = u32::from_le_bytes(len) as usize;
    if len > MAX_FEED_PACKET_BYTES {
        return None;
    }
    let total = PREFIX_BYTES + len + CRC_BYTES;
    let record = bytes.get(..total)?;
    let mut crc = [0u8; CRC_BYTES];
    crc.copy_from_slice(&record[PREFIX_BYTES + len..]);
    if CRC32.checksum(&record[..PREFIX_BYTES + len]) != u32::from_le_bytes(crc) {
        return None;
    }
    let packet = record[PREFIX_BYTES..PREFIX_BYTES + len].to_vec();
    Some((FeedRecord { recv_ns: u64::from_le_bytes(stamp), source: prefix[8], packet }, total))
}

/// Parses a feed log from memory; never fails (see the module documentation).
pub fn parse_feed_log(bytes: &[u8]) -> FeedLog {
    let has_magic = bytes.starts_with(FEED_LOG_MAGIC);
    let mut at = if has_magic { FEED_LOG_MAGIC.len() } else { 0 };
    let mut log = FeedLog { has_magic, ..FeedLog::default() };
    while at < bytes.len() {
        match record_at(&bytes[at..]) {
            Some((record, len)) => {
                log.records.push(record);
                at += len;
            }
            None => {
                log.ignored_bytes += 1;
                at += 1;
            }
        }
    }
    log
}

/// Reads and parses a feed log file; a file without the magic bytes is refused.
pub fn read_feed_log(path: impl AsRef<Path>) -> Result<FeedLog, FeedLogError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| FeedLogError::Io { path: path.to_owned(), source })?;
    let log = parse_feed_log(&bytes);
    if !log.has_magic {
        return Err(FeedLogError::NotAFeedLog(path.to_owned()));
    }
    Ok(log)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use proptest::prelude::*;

    fn write(records: &[FeedRecord]) -> Vec<u8> {
        let dir = std::env::temp_dir().join(format!("feedlog-{}-{}", std::process::id(), records.len()));
        let path = dir.with_extension("log");
        let mut writer = FeedLogWriter::create(&path).unwrap();
        for r in records {
            writer.append(r.recv_ns, r.source, &r.packet).unwrap();
        }
        writer.flush().unwrap();
        drop(writer);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).ok();
        bytes
    }

    fn record(i: u8) -> FeedRecord {
        FeedRecord { recv_ns: 1_000_000 * u64::from(i), source: i % 3, packet: vec![i; usize::from(i) * 7] }
    }

    #[test]
    fn round_trip_and_file_errors() {
        let records: Vec<_> = (0..20).map(record).collect();
        let bytes = write(&records);
        let log = parse_feed_log(&bytes);
        assert_eq!(log.records, records);
        assert_eq!(log.ignored_bytes, 0);
        assert!(log.has_magic);
        let missing = read_feed_log("/nonexistent/feed.log").unwrap_err();
        assert!(missing.to_string().contains("/nonexistent/feed.log"), "{missing}");
    }

    #[test]
    fn a_damaged_record_loses_only_itself() {
        let records: Vec<_> = (1..6).map(record).collect();
        let mut bytes = write(&records);
        // Flip a byte inside the third record's packet.
        let third = FEED_LOG_MAGIC.len()
            + records[..2].iter().map(|r| PREFIX_BYTES + r.packet.len() + CRC_BYTES).sum::<usize>();
        bytes[third + PREFIX_BYTES + 2] ^= 0x55;
        let log = parse_feed_log(&bytes);
        let expected: Vec<_> = records.iter().enumerate().filter(|(i, _)| *i != 2).map(|(_, r)| r.clone()).collect();
        assert_eq!(log.records, expected);
        assert_eq!(log.ignored_bytes, PREFIX_BYTES + records[2].packet.len() + CRC_BYTES);
        // A cut-off tail: the last record is lost, the rest stays.
        let log = parse_feed_log(&bytes[..bytes.len() - 3]);
        assert_eq!(log.records.len(), expected.len() - 1);
    }

    proptest! {
        #[test]
        fn parser_is_total(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
            let log = parse_feed_log(&bytes);
            let used: usize = log.records.iter().map(|r| PREFIX_BYTES + r.packet.len() + CRC_BYTES).sum();
            let magic = if log.has_magic { FEED_LOG_MAGIC.len() } else { 0 };
            prop_assert_eq!(used + log.ignored_bytes + magic, bytes.len());
        }

        #[test]
        fn any_records_round_trip(packets in proptest::collection::vec(
            (any::<u64>(), any::<u8>(), proptest::collection::vec(any::<u8>(), 0..300)), 0..12)) {
            let mut bytes = FEED_LOG_MAGIC.to_vec();
            let mut records = Vec::new();
            for (recv_ns, source, packet) in packets {
                let mut prefix = [0u8; PREFIX_BYTES];
                prefix[..8].copy_from_slice(&recv_ns.to_le_bytes());
                prefix[8] = source;
                prefix[9..].copy_from_slice(&(packet.len() as u32).to_le_bytes());
                let mut digest = CRC32.digest();
                digest.update(&prefix);
                digest.update(&packet);
                bytes.extend_from_slice(&prefix);
                bytes.extend_from_slice(&packet);
                bytes.extend_from_slice(&digest.finalize().to_le_bytes());
                records.push(FeedRecord { recv_ns, source, packet });
            }
            let log = parse_feed_log(&bytes);
            prop_assert_eq!(log.records, records);
            prop_assert_eq!(log.ignored_bytes, 0);
        }
    }
}
