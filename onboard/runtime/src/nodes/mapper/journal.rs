//! The mapper's state on disk (DESIGN §3.4): finished own submaps as files, written atomically
//! (tmp + rename) before they are sent, and an append-only journal of every graph input.
//!
//! ```text
//! {state_dir}/submaps/{index:08}.subm   mapper::exchange encoding of own finished submap `index`
//! {state_dir}/journal.bin               records: len u32 | kind u8 | payload | crc32 u32 (LE)
//! ```
//! `len` counts kind and payload; the CRC covers them too. Each record is one `write` call on an
//! unbuffered file, so a `kill -9` leaves at most a torn last record, which parsing drops (and
//! counts); the journal is then cut back to its last good record before appending. No `fsync`:
//! the promise is "survives a process crash", not a power cut.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};

use protocol::crc::crc32;

/// Largest record accepted (protocol packets are ~1.1 kB; anything larger is corruption).
const MAX_RECORD_BYTES: usize = 1 << 16;

const KIND_OWN_SWITCH: u8 = 1;
const KIND_OWN_POSE: u8 = 2;
const KIND_PACKET: u8 = 3;
const KIND_SUBMAP_SENT: u8 = 4;
const KIND_ONLINE: u8 = 5;

/// One journal entry.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// A frame switch of the own filter; covariance in the filter convention.
    OwnSwitch { stamp_ns: u64, from_index: u32, t_old_new: Isometry3<f64>, covariance: Matrix6<f64> },
    /// An own filter pose entered into the graph; covariance in the graph convention.
    OwnPose { stamp_ns: u64, submap_index: u32, t_submap_body: Isometry3<f64>, covariance: Matrix6<f64> },
    /// A protocol packet: received from a peer, or an own loop closure as sent.
    Packet(Vec<u8>),
    /// All chunks of own submap `index` were handed to comms.
    SubmapSent(u32),
    /// A sample of the online trajectory.
    Online { stamp_ns: u64, t_global_body: Isometry3<f64> },
}

fn put_isometry(out: &mut Vec<u8>, t: &Isometry3<f64>) {
    let q = t.rotation.quaternion();
    for v in t.translation.vector.iter().chain([q.w, q.i, q.j, q.k].iter()) {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn put_matrix(out: &mut Vec<u8>, m: &Matrix6<f64>) {
    for v in m.iter() {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

impl Record {
    /// Appends the framed record to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let start = out.len();
        out.extend_from_slice(&[0; 4]);
        match self {
            Record::OwnSwitch { stamp_ns, from_index, t_old_new, covariance } => {
                out.push(KIND_OWN_SWITCH);
                out.extend_from_slice(&stamp_ns.to_le_bytes());
                out.extend_from_slice(&from_index.to_le_bytes());
                put_isometry(out, t_old_new);
                put_matrix(out, covariance);
            }
            Record::OwnPose { stamp_ns, submap_index, t_submap_body, covariance } => {
                out.push(KIND_OWN_POSE);
                out.extend_from_slice(&stamp_ns.to_le_bytes());
                out.extend_from_slice(&submap_index.to_le_bytes());
                put_isometry(out, t_submap_body);
                put_matrix(out, covariance);
            }
            Record::Packet(bytes) => {
                out.push(KIND_PACKET);
                out.extend_from_slice(bytes);
            }
            Record::SubmapSent(index) => {
                out.push(KIND_SUBMAP_SENT);
                out.extend_from_slice(&index.to_le_bytes());
            }
            Record::Online { stamp_ns, t_global_body } => {
                out.push(KIND_ONLINE);
                out.extend_from_slice(&stamp_ns.to_le_bytes());
                put_isometry(out, t_global_body);
            }
        }
        let len = (out.len() - start - 4) as u32;
        out[start..start + 4].copy_from_slice(&len.to_le_bytes());
        let crc = crc32(&out[start + 4..]);
        out.extend_from_slice(&crc.to_le_bytes());
    }

    fn decode(kind: u8, payload: &[u8]) -> Option<Record> {
        let mut r = Reader(payload);
        let record = match kind {
            KIND_OWN_SWITCH => Record::OwnSwitch {
                stamp_ns: r.u64()?,
                from_index: r.u32()?,
                t_old_new: r.isometry()?,
                covariance: r.matrix()?,
            },
            KIND_OWN_POSE => Record::OwnPose {
                stamp_ns: r.u64()?,
                submap_index: r.u32()?,
                t_submap_body: r.isometry()?,
                covariance: r.matrix()?,
            },
            KIND_PACKET => return Some(Record::Packet(payload.to_vec())),
            KIND_SUBMAP_SENT => Record::SubmapSent(r.u32()?),
            KIND_ONLINE => Record::Online { stamp_ns: r.u64()?, t_global_body: r.isometry()? },
            _ => return None,
        };
        r.0.is_empty().then_some(record)
    }
}

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, rest) = self.0.split_first_chunk::<N>()?;
        self.0 = rest;
        Some(*head)
    }

    fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_le_bytes)
    }

    fn u64(&mut self) -> Option<u64> {
        self.take().map(u64::from_le_bytes)
    }

    fn f64(&mut self) -> Option<f64> {
        self.take().map(f64::from_le_bytes).filter(|v| v.is_finite())
    }

    fn isometry(&mut self) -> Option<Isometry3<f64>> {
        let v: [f64; 7] = [self.f64()?, self.f64()?, self.f64()?, self.f64()?, self.f64()?, self.f64()?, self.f64()?];
        let q = Quaternion::new(v[3], v[4], v[5], v[6]);
        let norm_error = (q.norm() - 1.0).abs();
        if norm_error > 1e-6 {
            return None;
        }
        // A quaternion written from a unit one is taken as it is: renormalizing would move its
        // last bits, and a replay should give the same numbers as the run it replays.
        let rotation =
            if norm_error < 1e-12 { UnitQuaternion::new_unchecked(q) } else { UnitQuaternion::new_normalize(q) };
        Some(Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), rotation))
    }

    fn matrix(&mut self) -> Option<Matrix6<f64>> {
        let mut m = Matrix6::zeros();
        for v in m.iter_mut() {
            *v = self.f64()?;
        }
        Some(m)
    }
}

/// The records of a journal's bytes and where its good part ends. Total: any bytes give a
/// result; parsing stops at the first torn or corrupt record.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Parsed {
    pub records: Vec<Record>,
    /// Length of the well-formed prefix.
    pub valid_bytes: usize,
    /// Bytes after it (a torn or corrupt tail), ignored.
    pub ignored_bytes: usize,
}

pub fn parse(bytes: &[u8]) -> Parsed {
    let mut parsed = Parsed::default();
    let mut at = 0;
    while let Some(len_bytes) = bytes.get(at..at + 4) {
        let mut len = [0u8; 4];
        len.copy_from_slice(len_bytes);
        let len = u32::from_le_bytes(len) as usize;
        if len == 0 || len > MAX_RECORD_BYTES {
            break;
        }
        let Some(body) = bytes.get(at + 4..at + 4 + len) else { break };
        let Some(crc_bytes) = bytes.get(at + 4 + len..at + 8 + len) else { break };
        let mut crc = [0u8; 4];
        crc.copy_from_slice(crc_bytes);
        if crc32(body) != u32::from_le_bytes(crc) {
            break;
        }
        let Some(record) = Record::decode(body[0], &body[1..]) else { break };
        parsed.records.push(record);
        at += 8 + len;
    }
    parsed.valid_bytes = at;
    parsed.ignored_bytes = bytes.len() - at;
    parsed
}

/// The open state directory.
#[derive(Debug)]
pub struct StateDir {
    dir: PathBuf,
    journal: File,
    scratch: Vec<u8>,
}

/// What was found in a state directory.
#[derive(Debug, Default)]
pub struct Restored {
    pub journal: Parsed,
    /// Own submap files: index and bytes (not yet decoded).
    pub submaps: Vec<(u32, Vec<u8>)>,
    /// Files in `submaps/` that are not submap files (names not `{index}.subm`).
    pub foreign_files: usize,
}

impl StateDir {
    /// Opens (creating) `dir`, reads what a previous run left, and cuts a torn journal tail.
    pub fn open(dir: &Path) -> io::Result<(StateDir, Restored)> {
        let submaps = dir.join("submaps");
        fs::create_dir_all(&submaps)?;
        let mut restored = Restored::default();
        for entry in fs::read_dir(&submaps)? {
            let path = entry?.path();
            let index = path
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_suffix(".subm"))
                .and_then(|n| n.parse::<u32>().ok());
            match index {
                Some(index) => restored.submaps.push((index, fs::read(&path)?)),
                None if path.extension().is_some_and(|e| e == "tmp") => fs::remove_file(&path)?,
                None => restored.foreign_files += 1,
            }
        }
        restored.submaps.sort_by_key(|(index, _)| *index);
        let journal_path = dir.join("journal.bin");
        let bytes = match fs::read(&journal_path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == io::ErrorKind::NotFound => Vec::new(),
            Err(e) => return Err(e),
        };
        restored.journal = parse(&bytes);
        let journal = OpenOptions::new().create(true).append(true).open(&journal_path)?;
        if restored.journal.ignored_bytes > 0 {
            journal.set_len(restored.journal.valid_bytes as u64)?;
        }
        Ok((StateDir { dir: dir.to_path_buf(), journal, scratch: Vec::new() }, restored))
    }

    pub fn append(&mut self, record: &Record) -> io::Result<()> {
        self.scratch.clear();
        record.encode(&mut self.scratch);
        self.journal.write_all(&self.scratch)
    }

    /// Writes own submap `index` atomically.
    pub fn write_submap(&self, index: u32, bytes: &[u8]) -> io::Result<()> {
        let path = self.dir.join("submaps").join(format!("{index:08}.subm"));
        let tmp = path.with_extension("tmp");
        fs::write(&tmp, bytes)?;
        fs::rename(&tmp, &path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_a_torn_tail_is_cut() {
        let t = Isometry3::new(nalgebra::Vector3::new(1.0, -2.0, 0.5), nalgebra::Vector3::new(0.1, 0.2, 0.3));
        let records = vec![
            Record::OwnSwitch { stamp_ns: 5, from_index: 2, t_old_new: t, covariance: Matrix6::identity() * 0.5 },
            Record::OwnPose { stamp_ns: 7, submap_index: 3, t_submap_body: t, covariance: Matrix6::identity() },
            Record::Packet(vec![1, 2, 3]),
            Record::SubmapSent(9),
            Record::Online { stamp_ns: 11, t_global_body: t },
        ];
        let mut bytes = Vec::new();
        for r in &records {
            r.encode(&mut bytes);
        }
        let full = bytes.len();
        let parsed = parse(&bytes);
        assert_eq!(parsed.valid_bytes, full);
        assert_eq!(parsed.records.len(), records.len());
        assert_eq!(parsed.records, records);
        bytes.extend_from_slice(&[40, 0, 0, 0, 3, 1]);
        let parsed = parse(&bytes);
        assert_eq!((parsed.records.len(), parsed.valid_bytes, parsed.ignored_bytes), (5, full, 6));
    }
}
