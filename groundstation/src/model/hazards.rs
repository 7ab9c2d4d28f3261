//! The robots' hazard cells: the latest [`HazardCells`] of each robot, kept as received, and
//! placed in the reference frame when the view is built.
//!
//! A message's cells are offsets on a lattice in the body's heading frame (origin at the body,
//! x along its heading, z up), relative to the body pose the message carries in one of the robot's
//! submaps. The view places them like the trajectory's poses: `t_ref_body = t_ref_submap ·
//! t_submap_body` with the same submap origins, then each cell centre at
//! `t_ref_body.translation + Rz(yaw) · (i, j) · cell`, `yaw` the heading of `t_ref_body`'s x axis.

use nalgebra::{Isometry3, Vector3};
use protocol::message::HazardCells;

use crate::view::HazardView;

/// A robot's latest hazard message as the model keeps it.
#[derive(Debug, Clone, PartialEq)]
pub struct ReceivedHazards {
    pub received_ns: u64,
    pub stamp_ns: u64,
    /// The robot's submap the body pose is in.
    pub submap: u32,
    pub t_submap_body: Isometry3<f64>,
    pub cell_m: f64,
    pub cells: Vec<[i8; 2]>,
    pub omitted: u16,
}

impl ReceivedHazards {
    /// The message as kept, or `None` when it cannot be placed (not a pose, not a cell size, or
    /// a submap of another robot).
    pub fn from_message(received_ns: u64, message: &HazardCells) -> Option<ReceivedHazards> {
        if !message.is_valid() || message.submap.robot != message.robot {
            return None;
        }
        Some(ReceivedHazards {
            received_ns,
            stamp_ns: message.stamp_ns,
            submap: message.submap.index,
            t_submap_body: mapper::wire::isometry(&message.t_submap_body)?,
            cell_m: f64::from(message.cell_size_m),
            cells: message.cells.to_vec(),
            omitted: message.omitted,
        })
    }

    /// The cells placed with the body at `t_ref_body` (`exact`: that is the message's own pose).
    pub fn place(&self, t_ref_body: &Isometry3<f64>, exact: bool) -> HazardView {
        let heading = t_ref_body.rotation * Vector3::x();
        let yaw_ref_rad = heading.y.atan2(heading.x);
        let (sin, cos) = yaw_ref_rad.sin_cos();
        let body = t_ref_body.translation.vector;
        let cells_ref_m = self
            .cells
            .iter()
            .map(|&[i, j]| {
                let (x, y) = (f64::from(i) * self.cell_m, f64::from(j) * self.cell_m);
                [body.x + cos * x - sin * y, body.y + sin * x + cos * y]
            })
            .collect();
        HazardView {
            received_ns: self.received_ns,
            stamp_ns: self.stamp_ns,
            cell_m: self.cell_m,
            yaw_ref_rad,
            cells_ref_m,
            omitted: self.omitted,
            exact,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use nalgebra::{Translation3, UnitQuaternion};
    use protocol::{Pose3, RobotId, SubmapId};

    use super::*;

    fn message() -> HazardCells {
        let mut cells = heapless::Vec::new();
        cells.extend_from_slice(&[[10, 0], [0, -5]]).unwrap();
        HazardCells {
            robot: RobotId(2),
            stamp_ns: 9,
            submap: SubmapId { robot: RobotId(2), index: 4 },
            t_submap_body: Pose3::IDENTITY,
            cell_size_m: 0.1,
            omitted: 7,
            cells,
        }
    }

    #[test]
    fn cells_turn_with_the_body_heading() {
        let kept = ReceivedHazards::from_message(5, &message()).unwrap();
        assert_eq!((kept.received_ns, kept.stamp_ns, kept.submap, kept.omitted), (5, 9, 4, 7));
        // Facing +y from (3, 4): 1 m ahead is (3, 5), 0.5 m to the right is (3.5, 4).
        let t = Isometry3::from_parts(
            Translation3::new(3.0, 4.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        let view = kept.place(&t, true);
        let want = [[3.0, 5.0], [3.5, 4.0]];
        for (got, want) in view.cells_ref_m.iter().zip(want) {
            assert!((got[0] - want[0]).abs() < 1e-6 && (got[1] - want[1]).abs() < 1e-6, "{got:?} vs {want:?}");
        }
        assert!((view.yaw_ref_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!((view.cell_m - 0.1).abs() < 1e-6 && view.exact);
    }

    #[test]
    fn messages_that_cannot_be_placed_are_refused() {
        let mut m = message();
        m.submap.robot = RobotId(3);
        assert!(ReceivedHazards::from_message(0, &m).is_none());
        let mut m = message();
        m.cell_size_m = -0.1;
        assert!(ReceivedHazards::from_message(0, &m).is_none());
        let mut m = message();
        m.t_submap_body.rotation_wxyz = [0.0; 4];
        assert!(ReceivedHazards::from_message(0, &m).is_none());
    }
}
