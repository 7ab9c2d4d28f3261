//! Between the front-end's measurements and the team protocol's messages, and the fragmentation
//! of finished submaps into [`SubmapHeader`] + [`SubmapChunk`]s and back.
//!
//! Pure conversions with no I/O, shared by the robots' mapper node and the ground station, which
//! must turn received messages into the same [`TeamGraph`](crate::slam::TeamGraph) measurements.
//!
//! Covariances travel in the graph convention (what [`TeamGraph`](crate::slam::TeamGraph)
//! takes), as `f32`: a receiver clamps them back to positive semi-definite, because rounding a
//! singular filter covariance (right after a frame switch) to `f32` can leave an eigenvalue a
//! hair below zero.

use std::collections::{BTreeMap, BTreeSet};

use crate::slam::{
    self, AttemptOutcome, FilterPose, LandmarkObservation, Measurement, RobotDetection, SubmapMatch, SubmapPair,
    SubmapSwitch,
};
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};
use protocol::message::{
    Constraint, ConstraintId, ConstraintKind, MatchAttempt, MatchOutcome, PoseEstimate, SUBMAP_CHUNK_BYTES,
    SubmapChunk, SubmapHeader, SubmapLink,
};
use protocol::{Cov6, NodeRef, Pose3, RobotId as WireRobot, SubmapId as WireSubmap};

/// [`SubmapHeader::encoding`] of payloads made by [`crate::exchange::encode_submap`].
pub const SUBMAP_ENCODING_EXCHANGE_V1: protocol::message::SubmapEncoding = protocol::message::SubmapEncoding(1);

/// CRC-32 (ISO-HDLC), the checksum of [`SubmapHeader::payload_crc32`]: the project's one
/// ([`protocol::crc`]).
pub use protocol::crc::crc32;

pub fn pose3(t: &Isometry3<f64>) -> Pose3 {
    let q = t.rotation.quaternion();
    Pose3 { translation_m: t.translation.vector.into(), rotation_wxyz: [q.w, q.i, q.j, q.k] }
}

/// The transform of a received pose, `None` unless finite with a unit quaternion.
pub fn isometry(p: &Pose3) -> Option<Isometry3<f64>> {
    if !p.is_valid() {
        return None;
    }
    let [w, x, y, z] = p.rotation_wxyz;
    let [tx, ty, tz] = p.translation_m;
    Some(Isometry3::from_parts(
        Translation3::new(tx, ty, tz),
        UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
    ))
}

pub fn cov6(c: &Matrix6<f64>) -> Cov6 {
    let full: [[f64; 6]; 6] = std::array::from_fn(|r| std::array::from_fn(|col| c[(r, col)]));
    Cov6::from_full(&full)
}

/// A received covariance as a matrix, `None` when not finite.
pub fn matrix(c: &Cov6) -> Option<Matrix6<f64>> {
    if !c.upper.iter().all(|v| v.is_finite()) {
        return None;
    }
    let full = c.to_full();
    Some(Matrix6::from_fn(|r, col| full[r][col]))
}

/// A received filter-derived covariance (may be singular): the nearest PSD matrix.
fn psd(c: &Cov6) -> Option<Matrix6<f64>> {
    matrix(c).map(|m| slam::covariance::clamp_eigenvalues(&m, 0.0))
}

pub fn wire_submap(id: slam::SubmapId) -> Option<WireSubmap> {
    Some(WireSubmap { robot: WireRobot(u8::try_from(id.robot).ok()?), index: id.index })
}

pub fn slam_submap(id: WireSubmap) -> slam::SubmapId {
    slam::SubmapId::new(u16::from(id.robot.0), id.index)
}

fn wire_robot(robot: slam::RobotId) -> Option<WireRobot> {
    u8::try_from(robot).ok().map(WireRobot)
}

pub fn pose_estimate(p: &FilterPose) -> Option<PoseEstimate> {
    Some(PoseEstimate {
        robot: wire_robot(p.robot)?,
        stamp_ns: p.stamp_ns,
        submap: wire_submap(slam::SubmapId::new(p.robot, p.submap_index))?,
        t_submap_body: pose3(&p.t_submap_body),
        covariance: cov6(&p.covariance),
    })
}

pub fn filter_pose(p: &PoseEstimate) -> Result<FilterPose, &'static str> {
    if p.submap.robot != p.robot {
        return Err("pose estimate in another robot's submap");
    }
    Ok(FilterPose {
        robot: u16::from(p.robot.0),
        stamp_ns: p.stamp_ns,
        submap_index: p.submap.index,
        t_submap_body: isometry(&p.t_submap_body).ok_or("pose estimate is not a pose")?,
        covariance: psd(&p.covariance).ok_or("pose estimate covariance is not finite")?,
    })
}

/// The protocol message of a loop-closure measurement (`None` for frame switches and filter
/// poses, which travel otherwise, and for robot ids beyond the protocol's range).
pub fn constraint_message(
    m: &Measurement,
    id: ConstraintId,
    match_ids: &BTreeMap<SubmapPair, ConstraintId>,
) -> Option<protocol::AnyMessage> {
    let pose_ref =
        |robot: slam::RobotId, stamp_ns: u64| Some(NodeRef::RobotPose { robot: wire_robot(robot)?, stamp_ns });
    let constraint = |kind, stamp_ns, from, to, t: &Isometry3<f64>, c: &Matrix6<f64>| Constraint {
        id,
        kind,
        stamp_ns,
        from,
        to,
        t_from_to: pose3(t),
        covariance: cov6(c),
    };
    let message = match m {
        Measurement::Detection(d) => constraint(
            ConstraintKind::RobotDetection,
            d.stamp_ns,
            pose_ref(d.observer, d.stamp_ns)?,
            pose_ref(d.observed, d.stamp_ns)?,
            &d.t_observer_observed,
            &d.covariance,
        )
        .into(),
        Measurement::Landmark(l) => constraint(
            ConstraintKind::LandmarkObservation,
            l.stamp_ns,
            pose_ref(l.robot, l.stamp_ns)?,
            NodeRef::Landmark { id: l.landmark },
            &l.t_body_landmark,
            &l.covariance,
        )
        .into(),
        Measurement::Match(s) => constraint(
            ConstraintKind::SubmapMatch,
            0,
            NodeRef::SubmapOrigin(wire_submap(s.a)?),
            NodeRef::SubmapOrigin(wire_submap(s.b)?),
            &s.t_a_b,
            &s.covariance,
        )
        .into(),
        Measurement::Attempt(a) => {
            let (first, second) = (wire_submap(a.pair.first())?, wire_submap(a.pair.second())?);
            let outcome = match a.outcome {
                AttemptOutcome::Failed => MatchOutcome::Rejected,
                AttemptOutcome::Matched => MatchOutcome::Matched(
                    match_ids.get(&a.pair).copied().unwrap_or(ConstraintId { robot: wire_robot(a.by)?, seq: u32::MAX }),
                ),
            };
            MatchAttempt { first, second, by: wire_robot(a.by)?, outcome }.into()
        }
        Measurement::SubmapSwitch(_) | Measurement::FilterPose(_) => return None,
    };
    Some(message)
}

/// The measurement a received constraint stands for. The protocol has no marker tag id, so a
/// received detection is keyed by its constraint's running number (unique per observer).
pub fn constraint_measurement(c: &Constraint) -> Result<Measurement, &'static str> {
    let t = isometry(&c.t_from_to).ok_or("constraint transform is not a pose")?;
    let covariance = matrix(&c.covariance).ok_or("constraint covariance is not finite")?;
    let covariance = slam::covariance::symmetric(&covariance);
    match (c.kind, c.from, c.to) {
        (
            ConstraintKind::RobotDetection,
            NodeRef::RobotPose { robot: observer, stamp_ns },
            NodeRef::RobotPose { robot: observed, stamp_ns: observed_ns },
        ) if stamp_ns == observed_ns => Ok(Measurement::Detection(RobotDetection {
            observer: u16::from(observer.0),
            observed: u16::from(observed.0),
            tag_id: c.id.seq,
            stamp_ns,
            t_observer_observed: t,
            covariance,
        })),
        (ConstraintKind::LandmarkObservation, NodeRef::RobotPose { robot, stamp_ns }, NodeRef::Landmark { id }) => {
            Ok(Measurement::Landmark(LandmarkObservation {
                robot: u16::from(robot.0),
                landmark: id,
                stamp_ns,
                t_body_landmark: t,
                covariance,
            }))
        }
        (ConstraintKind::SubmapMatch, NodeRef::SubmapOrigin(a), NodeRef::SubmapOrigin(b)) => {
            Ok(Measurement::Match(SubmapMatch { a: slam_submap(a), b: slam_submap(b), t_a_b: t, covariance }))
        }
        _ => Err("constraint kind does not fit its nodes"),
    }
}

/// A received match-attempt record; `None` for a claim (the ledger only knows finished attempts).
pub fn attempt_measurement(a: &MatchAttempt) -> Option<Measurement> {
    let outcome = match a.outcome {
        MatchOutcome::Claimed => return None,
        MatchOutcome::Rejected => AttemptOutcome::Failed,
        MatchOutcome::Matched(_) => AttemptOutcome::Matched,
    };
    Some(Measurement::Attempt(slam::MatchAttempt {
        pair: SubmapPair::new(slam_submap(a.first), slam_submap(a.second)),
        by: u16::from(a.by.0),
        outcome,
    }))
}

/// The frame switch a submap header carries (into `header.submap` from its predecessor).
pub fn header_switch(h: &SubmapHeader) -> Result<Option<SubmapSwitch>, &'static str> {
    let Some(switch) = &h.switch else { return Ok(None) };
    let from_index = h.submap.index.checked_sub(1).ok_or("submap 0 cannot start with a switch")?;
    Ok(Some(SubmapSwitch {
        robot: u16::from(h.submap.robot.0),
        stamp_ns: h.started_stamp_ns,
        from_index,
        t_old_new: isometry(&switch.t_previous_this).ok_or("switch transform is not a pose")?,
        covariance: psd(&switch.covariance).ok_or("switch covariance is not finite")?,
    }))
}

pub fn frame_switch(t_previous_this: &Isometry3<f64>, covariance_graph: &Matrix6<f64>) -> SubmapLink {
    SubmapLink { t_previous_this: pose3(t_previous_this), covariance: cov6(covariance_graph) }
}

/// Number of chunks a payload of `bytes` is cut into.
pub fn chunk_count(bytes: usize) -> usize {
    bytes.div_ceil(SUBMAP_CHUNK_BYTES)
}

/// The `index`-th chunk of `payload`.
pub fn chunk(submap: WireSubmap, payload: &[u8], index: usize) -> Option<SubmapChunk> {
    let start = index.checked_mul(SUBMAP_CHUNK_BYTES)?;
    let piece = payload.get(start..payload.len().min(start + SUBMAP_CHUNK_BYTES))?;
    let mut chunk = SubmapChunk { submap, index: u16::try_from(index).ok()?, data: Default::default() };
    chunk.data.extend_from_slice(piece).ok()?;
    Some(chunk)
}

/// Header fields of a payload: `(payload_bytes, chunk_count, crc32)`, `None` if too large for
/// the protocol's counters.
pub fn payload_fields(payload: &[u8]) -> Option<(u32, u16, u32)> {
    Some((u32::try_from(payload.len()).ok()?, u16::try_from(chunk_count(payload.len())).ok()?, crc32(payload)))
}

#[derive(Debug, Clone)]
struct Partial {
    header: SubmapHeader,
    data: Vec<u8>,
    received: Vec<bool>,
    missing: usize,
}

/// Reassembles received submaps from their chunks, in any order, duplicates ignored. Bounded: at
/// most `max_partials` submaps in flight (the oldest-started is dropped) of at most
/// `max_payload_bytes` each.
#[derive(Debug, Clone)]
pub struct Reassembler {
    partial: BTreeMap<WireSubmap, Partial>,
    started: Vec<WireSubmap>,
    complete: BTreeSet<WireSubmap>,
    max_partials: usize,
    max_payload_bytes: usize,
    pub dropped: u64,
}

impl Reassembler {
    pub fn new(max_partials: usize, max_payload_bytes: usize) -> Reassembler {
        Reassembler {
            partial: BTreeMap::new(),
            started: Vec::new(),
            complete: BTreeSet::new(),
            max_partials,
            max_payload_bytes,
            dropped: 0,
        }
    }

    pub fn start(&mut self, header: &SubmapHeader) -> Result<(), &'static str> {
        let bytes = usize::try_from(header.payload_bytes).map_err(|_| "payload size")?;
        if bytes == 0 || bytes > self.max_payload_bytes {
            return Err("submap payload size out of bounds");
        }
        if usize::from(header.chunk_count) != chunk_count(bytes) {
            return Err("chunk count does not fit the payload size");
        }
        if self.complete.contains(&header.submap) {
            return Ok(());
        }
        if self.partial.get(&header.submap).is_some_and(|p| p.header == *header) {
            return Ok(());
        }
        if !self.partial.contains_key(&header.submap) && self.partial.len() >= self.max_partials {
            let oldest = self.started.remove(0);
            self.partial.remove(&oldest);
            self.dropped += 1;
        }
        let count = usize::from(header.chunk_count);
        self.started.retain(|id| *id != header.submap);
        self.started.push(header.submap);
        self.partial.insert(
            header.submap,
            Partial { header: *header, data: vec![0; bytes], received: vec![false; count], missing: count },
        );
        Ok(())
    }

    /// Adds a chunk; returns the header and payload once all chunks are in and the CRC matches.
    pub fn add(&mut self, chunk: &SubmapChunk) -> Result<Option<(SubmapHeader, Vec<u8>)>, &'static str> {
        if self.complete.contains(&chunk.submap) {
            return Ok(None);
        }
        let Some(p) = self.partial.get_mut(&chunk.submap) else {
            return Err("submap chunk without a header");
        };
        let index = usize::from(chunk.index);
        let start = index * SUBMAP_CHUNK_BYTES;
        let end = p.data.len().min(start + SUBMAP_CHUNK_BYTES);
        if index >= p.received.len() || end - start != chunk.data.len() {
            return Err("submap chunk index or length does not fit the header");
        }
        if p.received[index] {
            return Ok(None);
        }
        p.data[start..end].copy_from_slice(&chunk.data);
        p.received[index] = true;
        p.missing -= 1;
        if p.missing > 0 {
            return Ok(None);
        }
        let Some(done) = self.partial.remove(&chunk.submap) else { return Ok(None) };
        self.started.retain(|id| *id != chunk.submap);
        if crc32(&done.data) != done.header.payload_crc32 {
            return Err("submap payload CRC mismatch");
        }
        self.complete.insert(chunk.submap);
        Ok(Some((done.header, done.data)))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn crc_is_iso_hdlc() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    fn header(submap: WireSubmap, payload: &[u8]) -> SubmapHeader {
        let (payload_bytes, chunk_count, payload_crc32) = payload_fields(payload).unwrap();
        SubmapHeader {
            submap,
            started_stamp_ns: 1,
            finished_stamp_ns: 2,
            switch: None,
            encoding: protocol::message::SubmapEncoding(1),
            payload_bytes,
            chunk_count,
            payload_crc32,
        }
    }

    #[test]
    fn chunks_reassemble_in_any_order_and_a_bad_crc_is_refused() {
        let id = WireSubmap { robot: WireRobot(3), index: 4 };
        let payload: Vec<u8> = (0..3000u32).map(|i| (i * 7 % 251) as u8).collect();
        let h = header(id, &payload);
        let mut r = Reassembler::new(2, 1 << 20);
        r.start(&h).unwrap();
        let n = chunk_count(payload.len());
        assert_eq!(n, 3);
        assert_eq!(r.add(&chunk(id, &payload, 2).unwrap()).unwrap(), None);
        assert_eq!(r.add(&chunk(id, &payload, 0).unwrap()).unwrap(), None);
        assert_eq!(r.add(&chunk(id, &payload, 0).unwrap()).unwrap(), None);
        let (got, data) = r.add(&chunk(id, &payload, 1).unwrap()).unwrap().unwrap();
        assert_eq!((got, data), (h, payload.clone()));

        let other = WireSubmap { robot: WireRobot(3), index: 5 };
        let mut bad = header(other, &payload);
        bad.payload_crc32 ^= 1;
        r.start(&bad).unwrap();
        for i in 0..n - 1 {
            r.add(&chunk(other, &payload, i).unwrap()).unwrap();
        }
        assert!(r.add(&chunk(other, &payload, n - 1).unwrap()).is_err());
    }

    proptest! {
        #[test]
        fn pose_conversion_is_total(t in proptest::array::uniform3(any::<f64>()), q in proptest::array::uniform4(any::<f64>())) {
            let p = Pose3 { translation_m: t, rotation_wxyz: q };
            if let Some(iso) = isometry(&p) {
                prop_assert!(iso.translation.vector.iter().all(|v| v.is_finite()));
            }
        }
    }
}
