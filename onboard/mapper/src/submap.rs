//! A submap (thesis §5.1.2–5.1.3): a gravity-aligned origin plus its cloud and octree, and the
//! policy that starts the next one.
//!
//! A new submap starts when the filter's position standard deviation exceeds
//! `max_position_sigma_m` or the body has travelled `max_distance_m` since the current one
//! started (the two OR-ed, trap 17). The [`Submapper`] only *requests* the switch; the filter
//! performs it ([`filter::Filter::switch_frame`]) and the resulting [`filter::FrameSwitch`] is
//! handed back to [`Submapper::on_frame_switch`], so the submap origin is by construction the
//! filter's new local frame.

use filter::FrameSwitch;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};
use vision::depth::DepthImage;
use vision::obstacles::PixelLabels;

use crate::cloud::{CLOUD_LEAF_M, VoxelCloud};
use crate::integrate::{DepthIntegrator, IntegrationStats};
use crate::occupancy::{OCTREE_RESOLUTION_M, OccupancyMap, OccupancyParams};

/// One robot's submap. Index 0 is the robot's first; submap `i > 0` starts where the filter
/// switched frames, `t_prev_this` (the previous submap's origin to this one's) is that switch's
/// transform and `switch_covariance` its 6×6 covariance (`[δt; δθ]`, filter convention): the
/// graph factor between the two origins.
#[derive(Debug, Clone, PartialEq)]
pub struct Submap {
    pub robot_id: u16,
    pub index: u32,
    pub start_stamp_ns: u64,
    /// Stamp of the last integrated depth image (the submap is finished when the next starts).
    pub end_stamp_ns: u64,
    pub t_prev_this: Isometry3<f64>,
    pub switch_covariance: Matrix6<f64>,
    pub cloud: VoxelCloud,
    pub occupancy: OccupancyMap,
    /// Depth images integrated.
    pub images: u32,
    /// Distance the body travelled while this submap was current (m).
    pub distance_m: f64,
}

impl Submap {
    /// An empty submap with the standard 5 cm cloud and 10 cm octree.
    pub fn new(
        robot_id: u16,
        index: u32,
        start_stamp_ns: u64,
        t_prev_this: Isometry3<f64>,
        switch_covariance: Matrix6<f64>,
    ) -> Submap {
        Submap {
            robot_id,
            index,
            start_stamp_ns,
            end_stamp_ns: start_stamp_ns,
            t_prev_this,
            switch_covariance,
            cloud: VoxelCloud::new(CLOUD_LEAF_M),
            occupancy: OccupancyMap::new(OCTREE_RESOLUTION_M, OccupancyParams::default()),
            images: 0,
            distance_m: 0.0,
        }
    }
}

/// When to start a new submap.
///
/// The position sigma is the square root of the largest eigenvalue of the 3×3 position
/// covariance: the standard deviation along the worst direction, so no axis exceeds the map
/// resolution (the thesis's motivation) whatever the filter's error shape. Distance is the 3D
/// path length of the filter's body positions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubmapPolicy {
    /// Thesis: 0.1 m (§5.1.3), 0.2 m in the LRU multi-robot experiments (§8.3.2).
    pub max_position_sigma_m: f64,
    /// Thesis: 3.5 m in early, 7 m in later experiments.
    pub max_distance_m: f64,
}

impl Default for SubmapPolicy {
    /// The LRU multi-robot experiments' values: 0.2 m, 7 m.
    fn default() -> Self {
        SubmapPolicy { max_position_sigma_m: 0.2, max_distance_m: 7.0 }
    }
}

impl SubmapPolicy {
    /// The early experiments' values: 0.1 m, 3.5 m.
    pub fn early() -> SubmapPolicy {
        SubmapPolicy { max_position_sigma_m: 0.1, max_distance_m: 3.5 }
    }

    /// The scalar position standard deviation the threshold applies to (see the type's doc).
    /// Non-finite covariances give infinity (a broken filter should end the submap).
    pub fn position_sigma_m(position_covariance: &Matrix3<f64>) -> f64 {
        if !position_covariance.iter().all(|v| v.is_finite()) {
            return f64::INFINITY;
        }
        let sym = (position_covariance + position_covariance.transpose()) * 0.5;
        let largest = sym.symmetric_eigenvalues().max();
        largest.max(0.0).sqrt()
    }
}

/// Why a switch was requested.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwitchReason {
    Uncertainty,
    Distance,
}

/// A request to the filter to switch frames (and so start the next submap).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwitchRequest {
    pub stamp_ns: u64,
    pub reason: SwitchReason,
    pub position_sigma_m: f64,
    pub distance_m: f64,
}

/// Owns the current submap of one robot, decides when to start the next, and integrates depth
/// images into the current one.
#[derive(Debug, Clone)]
pub struct Submapper {
    policy: SubmapPolicy,
    integrator: DepthIntegrator,
    current: Submap,
    /// Last body position in the current frame, for the path length.
    last_position: Option<Vector3<f64>>,
    /// A request was issued for the current submap (one per submap).
    requested: bool,
    started: bool,
}

impl Submapper {
    /// Starts submap 0 (origin = the filter's first local frame; start stamp set by the first
    /// filter state or image).
    pub fn new(robot_id: u16, policy: SubmapPolicy, integrator: DepthIntegrator) -> Submapper {
        Submapper {
            policy,
            integrator,
            current: Submap::new(robot_id, 0, 0, Isometry3::identity(), Matrix6::zeros()),
            last_position: None,
            requested: false,
            started: false,
        }
    }

    pub fn policy(&self) -> &SubmapPolicy {
        &self.policy
    }

    pub fn current(&self) -> &Submap {
        &self.current
    }

    pub fn integrator(&self) -> &DepthIntegrator {
        &self.integrator
    }

    /// Whether a switch was requested and has not happened yet.
    pub fn switch_pending(&self) -> bool {
        self.requested
    }

    /// A filter state: accumulates the path and checks the policy. Returns a request once per
    /// submap, when either threshold is first exceeded.
    pub fn on_filter_state(
        &mut self,
        stamp_ns: u64,
        t_local_body: &Isometry3<f64>,
        position_covariance: &Matrix3<f64>,
    ) -> Option<SwitchRequest> {
        self.touch_start(stamp_ns);
        let p = t_local_body.translation.vector;
        if let Some(last) = self.last_position
            && p.iter().all(|v| v.is_finite())
        {
            self.current.distance_m += (p - last).norm();
        }
        if p.iter().all(|v| v.is_finite()) {
            self.last_position = Some(p);
        }
        if self.requested {
            return None;
        }
        let sigma = SubmapPolicy::position_sigma_m(position_covariance);
        let reason = if sigma > self.policy.max_position_sigma_m {
            SwitchReason::Uncertainty
        } else if self.current.distance_m > self.policy.max_distance_m {
            SwitchReason::Distance
        } else {
            return None;
        };
        self.requested = true;
        Some(SwitchRequest { stamp_ns, reason, position_sigma_m: sigma, distance_m: self.current.distance_m })
    }

    /// Integrates a depth image into the current submap; `t_local_cam` is the left camera in the
    /// filter's current local frame (= the submap frame).
    pub fn integrate(
        &mut self,
        stamp_ns: u64,
        depth: &DepthImage,
        labels: Option<&PixelLabels>,
        intensity: Option<&[u8]>,
        t_local_cam: &Isometry3<f64>,
    ) -> IntegrationStats {
        self.touch_start(stamp_ns);
        let stats = self.integrator.integrate(&mut self.current, depth, labels, intensity, t_local_cam);
        self.current.end_stamp_ns = self.current.end_stamp_ns.max(stamp_ns);
        stats
    }

    /// The filter switched frames: finishes the current submap and starts the next at the new
    /// frame, recording the switch transform and covariance on the new one. Returns the finished
    /// submap.
    pub fn on_frame_switch(&mut self, switch: &FrameSwitch) -> Submap {
        let robot_id = self.current.robot_id;
        let index = self.current.index.wrapping_add(1);
        let next = Submap::new(robot_id, index, switch.stamp_ns, switch.t_old_new, switch.covariance);
        let finished = std::mem::replace(&mut self.current, next);
        self.started = true;
        // The path continues from where the body was, expressed in the new frame.
        self.last_position = self.last_position.map(|p| switch.t_old_new.inverse_transform_point(&p.into()).coords);
        self.requested = false;
        finished
    }

    /// Submap 0 starts at the first stamp seen.
    fn touch_start(&mut self, stamp_ns: u64) {
        if !self.started {
            self.started = true;
            self.current.start_stamp_ns = stamp_ns;
            self.current.end_stamp_ns = stamp_ns;
        }
    }
}
