//! The pan-tilt head as the simulator executes a firmware's commands: each joint moves towards
//! its target at the commanded rate (at most the head's own [`PAN_RATE_MAX_RADPS`]) and stops
//! there, within the mechanical limits.
//!
//! Until the first command the head follows the scenario's script ([`World::head_angles`]: the
//! mounted tilt, a pan sweep at each stop); from the first command on it is the firmware's.

use hal::sensor::{HeadTarget, PanTiltHead};

use crate::world::PAN_RATE_MAX_RADPS;

/// One head's joints over time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadServo {
    limits: PanTiltHead,
    /// Angles at `stamp_ns`.
    pan_rad: f64,
    tilt_rad: f64,
    stamp_ns: u64,
    target: HeadTarget,
}

impl HeadServo {
    /// A head at `(pan_rad, tilt_rad)` at `stamp_ns`, about to move towards `target`.
    pub fn new(limits: PanTiltHead, (pan_rad, tilt_rad): (f64, f64), stamp_ns: u64, target: HeadTarget) -> Self {
        let hold = HeadTarget { stamp_ns, pan_rad, tilt_rad, max_rate_radps: PAN_RATE_MAX_RADPS };
        let mut servo = HeadServo { limits, pan_rad, tilt_rad, stamp_ns, target: hold };
        servo.command(target);
        servo
    }

    /// A new target from `target.stamp_ns` on (a command stamped before the head's last known
    /// instant takes effect at that instant: time does not run backwards).
    pub fn command(&mut self, target: HeadTarget) {
        self.advance(target.stamp_ns);
        let rate = if target.max_rate_radps.is_finite() && target.max_rate_radps > 0.0 {
            target.max_rate_radps.min(PAN_RATE_MAX_RADPS)
        } else {
            PAN_RATE_MAX_RADPS
        };
        let finite_or = |v: f64, keep: f64| if v.is_finite() { v } else { keep };
        self.target = HeadTarget {
            pan_rad: finite_or(target.pan_rad, self.pan_rad)
                .clamp(-self.limits.pan_limit_rad, self.limits.pan_limit_rad),
            tilt_rad: finite_or(target.tilt_rad, self.tilt_rad)
                .clamp(-self.limits.tilt_limit_rad, self.limits.tilt_limit_rad),
            max_rate_radps: rate,
            stamp_ns: target.stamp_ns.max(self.stamp_ns),
        };
    }

    /// The joint angles at `stamp_ns` (not before the last query or command).
    pub fn angles_at(&mut self, stamp_ns: u64) -> (f64, f64) {
        self.advance(stamp_ns);
        (self.pan_rad, self.tilt_rad)
    }

    fn advance(&mut self, stamp_ns: u64) {
        if stamp_ns <= self.stamp_ns {
            return;
        }
        let step = self.target.max_rate_radps * (stamp_ns - self.stamp_ns) as f64 * 1e-9;
        let towards = |from: f64, to: f64| from + (to - from).clamp(-step, step);
        self.pan_rad = towards(self.pan_rad, self.target.pan_rad);
        self.tilt_rad = towards(self.tilt_rad, self.target.tilt_rad);
        self.stamp_ns = stamp_ns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn target(stamp_s: f64, pan_rad: f64, tilt_rad: f64, rate: f64) -> HeadTarget {
        HeadTarget { stamp_ns: (stamp_s * 1e9) as u64, pan_rad, tilt_rad, max_rate_radps: rate }
    }

    #[test]
    fn joints_move_at_the_rate_and_stop_at_the_target() {
        let mut servo = HeadServo::new(PanTiltHead::lru(), (0.0, 0.25), 0, target(1.0, 0.5, 0.45, 0.4));
        assert_eq!(servo.angles_at(1_000_000_000), (0.0, 0.25));
        let (pan, tilt) = servo.angles_at(1_250_000_000);
        assert!((pan - 0.1).abs() < 1e-12 && (tilt - 0.35).abs() < 1e-12, "{pan} {tilt}");
        let (pan, tilt) = servo.angles_at(1_500_000_000);
        assert!((pan - 0.2).abs() < 1e-12 && (tilt - 0.45).abs() < 1e-12, "{pan} {tilt}");
        assert_eq!(servo.angles_at(3_000_000_000), (0.5, 0.45));
    }

    #[test]
    fn rate_and_angles_are_limited_and_time_never_runs_back() {
        let mut servo = HeadServo::new(PanTiltHead::lru(), (0.0, 0.0), 0, target(0.0, 0.0, 3.0, 100.0));
        let (_, tilt) = servo.angles_at(1_000_000_000);
        assert!((tilt - PAN_RATE_MAX_RADPS).abs() < 1e-12, "{tilt}");
        assert_eq!(servo.angles_at(10_000_000_000).1, std::f64::consts::FRAC_PI_2);
        // A late command starts where the head is now.
        servo.command(target(5.0, 0.1, f64::NAN, 0.5));
        assert_eq!(servo.angles_at(10_000_000_000), (0.0, std::f64::consts::FRAC_PI_2));
        let (pan, _) = servo.angles_at(10_100_000_000);
        assert!((pan - 0.05).abs() < 1e-12, "{pan}");
    }
}
