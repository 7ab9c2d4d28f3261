//! The gaze policy: where the pan-tilt head looks, decided on board at the vision task's rate.
//!
//! While the rover drives, the head alternates a **look ahead** at the mounted tilt (the view the
//! odometry and the mapper are tuned for, ground from about 2 m to the 4.5 m range cutoff) with
//! a shorter **look down** at the ground within and just beyond the stopping distance (from
//! about 1.1 m): the thesis's edge rule only finds a rim where the camera looks steeply enough
//! over it, which at the mounted tilt happens nearer than the stopping distance. While it stands
//! (after [`GazeOptions::standing_s`]) the head **sweeps** its pan to both sides at the look-ahead
//! tilt, as the LRU does at a stop, so the mapper and the robot detector see around the rover.
//!
//! Motion comes from the filter states: the rover moves when its horizontal speed or its yaw
//! rate exceeds [`GazeOptions::moving_mps`] / [`GazeOptions::turning_radps`]. A command is
//! published when the target changes and repeated every [`GazeOptions::resend_s`] (the topic
//! drops the oldest sample when full, so a lost command is replaced soon).
//!
//! The head's real angles at each capture come back in the stereo headers; nothing here assumes
//! a command was executed.

use msgs::HeadCommandMsg;

/// The policy's parameters (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeOptions {
    /// Tilt of the look ahead (down positive): the head's mounted tilt.
    pub ahead_tilt_rad: f64,
    /// Tilt of the look down.
    pub down_tilt_rad: f64,
    /// How long each look lasts from its command, the move there included.
    pub ahead_s: f64,
    pub down_s: f64,
    /// Joint rate for the looks while driving.
    pub rate_radps: f64,
    /// Pan amplitude and joint rate of the sweep at a stop.
    pub sweep_pan_rad: f64,
    pub sweep_rate_radps: f64,
    /// The rover moves above this horizontal speed or yaw rate.
    pub moving_mps: f64,
    pub turning_radps: f64,
    /// Standing this long starts the sweep.
    pub standing_s: f64,
    pub resend_s: f64,
}

impl GazeOptions {
    /// The LRU-like rover of the simulator: head about 1.4 m above the ground, 39° vertical
    /// field of view, mounted 0.25 rad down. At 0.55 rad the image's lower edge meets level
    /// ground 1.1 m ahead of the camera and its centre 2.3 m ahead, both within or at the 1.5 m
    /// stopping distance plus the rover's half length; a 0.3 rad move takes 0.375 s at 0.8 rad/s
    /// (the head's limit), so a 1 s look down has 0.6 s of still frames at 10 Hz.
    pub fn lru() -> Self {
        GazeOptions {
            ahead_tilt_rad: 0.25,
            down_tilt_rad: 0.55,
            ahead_s: 1.5,
            down_s: 1.0,
            rate_radps: 0.8,
            sweep_pan_rad: 1.0,
            sweep_rate_radps: 0.5,
            moving_mps: 0.05,
            turning_radps: 0.1,
            standing_s: 1.0,
            resend_s: 1.0,
        }
    }

    /// A refusal of nonsensical values: the field's name and the problem.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let half_pi = std::f64::consts::FRAC_PI_2;
        for (name, value, low, high) in [
            ("ahead_tilt_rad", self.ahead_tilt_rad, -half_pi, half_pi),
            ("down_tilt_rad", self.down_tilt_rad, -half_pi, half_pi),
            ("ahead_s", self.ahead_s, 0.05, 60.0),
            ("down_s", self.down_s, 0.0, 60.0),
            ("rate_radps", self.rate_radps, 0.01, 10.0),
            ("sweep_pan_rad", self.sweep_pan_rad, 0.0, std::f64::consts::PI),
            ("sweep_rate_radps", self.sweep_rate_radps, 0.01, 10.0),
            ("moving_mps", self.moving_mps, 0.0, 10.0),
            ("turning_radps", self.turning_radps, 0.0, 10.0),
            ("standing_s", self.standing_s, 0.0, 600.0),
            ("resend_s", self.resend_s, 0.05, 600.0),
        ] {
            if !(value.is_finite() && (low..=high).contains(&value)) {
                return Err((name, format!("{value}: expected {low}..={high}")));
            }
        }
        Ok(())
    }
}

/// What the policy is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Look {
    Ahead,
    Down,
    /// Panning towards `+1` or `-1` times the amplitude.
    Sweep {
        side: f64,
    },
}

/// A target for the head.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeTarget {
    pub pan_rad: f64,
    pub tilt_rad: f64,
    pub max_rate_radps: f64,
    /// [`HeadCommandMsg::LOOK_AHEAD`], [`HeadCommandMsg::LOOK_DOWN`] or [`HeadCommandMsg::SWEEP`].
    pub mode: u32,
}

/// The policy's state (see the module documentation).
#[derive(Debug, Clone)]
pub struct GazePolicy {
    options: GazeOptions,
    look: Look,
    /// When the current look was commanded, and how long the head needs to get there.
    since_ns: u64,
    travel_s: f64,
    standing_since_ns: Option<u64>,
    last_sent_ns: Option<u64>,
    /// The last target, which the head is assumed to reach at the commanded rate.
    target: GazeTarget,
}

impl GazePolicy {
    pub fn new(options: GazeOptions) -> Self {
        let target = GazeTarget {
            pan_rad: 0.0,
            tilt_rad: options.ahead_tilt_rad,
            max_rate_radps: options.rate_radps,
            mode: HeadCommandMsg::LOOK_AHEAD,
        };
        GazePolicy {
            options,
            look: Look::Ahead,
            since_ns: 0,
            travel_s: 0.0,
            standing_since_ns: None,
            last_sent_ns: None,
            target,
        }
    }

    pub fn options(&self) -> &GazeOptions {
        &self.options
    }

    /// The current target.
    pub fn target(&self) -> GazeTarget {
        self.target
    }

    /// One decision at `now_ns` for a rover moving at `speed_mps` (horizontal) and
    /// `yaw_rate_radps`: the target to send now, if any (a change, or the periodic repeat).
    pub fn update(&mut self, now_ns: u64, speed_mps: f64, yaw_rate_radps: f64) -> Option<GazeTarget> {
        let o = self.options;
        let moving = speed_mps > o.moving_mps || yaw_rate_radps.abs() > o.turning_radps;
        let elapsed_s = now_ns.saturating_sub(self.since_ns) as f64 * 1e-9;
        let next = if moving {
            self.standing_since_ns = None;
            match self.look {
                Look::Sweep { .. } => Some(Look::Ahead),
                // Turning on the spot: keep the view the odometry tracks.
                Look::Ahead if speed_mps > o.moving_mps && o.down_s > 0.0 && elapsed_s >= o.ahead_s => Some(Look::Down),
                Look::Down if elapsed_s >= o.down_s => Some(Look::Ahead),
                _ => None,
            }
        } else {
            let standing_since = *self.standing_since_ns.get_or_insert(now_ns);
            let standing_s = now_ns.saturating_sub(standing_since) as f64 * 1e-9;
            match self.look {
                Look::Sweep { side } if elapsed_s >= self.travel_s => Some(Look::Sweep { side: -side }),
                Look::Sweep { .. } => None,
                _ if standing_s >= o.standing_s && o.sweep_pan_rad > 0.0 => Some(Look::Sweep { side: 1.0 }),
                Look::Down => Some(Look::Ahead),
                Look::Ahead => None,
            }
        };
        if let Some(look) = next {
            self.start(look, now_ns);
            self.last_sent_ns = Some(now_ns);
            return Some(self.target);
        }
        let repeat = self.last_sent_ns.is_none_or(|t| now_ns.saturating_sub(t) as f64 * 1e-9 >= o.resend_s);
        if repeat {
            self.last_sent_ns = Some(now_ns);
            return Some(self.target);
        }
        None
    }

    fn start(&mut self, look: Look, now_ns: u64) {
        let o = self.options;
        let target = match look {
            Look::Ahead => GazeTarget {
                pan_rad: 0.0,
                tilt_rad: o.ahead_tilt_rad,
                max_rate_radps: o.rate_radps,
                mode: HeadCommandMsg::LOOK_AHEAD,
            },
            Look::Down => GazeTarget {
                pan_rad: 0.0,
                tilt_rad: o.down_tilt_rad,
                max_rate_radps: o.rate_radps,
                mode: HeadCommandMsg::LOOK_DOWN,
            },
            Look::Sweep { side } => GazeTarget {
                pan_rad: side * o.sweep_pan_rad,
                tilt_rad: o.ahead_tilt_rad,
                max_rate_radps: o.sweep_rate_radps,
                mode: HeadCommandMsg::SWEEP,
            },
        };
        let travel = (target.pan_rad - self.target.pan_rad).abs().max((target.tilt_rad - self.target.tilt_rad).abs());
        self.travel_s = travel / target.max_rate_radps;
        self.look = look;
        self.since_ns = now_ns;
        self.target = target;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    fn run(policy: &mut GazePolicy, from_s: f64, to_s: f64, speed: f64, yaw_rate: f64) -> Vec<(f64, GazeTarget)> {
        let mut out = Vec::new();
        let mut t = from_s;
        while t < to_s - 1e-9 {
            let now = (t * S as f64).round() as u64;
            if let Some(target) = policy.update(now, speed, yaw_rate) {
                out.push((t, target));
            }
            t += 0.05;
        }
        out
    }

    #[test]
    fn driving_alternates_ahead_and_down() {
        let mut policy = GazePolicy::new(GazeOptions::lru());
        let sent = run(&mut policy, 0.0, 6.0, 0.3, 0.0);
        let changes: Vec<(f64, u32)> = sent
            .windows(2)
            .filter(|w| w[0].1.mode != w[1].1.mode)
            .map(|w| ((w[1].0 * 100.0).round() / 100.0, w[1].1.mode))
            .collect();
        assert_eq!(
            changes,
            vec![
                (1.5, HeadCommandMsg::LOOK_DOWN),
                (2.5, HeadCommandMsg::LOOK_AHEAD),
                (4.0, HeadCommandMsg::LOOK_DOWN),
                (5.0, HeadCommandMsg::LOOK_AHEAD)
            ]
        );
        let down = sent.iter().find(|(_, t)| t.mode == HeadCommandMsg::LOOK_DOWN).map(|(_, t)| *t);
        assert_eq!(down.map(|t| (t.pan_rad, t.tilt_rad)), Some((0.0, 0.55)));
        // Repeated at least once a second even without a change.
        assert!(sent.windows(2).all(|w| w[1].0 - w[0].0 <= 1.0 + 1e-9), "{sent:?}");
    }

    #[test]
    fn a_stop_sweeps_both_sides_and_driving_off_looks_ahead() {
        let mut policy = GazePolicy::new(GazeOptions::lru());
        run(&mut policy, 0.0, 0.5, 0.3, 0.0);
        let sent = run(&mut policy, 0.5, 8.0, 0.0, 0.0);
        let sweeps: Vec<(f64, f64)> = sent
            .iter()
            .filter(|(_, t)| t.mode == HeadCommandMsg::SWEEP)
            .map(|(t, g)| ((t * 100.0).round() / 100.0, g.pan_rad))
            .collect();
        // Standing from 0.5 s: sweep at 1.5 s to +1 rad (2 s at 0.5 rad/s), then −1 (4 s).
        assert_eq!(sweeps.first(), Some(&(1.5, 1.0)));
        assert!(sweeps.contains(&(3.5, -1.0)), "{sweeps:?}");
        assert!(sweeps.contains(&(7.5, 1.0)), "{sweeps:?}");
        let drive = run(&mut policy, 8.0, 8.2, 0.3, 0.0);
        assert_eq!(drive.first().map(|(_, g)| (g.mode, g.pan_rad)), Some((HeadCommandMsg::LOOK_AHEAD, 0.0)));
    }

    #[test]
    fn turning_on_the_spot_keeps_looking_ahead() {
        let mut policy = GazePolicy::new(GazeOptions::lru());
        let sent = run(&mut policy, 0.0, 10.0, 0.0, 0.3);
        assert!(sent.iter().all(|(_, g)| g.mode == HeadCommandMsg::LOOK_AHEAD), "{sent:?}");
    }

    #[test]
    fn options_are_checked() {
        assert!(GazeOptions::lru().validate().is_ok());
        let bad = GazeOptions { rate_radps: 0.0, ..GazeOptions::lru() };
        assert!(bad.validate().is_err_and(|(field, _)| field == "rate_radps"));
    }
}
