//! The robot's hazard cells for the ground station: the vision process's [`HazardCellsMsg`]
//! (up to 960 cells of 5 cm on the lattice of the filter's local frame, about 4 KiB) becomes one
//! [`HazardCells`] of at most [`HAZARD_CELLS_MAX`] cells of [`WIRE_CELL_SIZE_M`] in the body's
//! heading frame (at most 605 bytes a packet), because the ground link is a thin shared radio
//! and the ground does not know where the local frame's origin is.
//!
//! What is lost on the way, on purpose:
//! - resolution: each 5 cm cell's centre is rounded to the nearest 0.1 m lattice point of the
//!   heading frame (up to 7 cm off; cells that land on the same point are sent once);
//! - range: cells beyond ±12.7 m (the i8 offsets), none with the 10 m local map;
//! - the farthest cells beyond the first [`HAZARD_CELLS_MAX`] (the nearest are what an operator
//!   watching a rover drive needs). Both are counted in [`HazardCells::omitted`], with the cells
//!   the vision process had already left out of its own message.

use msgs::HazardCellsMsg;
use nalgebra::Vector3;
use protocol::message::HazardCells;
use protocol::message::hazards::HAZARD_CELLS_MAX;
use protocol::{Pose3, RobotId, SubmapId};

/// Edge of a cell on the wire: twice the map's 5 cm, a quarter of the cells.
pub const WIRE_CELL_SIZE_M: f64 = 0.1;

/// The hazard message of `msg` for the ground, or `None` when `msg` holds no usable picture (a
/// pose that is not one, a cell size that is not a positive length).
///
/// The submap of the pose is the filter's frame id, as in the ground feed's poses (the mapper's
/// submap index follows the filter's frame).
pub fn hazard_cells(robot: RobotId, msg: &HazardCellsMsg) -> Option<HazardCells> {
    let t_local_body = msg.t_local_body.to_isometry()?;
    let fine_m = f64::from(msg.cell_size_m);
    if !(fine_m.is_finite() && fine_m > 0.0) {
        return None;
    }
    // The local frame is gravity-aligned: the heading frame is the local frame turned by the
    // yaw of the body's x axis about z, with its origin at the body.
    let heading = t_local_body.rotation * Vector3::x();
    let (sin, cos) = heading.y.atan2(heading.x).sin_cos();
    let body = t_local_body.translation.vector;
    let count = usize::try_from(msg.count).map_or(msg.cells.len(), |n| n.min(msg.cells.len()));
    let mut coarse: Vec<(i32, [i8; 2])> = Vec::with_capacity(count);
    let mut out_of_range = 0u64;
    for &[di, dj] in &msg.cells[..count] {
        let x = (f64::from(msg.origin_cell[0]) + f64::from(di) + 0.5) * fine_m - body.x;
        let y = (f64::from(msg.origin_cell[1]) + f64::from(dj) + 0.5) * fine_m - body.y;
        let i = ((cos * x + sin * y) / WIRE_CELL_SIZE_M).round();
        let j = ((-sin * x + cos * y) / WIRE_CELL_SIZE_M).round();
        let in_range = |v: f64| (f64::from(i8::MIN)..=f64::from(i8::MAX)).contains(&v);
        if in_range(i) && in_range(j) {
            let (i, j) = (i as i32, j as i32);
            coarse.push((i * i + j * j, [i as i8, j as i8]));
        } else {
            out_of_range += 1;
        }
    }
    // Nearest first, ties in a fixed order (the same input gives the same bytes), each cell once.
    coarse.sort_unstable();
    coarse.dedup();
    let kept = coarse.len().min(HAZARD_CELLS_MAX);
    let omitted = (coarse.len() - kept) as u64 + out_of_range + u64::from(msg.omitted);
    let mut message = HazardCells {
        robot,
        stamp_ns: msg.stamp_ns,
        submap: SubmapId { robot, index: msg.frame_id },
        t_submap_body: Pose3 {
            translation_m: msg.t_local_body.translation_m,
            rotation_wxyz: msg.t_local_body.rotation_wxyz,
        },
        cell_size_m: WIRE_CELL_SIZE_M as f32,
        omitted: u16::try_from(omitted).unwrap_or(u16::MAX),
        cells: Default::default(),
    };
    for &(_, cell) in &coarse[..kept] {
        // Cannot fail: at most HAZARD_CELLS_MAX are taken.
        let _ = message.cells.push(cell);
    }
    Some(message)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use msgs::{HAZARD_CELLS_MAX as BUS_CELLS_MAX, Pose};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    use super::*;

    const FINE_M: f64 = 0.05;

    /// A bus message with the body at `(x, y)` heading `yaw` and these cells (offsets from the
    /// body's fine cell).
    fn bus_cells(x: f64, y: f64, yaw: f64, cells: &[[i16; 2]]) -> Box<HazardCellsMsg> {
        let t = Isometry3::from_parts(Translation3::new(x, y, 0.3), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw));
        let mut msg = Box::new(HazardCellsMsg {
            stamp_ns: 7_000,
            t_local_body: Pose::from_isometry(&t),
            frame_id: 3,
            cell_size_m: FINE_M as f32,
            origin_cell: [(x / FINE_M).floor() as i32, (y / FINE_M).floor() as i32],
            count: cells.len() as u32,
            omitted: 0,
            cells: [[0; 2]; BUS_CELLS_MAX],
        });
        msg.cells[..cells.len()].copy_from_slice(cells);
        msg
    }

    /// The same with the fine cells holding these local-frame points (kept off cell borders).
    fn bus_points(x: f64, y: f64, yaw: f64, points_local: &[[f64; 2]]) -> Box<HazardCellsMsg> {
        let origin = [(x / FINE_M).floor() as i32, (y / FINE_M).floor() as i32];
        let cell = |v: f64, o: i32| ((v / FINE_M).floor() as i32 - o) as i16;
        let cells: Vec<[i16; 2]> =
            points_local.iter().map(|p| [cell(p[0], origin[0]), cell(p[1], origin[1])]).collect();
        bus_cells(x, y, yaw, &cells)
    }

    #[test]
    fn cells_are_relative_to_the_body_in_its_heading_frame() {
        // The body at (1.01, 2.01) facing +y: ahead is +y, left is -x in the local frame.
        let points = [[1.025, 3.025], [0.525, 2.025], [1.025, 1.325]];
        let msg = bus_points(1.01, 2.01, std::f64::consts::FRAC_PI_2, &points);
        let wire = hazard_cells(RobotId(4), &msg).unwrap();
        // 1 m ahead, 0.5 m to the left, 0.7 m behind; nearest first.
        assert_eq!(wire.cells.as_slice(), &[[0, 5], [-7, 0], [10, 0]]);
        assert_eq!((wire.robot, wire.stamp_ns, wire.submap.index, wire.omitted), (RobotId(4), 7_000, 3, 0));
        assert_eq!(wire.submap.robot, RobotId(4));
        assert_eq!(wire.t_submap_body.translation_m, msg.t_local_body.translation_m);
        assert_eq!(wire.cell_size_m, WIRE_CELL_SIZE_M as f32);
        assert!(wire.is_valid());
    }

    #[test]
    fn fine_cells_merge_into_one_wire_cell() {
        // Four 5 cm cells around the point 2 m ahead of a body facing +x.
        let square = [[1.975, -0.025], [2.025, -0.025], [1.975, 0.025], [2.025, 0.025]];
        let wire = hazard_cells(RobotId(1), &bus_points(0.01, 0.01, 0.0, &square)).unwrap();
        assert_eq!(wire.cells.as_slice(), &[[20, 0]]);
        assert_eq!(wire.omitted, 0);
    }

    #[test]
    fn the_nearest_are_kept_and_the_rest_counted() {
        // A 20 × 20 block of fine cells two apart (400 wire cells, `[a + 5, b - 10]`) ahead of a
        // body facing +x, one cell 13 m away, and 10 cells the vision process left out already.
        let mut cells: Vec<[i16; 2]> = (0..20).flat_map(|a| (0..20).map(move |b| [2 * a + 10, 2 * b - 20])).collect();
        cells.push([260, 0]);
        let mut msg = bus_cells(0.01, 0.01, 0.0, &cells);
        msg.omitted = 10;
        let wire = hazard_cells(RobotId(1), &msg).unwrap();
        assert_eq!(wire.cells.len(), HAZARD_CELLS_MAX);
        assert_eq!(wire.omitted, 400 - 256 + 1 + 10);
        let d2 = |c: [i32; 2]| c[0] * c[0] + c[1] * c[1];
        let kept: Vec<i32> = wire.cells.iter().map(|c| d2([i32::from(c[0]), i32::from(c[1])])).collect();
        assert!(kept.is_sorted(), "nearest first");
        // The kept cells are the 256 nearest of the block, computed here from the lattice.
        let mut all: Vec<i32> = (0..20).flat_map(|a| (0..20).map(move |b| d2([a + 5, b - 10]))).collect();
        all.sort_unstable();
        assert_eq!(kept, all[..HAZARD_CELLS_MAX]);
        // Same input, same bytes.
        assert_eq!(hazard_cells(RobotId(1), &msg).unwrap(), wire);
    }

    #[test]
    fn a_message_that_is_no_picture_is_refused() {
        let mut msg = bus_points(0.0, 0.0, 0.0, &[[1.0, 0.0]]);
        msg.cell_size_m = f32::NAN;
        assert!(hazard_cells(RobotId(1), &msg).is_none());
        let mut msg = bus_points(0.0, 0.0, 0.0, &[[1.0, 0.0]]);
        msg.t_local_body.rotation_wxyz = [0.0; 4];
        assert!(hazard_cells(RobotId(1), &msg).is_none());
        // A count beyond the array is read as the array.
        let mut msg = bus_points(0.0, 0.0, 0.0, &[[1.0, 0.0]]);
        msg.count = u32::MAX;
        assert_eq!(hazard_cells(RobotId(1), &msg).unwrap().cells.len(), 2, "the listed cell and [0, 0]");
    }
}
