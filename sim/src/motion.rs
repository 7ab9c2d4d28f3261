//! How robots move: rovers drive waypoint paths on the terrain (pose from wheel contact), flyers
//! fly free 6D paths (owned by the world helper).
//!
//! A path becomes a [`MotionPlan`] first: a timed sequence of phases (stand, turn on the spot,
//! drive a straight leg, climb), each with an acceleration-limited trapezoidal speed profile. The
//! plan is sampled every knot interval into the control points of a quintic B-spline
//! [`Trajectory`], which smooths the profile's acceleration steps into a C⁴ motion. Straight legs
//! stay exactly straight (a B-spline reproduces affine motion along a line), and robots stop at
//! every waypoint, so the driven path is the waypoint polyline.

use crate::robot::{FLYER_REST_HEIGHT_M, ROVER_CHASSIS_HEIGHT_M, ROVER_TRACK_M, ROVER_WHEELBASE_M};
use crate::terrain::{Heightfield, Terrain};
use crate::trajectory::{Trajectory, TrajectoryError};

/// Linear acceleration limit of a rover.
pub const ROVER_ACCEL_MPS2: f64 = 0.25;
/// Yaw rate and yaw acceleration limits of a rover turning on the spot.
pub const ROVER_YAW_RATE_RADPS: f64 = 0.5;
pub const ROVER_YAW_ACCEL_RADPS2: f64 = 0.8;
/// Flyer limits: horizontal acceleration, climb rate and vertical acceleration, yaw rate.
pub const FLYER_ACCEL_MPS2: f64 = 0.5;
pub const FLYER_CLIMB_MPS: f64 = 0.5;
pub const FLYER_CLIMB_ACCEL_MPS2: f64 = 0.3;
pub const FLYER_YAW_RATE_RADPS: f64 = 0.6;
pub const FLYER_YAW_ACCEL_RADPS2: f64 = 1.0;
/// Shortest standstill at the start: the spline blends five knot intervals, so a shorter stand
/// would leave the robot moving at the first stamp.
const MIN_STAND_KNOTS: f64 = 6.0;
/// Half the side of the square over which a flyer's reference ground height is averaged (keeps
/// its altitude from twitching over every rock).
const FLYER_GROUND_HALF_M: f64 = 1.0;

/// Driving parameters of a rover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoverDrive {
    pub speed_mps: f64,
    /// Standing time at each waypoint (zero-velocity phases).
    pub pause_s: f64,
    /// Spacing of the trajectory's spline control points.
    pub knot_interval_s: f64,
}

impl Default for RoverDrive {
    fn default() -> Self {
        RoverDrive { speed_mps: 0.3, pause_s: 2.0, knot_interval_s: 0.1 }
    }
}

/// Why a motion could not be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionError {
    #[error("a path needs at least two waypoints")]
    TooFewWaypoints,
    #[error("waypoint {0} is off the terrain")]
    OffTerrain(usize),
    #[error("invalid drive parameters: {0}")]
    BadDrive(String),
    #[error(transparent)]
    Trajectory(#[from] TrajectoryError),
}

/// A rest-to-rest move over `distance` with a trapezoidal (or, when short, triangular) speed
/// profile.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Trapezoid {
    distance: f64,
    v_peak: f64,
    accel: f64,
    t_ramp: f64,
    t_total: f64,
}

impl Trapezoid {
    fn new(distance: f64, v_max: f64, accel: f64) -> Self {
        let d = distance.abs();
        let t_ramp_full = v_max / accel;
        let d_ramp_full = 0.5 * v_max * t_ramp_full;
        if 2.0 * d_ramp_full >= d {
            let v_peak = (d * accel).sqrt();
            let t_ramp = v_peak / accel;
            Trapezoid { distance: d, v_peak, accel, t_ramp, t_total: 2.0 * t_ramp }
        } else {
            let t_total = 2.0 * t_ramp_full + (d - 2.0 * d_ramp_full) / v_max;
            Trapezoid { distance: d, v_peak: v_max, accel, t_ramp: t_ramp_full, t_total }
        }
    }

    /// Distance covered `t` after the start of the move.
    fn position(&self, t: f64) -> f64 {
        let t = t.clamp(0.0, self.t_total);
        if t < self.t_ramp {
            0.5 * self.accel * t * t
        } else if t <= self.t_total - self.t_ramp {
            0.5 * self.accel * self.t_ramp * self.t_ramp + self.v_peak * (t - self.t_ramp)
        } else {
            let rest = self.t_total - t;
            self.distance - 0.5 * self.accel * rest * rest
        }
    }
}

/// What a robot does during one [`Phase`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhaseKind {
    /// At rest (a rover's pause, a flyer's hover or its rest on the ground).
    Stand,
    /// Yawing on the spot.
    Turn,
    /// Moving along a straight leg at constant heading.
    Drive,
    /// A flyer's vertical take-off or landing.
    Climb,
}

/// One timed piece of a [`MotionPlan`]: from `from` to `to` (`[x, y, height above ground]`;
/// the height is a flyer's) and from `yaw_from` to `yaw_to`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Phase {
    pub kind: PhaseKind,
    pub start_s: f64,
    pub end_s: f64,
    pub from: [f64; 3],
    pub to: [f64; 3],
    pub yaw_from_rad: f64,
    pub yaw_to_rad: f64,
    /// Index of the waypoint the phase moves to or stands at.
    pub waypoint: usize,
    profile: Trapezoid,
}

/// A sample of a plan: position (`h` is the height above ground of a flyer), heading, and the
/// phase it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanPose {
    pub x_m: f64,
    pub y_m: f64,
    pub h_m: f64,
    pub yaw_rad: f64,
    pub kind: PhaseKind,
    pub waypoint: usize,
}

/// The timed motion along a path, times in seconds from the start of the motion. After the last
/// phase the robot stands where that phase ended.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionPlan {
    phases: Vec<Phase>,
}

struct PlanBuilder {
    phases: Vec<Phase>,
    t_s: f64,
    at: [f64; 3],
    yaw_rad: f64,
}

impl PlanBuilder {
    fn push(&mut self, kind: PhaseKind, duration_s: f64, to: [f64; 3], yaw_to: f64, waypoint: usize, p: Trapezoid) {
        if duration_s <= 0.0 {
            return;
        }
        self.phases.push(Phase {
            kind,
            start_s: self.t_s,
            end_s: self.t_s + duration_s,
            from: self.at,
            to,
            yaw_from_rad: self.yaw_rad,
            yaw_to_rad: yaw_to,
            waypoint,
            profile: p,
        });
        self.t_s += duration_s;
        self.at = to;
        self.yaw_rad = yaw_to;
    }

    fn stand(&mut self, duration_s: f64, waypoint: usize) {
        let still = Trapezoid::new(0.0, 1.0, 1.0);
        self.push(PhaseKind::Stand, duration_s, self.at, self.yaw_rad, waypoint, still);
    }

    fn turn_to(&mut self, heading_rad: f64, rate: f64, accel: f64, waypoint: usize) {
        let delta = wrap_angle(heading_rad - self.yaw_rad);
        if delta.abs() < 1e-9 {
            return;
        }
        let p = Trapezoid::new(delta, rate, accel);
        self.push(PhaseKind::Turn, p.t_total, self.at, self.yaw_rad + delta, waypoint, p);
    }

    fn move_to(&mut self, kind: PhaseKind, to: [f64; 3], speed: f64, accel: f64, waypoint: usize) {
        let d = distance3(&self.at, &to);
        if d < 1e-9 {
            return;
        }
        let p = Trapezoid::new(d, speed, accel);
        self.push(kind, p.t_total, to, self.yaw_rad, waypoint, p);
    }
}

fn distance3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt()
}

/// `a` wrapped into `(−π, π]`.
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = 2.0 * std::f64::consts::PI;
    let w = a.rem_euclid(two_pi);
    if w > std::f64::consts::PI { w - two_pi } else { w }
}

/// Heading of the first leg that has a length, 0 if none has.
fn first_heading(points: &[[f64; 3]]) -> f64 {
    points
        .windows(2)
        .find(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) > 1e-9)
        .map_or(0.0, |w| (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0]))
}

fn check_drive(drive: &RoverDrive) -> Result<(), MotionError> {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(drive.speed_mps) && ok(drive.knot_interval_s) && drive.pause_s.is_finite() && drive.pause_s >= 0.0) {
        return Err(MotionError::BadDrive(format!("{drive:?}")));
    }
    Ok(())
}

impl MotionPlan {
    /// A rover's plan: stand at the first waypoint (`pause_s`, at least six knot intervals),
    /// then for each leg turn on the spot to its heading, drive it, and stand `pause_s`.
    pub fn rover(waypoints_m: &[[f64; 2]], drive: &RoverDrive) -> Result<Self, MotionError> {
        check_drive(drive)?;
        if waypoints_m.len() < 2 {
            return Err(MotionError::TooFewWaypoints);
        }
        let points: Vec<[f64; 3]> = waypoints_m.iter().map(|w| [w[0], w[1], 0.0]).collect();
        let mut b = PlanBuilder { phases: Vec::new(), t_s: 0.0, at: points[0], yaw_rad: first_heading(&points) };
        b.stand(drive.pause_s.max(MIN_STAND_KNOTS * drive.knot_interval_s), 0);
        for (i, to) in points.iter().enumerate().skip(1) {
            let (dx, dy) = (to[0] - b.at[0], to[1] - b.at[1]);
            if dx.hypot(dy) < 1e-9 {
                continue;
            }
            b.turn_to(dy.atan2(dx), ROVER_YAW_RATE_RADPS, ROVER_YAW_ACCEL_RADPS2, i);
            b.move_to(PhaseKind::Drive, *to, drive.speed_mps, ROVER_ACCEL_MPS2, i);
            b.stand(drive.pause_s, i);
        }
        Ok(MotionPlan { phases: b.phases })
    }

    /// A flyer's plan over `[x, y, height above ground]` waypoints: rest on the ground at the
    /// first waypoint, climb to its height, then per leg turn (hovering), fly it and hover
    /// `pause_s`; finally land at the last waypoint and rest.
    pub fn flyer(waypoints_m: &[[f64; 3]], drive: &RoverDrive) -> Result<Self, MotionError> {
        check_drive(drive)?;
        if waypoints_m.len() < 2 {
            return Err(MotionError::TooFewWaypoints);
        }
        let first = waypoints_m[0];
        let mut b = PlanBuilder {
            phases: Vec::new(),
            t_s: 0.0,
            at: [first[0], first[1], 0.0],
            yaw_rad: first_heading(waypoints_m),
        };
        b.stand(drive.pause_s.max(MIN_STAND_KNOTS * drive.knot_interval_s), 0);
        b.move_to(PhaseKind::Climb, first, FLYER_CLIMB_MPS, FLYER_CLIMB_ACCEL_MPS2, 0);
        b.stand(drive.pause_s, 0);
        for (i, to) in waypoints_m.iter().enumerate().skip(1) {
            let (dx, dy) = (to[0] - b.at[0], to[1] - b.at[1]);
            if dx.hypot(dy) > 1e-9 {
                b.turn_to(dy.atan2(dx), FLYER_YAW_RATE_RADPS, FLYER_YAW_ACCEL_RADPS2, i);
            }
            // Mostly vertical legs are flown at the climb rate.
            let speed = if dx.hypot(dy) < (to[2] - b.at[2]).abs() { FLYER_CLIMB_MPS } else { drive.speed_mps };
            b.move_to(PhaseKind::Drive, *to, speed, FLYER_ACCEL_MPS2, i);
            b.stand(drive.pause_s, i);
        }
        let last = waypoints_m.len() - 1;
        let ground = [b.at[0], b.at[1], 0.0];
        b.move_to(PhaseKind::Climb, ground, FLYER_CLIMB_MPS, FLYER_CLIMB_ACCEL_MPS2, last);
        b.stand(MIN_STAND_KNOTS * drive.knot_interval_s, last);
        Ok(MotionPlan { phases: b.phases })
    }

    pub fn phases(&self) -> &[Phase] {
        &self.phases
    }

    /// End of the last phase (the robot stands from then on).
    pub fn end_s(&self) -> f64 {
        self.phases.last().map_or(0.0, |p| p.end_s)
    }

    /// The phase running at `t_s` (the last one after the end, the first one before the start).
    pub fn phase_at(&self, t_s: f64) -> Option<&Phase> {
        self.phases.get(self.phase_index_at(t_s)?)
    }

    /// Index of [`MotionPlan::phase_at`]'s phase.
    pub fn phase_index_at(&self, t_s: f64) -> Option<usize> {
        let last = self.phases.len().checked_sub(1)?;
        Some(self.phases.partition_point(|p| p.end_s <= t_s).min(last))
    }

    /// Where the plan is at `t_s`.
    pub fn pose_at(&self, t_s: f64) -> Option<PlanPose> {
        let p = self.phase_at(t_s)?;
        let (t_s, standing_on) = if t_s >= p.end_s { (p.end_s, true) } else { (t_s.max(p.start_s), false) };
        let tau = t_s - p.start_s;
        let fraction = if p.profile.distance > 0.0 { p.profile.position(tau) / p.profile.distance } else { 0.0 };
        let lerp = |a: f64, b: f64| a + (b - a) * fraction;
        let (kind, yaw) = match p.kind {
            PhaseKind::Turn => (PhaseKind::Turn, lerp(p.yaw_from_rad, p.yaw_to_rad)),
            k => (k, p.yaw_from_rad),
        };
        let kind = if standing_on { PhaseKind::Stand } else { kind };
        let pos = match p.kind {
            PhaseKind::Drive | PhaseKind::Climb => {
                [lerp(p.from[0], p.to[0]), lerp(p.from[1], p.to[1]), lerp(p.from[2], p.to[2])]
            }
            PhaseKind::Stand | PhaseKind::Turn => p.from,
        };
        Some(PlanPose { x_m: pos[0], y_m: pos[1], h_m: pos[2], yaw_rad: yaw, kind, waypoint: p.waypoint })
    }

    /// The standing phases as `(start, end)` seconds; the last one extends to `until_s` when the
    /// plan ends standing before it.
    pub fn stands_s(&self, until_s: f64) -> Vec<(f64, f64)> {
        let mut stands: Vec<(f64, f64)> =
            self.phases.iter().filter(|p| p.kind == PhaseKind::Stand).map(|p| (p.start_s, p.end_s)).collect();
        let end = self.end_s();
        match stands.last_mut() {
            Some(last) if (last.1 - end).abs() < 1e-12 => last.1 = last.1.max(until_s),
            _ if until_s > end => stands.push((end, until_s)),
            _ => {}
        }
        stands
    }
}

/// The plane under a rover's four wheels: height at the body centre and slopes along the heading
/// and to the left.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactPlane {
    pub height_m: f64,
    pub slope_forward: f64,
    pub slope_left: f64,
}

impl ContactPlane {
    /// Roll and pitch of a body resting on the plane (`R = Rz·Ry·Rx`, positive pitch noses down).
    pub fn roll_pitch_rad(&self) -> (f64, f64) {
        let norm = (1.0 + self.slope_forward.powi(2) + self.slope_left.powi(2)).sqrt();
        ((self.slope_left / norm).asin(), -self.slope_forward.atan())
    }
}

/// Least-squares plane through the terrain heights at the four wheel centres of a rover at
/// `(x, y)` heading `yaw_rad`; `None` if a wheel is off the terrain.
pub fn wheel_contact_plane(heightfield: &Heightfield, x_m: f64, y_m: f64, yaw_rad: f64) -> Option<ContactPlane> {
    let (s, c) = yaw_rad.sin_cos();
    let (hx, hy) = (0.5 * ROVER_WHEELBASE_M, 0.5 * ROVER_TRACK_M);
    let at = |f: f64, l: f64| heightfield.height_at(x_m + c * f - s * l, y_m + s * f + c * l);
    let (fl, fr, rl, rr) = (at(hx, hy)?, at(hx, -hy)?, at(-hx, hy)?, at(-hx, -hy)?);
    // With the wheels at (±hx, ±hy) the least-squares fit decouples into means and differences.
    Some(ContactPlane {
        height_m: 0.25 * (fl + fr + rl + rr),
        slope_forward: ((fl + fr) - (rl + rr)) / (4.0 * hx),
        slope_left: ((fl + rl) - (fr + rr)) / (4.0 * hy),
    })
}

/// Number of control points so that the spline's span covers `span_s` from the first sample.
fn control_point_count(span_s: f64, knot_interval_s: f64) -> usize {
    5 + (span_s / knot_interval_s - 1e-9).ceil().max(1.0) as usize
}

/// Time of control point `j`: a uniform quintic B-spline centres control point `j` on
/// `(j − 2)·Δ` after its start.
fn control_time_s(j: usize, knot_interval_s: f64) -> f64 {
    (j as f64 - 2.0) * knot_interval_s
}

/// The trajectory of a rover driving `waypoints_m` (world x, y) on `terrain`, starting at
/// `start_ns`, and standing still until at least `until_ns` after the last waypoint.
pub fn rover_trajectory(
    terrain: &Terrain,
    waypoints_m: &[[f64; 2]],
    drive: &RoverDrive,
    start_ns: u64,
    until_ns: u64,
) -> Result<Trajectory, MotionError> {
    let plan = MotionPlan::rover(waypoints_m, drive)?;
    rover_trajectory_from_plan(terrain, &plan, drive.knot_interval_s, start_ns, until_ns)
}

/// [`rover_trajectory`] of a plan made with [`MotionPlan::rover`]: every knot interval, the
/// plan's (x, y, yaw) and the wheel contact plane give the control point
/// `[x, y, plane height + chassis height, roll, pitch, yaw]`.
pub fn rover_trajectory_from_plan(
    terrain: &Terrain,
    plan: &MotionPlan,
    knot_interval_s: f64,
    start_ns: u64,
    until_ns: u64,
) -> Result<Trajectory, MotionError> {
    let span_s = (until_ns.saturating_sub(start_ns) as f64 * 1e-9).max(plan.end_s());
    let n = control_point_count(span_s, knot_interval_s);
    let mut control_points = Vec::with_capacity(n);
    for j in 0..n {
        let t = control_time_s(j, knot_interval_s);
        let Some(pose) = plan.pose_at(t) else {
            return Err(MotionError::TooFewWaypoints);
        };
        let plane = wheel_contact_plane(&terrain.heightfield, pose.x_m, pose.y_m, pose.yaw_rad)
            .ok_or(MotionError::OffTerrain(pose.waypoint))?;
        let (roll, pitch) = plane.roll_pitch_rad();
        control_points.push([pose.x_m, pose.y_m, plane.height_m + ROVER_CHASSIS_HEIGHT_M, roll, pitch, pose.yaw_rad]);
    }
    Ok(Trajectory::new(start_ns, knot_interval_s, control_points)?)
}

/// Mean terrain height over a square around `(x, y)`, the flyer's altitude reference; `None`
/// when the centre is off the terrain (samples off the terrain are left out).
pub fn flyer_ground_height(heightfield: &Heightfield, x_m: f64, y_m: f64) -> Option<f64> {
    heightfield.height_at(x_m, y_m)?;
    let mut sum = 0.0;
    let mut count = 0.0;
    for i in -2..=2 {
        for j in -2..=2 {
            let step = 0.5 * FLYER_GROUND_HALF_M;
            if let Some(h) = heightfield.height_at(x_m + f64::from(i) * step, y_m + f64::from(j) * step) {
                sum += h;
                count += 1.0;
            }
        }
    }
    Some(sum / count)
}

/// The trajectory of a flyer over `waypoints_m` (`[x, y, height above ground]`): take-off from
/// the ground at the first waypoint, straight legs at the waypoints' heights above the (locally
/// averaged) terrain, yaw along each leg (turning while hovering), roll and pitch tilting the
/// thrust to produce the horizontal acceleration under `gravity_mps2`, landing at the last
/// waypoint and resting until at least `until_ns`.
pub fn flyer_trajectory(
    terrain: &Terrain,
    waypoints_m: &[[f64; 3]],
    drive: &RoverDrive,
    gravity_mps2: f64,
    start_ns: u64,
    until_ns: u64,
) -> Result<Trajectory, MotionError> {
    let plan = MotionPlan::flyer(waypoints_m, drive)?;
    flyer_trajectory_from_plan(terrain, &plan, drive.knot_interval_s, gravity_mps2, start_ns, until_ns)
}

/// [`flyer_trajectory`] of a plan made with [`MotionPlan::flyer`].
pub fn flyer_trajectory_from_plan(
    terrain: &Terrain,
    plan: &MotionPlan,
    knot_interval_s: f64,
    gravity_mps2: f64,
    start_ns: u64,
    until_ns: u64,
) -> Result<Trajectory, MotionError> {
    let span_s = (until_ns.saturating_sub(start_ns) as f64 * 1e-9).max(plan.end_s());
    let n = control_point_count(span_s, knot_interval_s);
    let dt = knot_interval_s;
    let position = |t: f64| -> Result<([f64; 3], PlanPose), MotionError> {
        let pose = plan.pose_at(t).ok_or(MotionError::TooFewWaypoints)?;
        let ground = flyer_ground_height(&terrain.heightfield, pose.x_m, pose.y_m)
            .ok_or(MotionError::OffTerrain(pose.waypoint))?;
        Ok(([pose.x_m, pose.y_m, ground + FLYER_REST_HEIGHT_M + pose.h_m], pose))
    };
    let mut control_points = Vec::with_capacity(n);
    for j in 0..n {
        let t = control_time_s(j, dt);
        let (p, pose) = position(t)?;
        let (prev, _) = position(t - dt)?;
        let (next, _) = position(t + dt)?;
        // Thrust must supply a − g: tilt the body so its z axis points along it.
        let ax = (next[0] - 2.0 * p[0] + prev[0]) / (dt * dt);
        let ay = (next[1] - 2.0 * p[1] + prev[1]) / (dt * dt);
        let az = (next[2] - 2.0 * p[2] + prev[2]) / (dt * dt);
        let (s, c) = pose.yaw_rad.sin_cos();
        let a_forward = c * ax + s * ay;
        let a_left = -s * ax + c * ay;
        let thrust_z = (gravity_mps2 + az).max(0.1 * gravity_mps2);
        let thrust = (a_forward.powi(2) + a_left.powi(2) + thrust_z.powi(2)).sqrt();
        let pitch = a_forward.atan2(thrust_z);
        let roll = (-a_left / thrust).asin();
        control_points.push([p[0], p[1], p[2], roll, pitch, pose.yaw_rad]);
    }
    Ok(Trajectory::new(start_ns, knot_interval_s, control_points)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_reaches_the_distance_with_limited_speed() {
        let p = Trapezoid::new(5.0, 0.3, 0.25);
        assert!((p.position(p.t_total) - 5.0).abs() < 1e-12);
        assert!((p.t_total - (5.0 / 0.3 + 0.3 / 0.25)).abs() < 1e-9);
        let short = Trapezoid::new(0.1, 0.3, 0.25);
        assert!(short.v_peak < 0.3);
        assert!((short.position(short.t_total) - 0.1).abs() < 1e-12);
        assert!((short.position(0.5 * short.t_total) - 0.05).abs() < 1e-12);
    }

    #[test]
    fn rover_plan_stands_turns_and_drives() {
        let drive = RoverDrive { speed_mps: 0.3, pause_s: 2.0, knot_interval_s: 0.1 };
        let plan = MotionPlan::rover(&[[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]], &drive).unwrap();
        let kinds: Vec<PhaseKind> = plan.phases().iter().map(|p| p.kind).collect();
        use PhaseKind::*;
        assert_eq!(kinds, vec![Stand, Drive, Stand, Turn, Drive, Stand]);
        let turn = plan.phases()[3];
        assert!((turn.yaw_to_rad - turn.yaw_from_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let mid = plan.pose_at(0.5 * (plan.phases()[1].start_s + plan.phases()[1].end_s)).unwrap();
        assert!((mid.x_m - 1.5).abs() < 1e-9 && mid.y_m.abs() < 1e-12);
        let end = plan.pose_at(1e6).unwrap();
        assert_eq!((end.x_m, end.y_m, end.kind), (3.0, 3.0, Stand));
        let stands = plan.stands_s(100.0);
        assert_eq!(stands.len(), 3);
        assert_eq!(stands[2].1, 100.0);
    }

    #[test]
    fn turns_take_the_short_way() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI / 2.0) + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let drive = RoverDrive::default();
        let plan = MotionPlan::rover(&[[0.0, 0.0], [1.0, 0.0], [1.0, -1.0], [-1.0, -1.0]], &drive).unwrap();
        let yaws: Vec<f64> = plan.phases().iter().filter(|p| p.kind == PhaseKind::Turn).map(|p| p.yaw_to_rad).collect();
        assert_eq!(yaws.len(), 2);
        assert!((yaws[0] + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((yaws[1] + std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn contact_plane_slopes_give_roll_and_pitch() {
        let plane = ContactPlane { height_m: 0.0, slope_forward: 0.2, slope_left: 0.0 };
        let (roll, pitch) = plane.roll_pitch_rad();
        assert!(roll.abs() < 1e-12 && (pitch + 0.2f64.atan()).abs() < 1e-12);
        let plane = ContactPlane { height_m: 0.0, slope_forward: 0.0, slope_left: 0.1 };
        let (roll, _) = plane.roll_pitch_rad();
        // The body's y axis climbs with the ground to the left.
        let r = nalgebra::Rotation3::from_euler_angles(roll, 0.0, 0.0);
        assert!(((r * nalgebra::Vector3::y()).z / (r * nalgebra::Vector3::y()).y - 0.1).abs() < 1e-12);
    }
}
