//! The filter process's checkpoint: what a restarted filter needs to go on where its predecessor
//! stopped (the whole [`FilterSnapshot`], the last IMU sequence it integrated, and the counters
//! carried across restarts), one file replaced atomically (tmp + rename), so a `kill -9` leaves
//! either the previous or the new checkpoint, never a torn one.
//!
//! ```text
//! magic "OBFC" | version u16 | run_id u64 | imu_sequence u64 | initialized_ns u64
//! | counters: n u8, n × u64 | stamp_ns u64 | frame_id u32 | pose (7 f64: t, q w i j k)
//! | v, b_a, b_g (3 × 3 f64) | last IMU: flag u8 [stamp u64, gyro 3 f64, accel 3 f64]
//! | last wheel: flag u8 [stamp u64] | clones: n u16, n × (stamp u64, pose, flags u8)
//! | covariance (15 + 6n)² f64, column-major | crc32 u32 of everything before
//! ```
//! Little endian. [`decode`] is total: any bytes give a checkpoint or an error.

use std::io;
use std::path::Path;

use filter::{CloneSnapshot, FilterSnapshot};
use hal::sensor::ImuSample;
use nalgebra::{DMatrix, Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

const MAGIC: &[u8; 4] = b"OBFC";
const VERSION: u16 = 1;
/// More clones than any filter configuration keeps: a larger count is corruption (and would
/// make the covariance allocation huge).
const MAX_CLONES: usize = 256;
const CORE: usize = 15;

/// Counters of [`super::FilterNodeSummary`] that continue across restarts, in file order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CarriedCounters {
    pub imu_received: u64,
    pub imu_lost: u64,
    pub imu_rejected: u64,
    pub vo_received: u64,
    pub vo_updates_applied: u64,
    pub wheel_updates_applied: u64,
    pub frame_switches: u64,
    pub resumes: u64,
}

impl CarriedCounters {
    fn to_array(self) -> [u64; 8] {
        [
            self.imu_received,
            self.imu_lost,
            self.imu_rejected,
            self.vo_received,
            self.vo_updates_applied,
            self.wheel_updates_applied,
            self.frame_switches,
            self.resumes,
        ]
    }

    /// Missing trailing counters (an older writer) are zero; extra ones are ignored.
    fn from_slice(v: &[u64]) -> Self {
        let at = |i: usize| v.get(i).copied().unwrap_or(0);
        CarriedCounters {
            imu_received: at(0),
            imu_lost: at(1),
            imu_rejected: at(2),
            vo_received: at(3),
            vo_updates_applied: at(4),
            wheel_updates_applied: at(5),
            frame_switches: at(6),
            resumes: at(7),
        }
    }
}

/// One checkpoint of the filter node.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterCheckpoint {
    /// The run it belongs to (the mission epoch): a checkpoint of another run is not resumed.
    pub run_id: u64,
    /// Sequence number of the last IMU sample the snapshot contains.
    pub imu_sequence: u64,
    pub initialized_ns: u64,
    pub counters: CarriedCounters,
    pub snapshot: FilterSnapshot,
}

/// Why a checkpoint file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: {source}")]
    Io { path: String, source: io::Error },
    #[error("checkpoint is truncated")]
    Truncated,
    #[error("not a filter checkpoint (bad magic)")]
    Magic,
    #[error("checkpoint version {0}, expected {VERSION}")]
    Version(u16),
    #[error("checkpoint CRC mismatch")]
    Crc,
    #[error("checkpoint has {0} clones")]
    Clones(usize),
    #[error("checkpoint holds an invalid value: {0}")]
    Invalid(&'static str),
    #[error("{0} trailing bytes after the checkpoint")]
    Trailing(usize),
}

fn put_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64s(out: &mut Vec<u8>, values: impl IntoIterator<Item = f64>) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn put_pose(out: &mut Vec<u8>, t: &Isometry3<f64>) {
    let q = t.rotation.quaternion();
    put_f64s(out, t.translation.vector.iter().copied().chain([q.w, q.i, q.j, q.k]));
}

/// Appends the encoded checkpoint to `out` (cleared first; its capacity is reused).
pub fn encode(checkpoint: &FilterCheckpoint, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    put_u64(out, checkpoint.run_id);
    put_u64(out, checkpoint.imu_sequence);
    put_u64(out, checkpoint.initialized_ns);
    let counters = checkpoint.counters.to_array();
    out.push(counters.len() as u8);
    for c in counters {
        put_u64(out, c);
    }
    let s = &checkpoint.snapshot;
    put_u64(out, s.stamp_ns);
    out.extend_from_slice(&s.frame_id.to_le_bytes());
    put_pose(out, &s.t_local_body);
    for v in [&s.v_local_mps, &s.accel_bias_mps2, &s.gyro_bias_radps] {
        put_f64s(out, v.iter().copied());
    }
    match &s.last_imu {
        Some(imu) => {
            out.push(1);
            put_u64(out, imu.stamp_ns);
            put_f64s(out, imu.gyro_radps.iter().chain(imu.accel_mps2.iter()).copied());
        }
        None => out.push(0),
    }
    match s.last_wheel_stamp_ns {
        Some(stamp) => {
            out.push(1);
            put_u64(out, stamp);
        }
        None => out.push(0),
    }
    // A snapshot never holds more than `max_clones` (a few dozen); `MAX_CLONES` caps the file.
    let clones = &s.clones[..s.clones.len().min(MAX_CLONES)];
    out.extend_from_slice(&(clones.len() as u16).to_le_bytes());
    for c in clones {
        put_u64(out, c.stamp_ns);
        put_pose(out, &c.t_local_body);
        out.push(u8::from(c.keyframe) | (u8::from(c.released) << 1));
    }
    let n = CORE + 6 * clones.len();
    if s.covariance.shape() == (n, n) {
        put_f64s(out, s.covariance.iter().copied());
    } else {
        // Not a filter's own snapshot; written so that the reader refuses it (non-finite).
        put_f64s(out, std::iter::repeat_n(f64::NAN, n * n));
    }
    let crc = protocol::crc::crc32(out);
    out.extend_from_slice(&crc.to_le_bytes());
}

struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], CheckpointError> {
        if self.bytes.len() < n {
            return Err(CheckpointError::Truncated);
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], CheckpointError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    fn u8(&mut self) -> Result<u8, CheckpointError> {
        Ok(self.array::<1>()?[0])
    }

    fn u16(&mut self) -> Result<u16, CheckpointError> {
        Ok(u16::from_le_bytes(self.array()?))
    }

    fn u32(&mut self) -> Result<u32, CheckpointError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    fn u64(&mut self) -> Result<u64, CheckpointError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    fn f64(&mut self) -> Result<f64, CheckpointError> {
        let v = f64::from_le_bytes(self.array()?);
        if v.is_finite() { Ok(v) } else { Err(CheckpointError::Invalid("non-finite number")) }
    }

    fn vector(&mut self) -> Result<Vector3<f64>, CheckpointError> {
        Ok(Vector3::new(self.f64()?, self.f64()?, self.f64()?))
    }

    fn pose(&mut self) -> Result<Isometry3<f64>, CheckpointError> {
        let t = self.vector()?;
        let q = Quaternion::new(self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        // Written from unit quaternions; anything far from unit length is corruption.
        if (q.norm() - 1.0).abs() > 1e-6 {
            return Err(CheckpointError::Invalid("quaternion not of unit length"));
        }
        // Kept bit for bit (no renormalization): a checkpoint resumes exactly.
        Ok(Isometry3::from_parts(Translation3::from(t), UnitQuaternion::new_unchecked(q)))
    }

    fn flag(&mut self) -> Result<bool, CheckpointError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(CheckpointError::Invalid("flag not 0 or 1")),
        }
    }
}

/// Decodes a checkpoint written by [`encode`].
pub fn decode(bytes: &[u8]) -> Result<FilterCheckpoint, CheckpointError> {
    if bytes.len() < MAGIC.len() + 2 + 4 {
        return Err(CheckpointError::Truncated);
    }
    if &bytes[..MAGIC.len()] != MAGIC {
        return Err(CheckpointError::Magic);
    }
    let (body, crc) = bytes.split_at(bytes.len() - 4);
    let mut r = Reader { bytes: &body[MAGIC.len()..] };
    let version = r.u16()?;
    if version != VERSION {
        return Err(CheckpointError::Version(version));
    }
    let mut crc_bytes = [0u8; 4];
    crc_bytes.copy_from_slice(crc);
    if protocol::crc::crc32(body) != u32::from_le_bytes(crc_bytes) {
        return Err(CheckpointError::Crc);
    }
    let run_id = r.u64()?;
    let imu_sequence = r.u64()?;
    let initialized_ns = r.u64()?;
    let n_counters = usize::from(r.u8()?);
    let mut counters = [0u64; 255];
    for c in counters.iter_mut().take(n_counters) {
        *c = r.u64()?;
    }
    let counters = CarriedCounters::from_slice(&counters[..n_counters]);
    let stamp_ns = r.u64()?;
    let frame_id = r.u32()?;
    let t_local_body = r.pose()?;
    let (v_local_mps, accel_bias_mps2, gyro_bias_radps) = (r.vector()?, r.vector()?, r.vector()?);
    let last_imu = if r.flag()? {
        Some(ImuSample { stamp_ns: r.u64()?, gyro_radps: r.vector()?, accel_mps2: r.vector()? })
    } else {
        None
    };
    let last_wheel_stamp_ns = if r.flag()? { Some(r.u64()?) } else { None };
    let n_clones = usize::from(r.u16()?);
    if n_clones > MAX_CLONES {
        return Err(CheckpointError::Clones(n_clones));
    }
    let mut clones = Vec::with_capacity(n_clones);
    for _ in 0..n_clones {
        let stamp_ns = r.u64()?;
        let t_local_body = r.pose()?;
        let flags = r.u8()?;
        if flags > 3 {
            return Err(CheckpointError::Invalid("clone flags"));
        }
        clones.push(CloneSnapshot { stamp_ns, t_local_body, keyframe: flags & 1 != 0, released: flags & 2 != 0 });
    }
    let n = CORE + 6 * n_clones;
    // Checked before allocating: the remaining bytes must hold the matrix.
    if r.bytes.len() < n * n * 8 {
        return Err(CheckpointError::Truncated);
    }
    let mut values = Vec::with_capacity(n * n);
    for _ in 0..n * n {
        values.push(r.f64()?);
    }
    if !r.bytes.is_empty() {
        return Err(CheckpointError::Trailing(r.bytes.len()));
    }
    Ok(FilterCheckpoint {
        run_id,
        imu_sequence,
        initialized_ns,
        counters,
        snapshot: FilterSnapshot {
            stamp_ns,
            frame_id,
            t_local_body,
            v_local_mps,
            accel_bias_mps2,
            gyro_bias_radps,
            last_imu,
            last_wheel_stamp_ns,
            clones,
            covariance: DMatrix::from_vec(n, n, values),
        },
    })
}

/// Writes `bytes` to `path` atomically: a crash leaves the old file or the new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

/// Reads the checkpoint at `path`; `Ok(None)` when there is none.
pub fn read(path: &Path) -> Result<Option<FilterCheckpoint>, CheckpointError> {
    match std::fs::read(path) {
        Ok(bytes) => decode(&bytes).map(Some),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(CheckpointError::Io { path: path.display().to_string(), source }),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use proptest::prelude::*;

    fn checkpoint(n_clones: usize, seed: f64) -> FilterCheckpoint {
        let pose = |k: f64| Isometry3::new(Vector3::new(k, -2.0 * k, 0.5), Vector3::new(0.1 * k, 0.2, -0.3));
        let n = CORE + 6 * n_clones;
        FilterCheckpoint {
            run_id: 123_456_789,
            imu_sequence: 4_242,
            initialized_ns: 500_000_000,
            counters: CarriedCounters {
                imu_received: 4_243,
                imu_lost: 2,
                imu_rejected: 1,
                vo_received: 200,
                vo_updates_applied: 190,
                wheel_updates_applied: 1_000,
                frame_switches: 3,
                resumes: 1,
            },
            snapshot: FilterSnapshot {
                stamp_ns: 21_210_000_000,
                frame_id: 3,
                t_local_body: pose(seed),
                v_local_mps: Vector3::new(0.3, seed, -0.01),
                accel_bias_mps2: Vector3::new(1e-3, -2e-3, 3e-3),
                gyro_bias_radps: Vector3::new(1e-5, 2e-5, -3e-5),
                last_imu: Some(ImuSample {
                    stamp_ns: 21_210_000_000,
                    gyro_radps: Vector3::new(0.01, 0.02, seed),
                    accel_mps2: Vector3::new(0.1, 0.0, 1.62),
                }),
                last_wheel_stamp_ns: n_clones.is_multiple_of(2).then_some(21_200_000_000),
                clones: (0..n_clones)
                    .map(|i| CloneSnapshot {
                        stamp_ns: 21_000_000_000 + i as u64 * 100_000_000,
                        t_local_body: pose(seed + i as f64),
                        keyframe: i == 0,
                        released: i % 2 == 1,
                    })
                    .collect(),
                covariance: DMatrix::from_fn(n, n, |i, j| if i == j { 1e-3 + seed.abs() } else { 1e-6 }),
            },
        }
    }

    #[test]
    fn round_trip_and_atomic_file() {
        let dir = std::env::temp_dir().join(format!("onboard-filter-checkpoint-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("filter.ckpt");
        assert!(read(&path).unwrap().is_none());
        let mut bytes = Vec::new();
        for n_clones in [0, 1, 5] {
            let c = checkpoint(n_clones, 0.7);
            encode(&c, &mut bytes);
            write_atomic(&path, &bytes).unwrap();
            assert!(!path.with_extension("tmp").exists());
            assert_eq!(read(&path).unwrap().unwrap(), c);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn damaged_files_are_refused() {
        let mut bytes = Vec::new();
        encode(&checkpoint(2, 0.1), &mut bytes);
        assert!(matches!(decode(&bytes[..bytes.len() - 1]), Err(CheckpointError::Crc)));
        assert!(matches!(decode(&bytes[..3]), Err(CheckpointError::Truncated)));
        let mut flipped = bytes.clone();
        flipped[40] ^= 0x10;
        assert!(matches!(decode(&flipped), Err(CheckpointError::Crc)));
        let mut magic = bytes.clone();
        magic[0] = b'X';
        assert!(matches!(decode(&magic), Err(CheckpointError::Magic)));
    }

    proptest! {
        #[test]
        fn decoding_any_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..2_000)) {
            let _ = decode(&bytes);
            let mut framed = b"OBFC\x01\x00".to_vec();
            framed.extend_from_slice(&bytes);
            let crc = protocol::crc::crc32(&framed);
            framed.extend_from_slice(&crc.to_le_bytes());
            let _ = decode(&framed);
        }

        #[test]
        fn valid_checkpoints_round_trip(n_clones in 0usize..8, seed in -10.0f64..10.0) {
            let c = checkpoint(n_clones, seed);
            let mut bytes = Vec::new();
            encode(&c, &mut bytes);
            prop_assert_eq!(decode(&bytes).unwrap(), c);
        }

        #[test]
        fn any_single_byte_change_is_detected(at in 0usize..10_000, xor in 1u8..=255) {
            let mut bytes = Vec::new();
            encode(&checkpoint(1, 0.3), &mut bytes);
            let at = at % bytes.len();
            bytes[at] ^= xor;
            prop_assert!(decode(&bytes).is_err());
        }
    }
}
