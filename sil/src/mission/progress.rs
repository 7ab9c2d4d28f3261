//! The one-line progress display of a mission on a terminal: how far the simulated time is, how
//! fast it goes, and per robot what its SLAM has so far. A full-resolution mission runs for
//! many minutes; the line tells an operator whether the team has met and is closing loops
//! before the report does.

use std::io::Write;
use std::time::{Duration, Instant};

/// How often the line is redrawn (wall time).
const REDRAW: Duration = Duration::from_secs(1);

/// What one robot has at a moment of the mission.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotProgress {
    pub robot: u16,
    /// Length of its online trajectory (m).
    pub distance_m: f64,
    pub submaps: u64,
    /// Submap matches accepted by its own matcher.
    pub matches: u64,
    /// Robot detections in its graph.
    pub detections: u64,
    /// Robots connected to its frame, itself included.
    pub connected: Vec<u16>,
}

/// The progress line of a mission of `duration_s` simulated seconds, drawn to standard error
/// when enabled.
#[derive(Debug)]
pub struct Progress {
    enabled: bool,
    duration_s: f64,
    started: Instant,
    drawn: Option<Instant>,
}

impl Progress {
    pub fn new(enabled: bool, duration_s: f64) -> Progress {
        Progress { enabled, duration_s, started: Instant::now(), drawn: None }
    }

    /// Whether the line should be redrawn now (never when disabled).
    pub fn due(&self) -> bool {
        self.enabled && self.drawn.is_none_or(|t| t.elapsed() >= REDRAW)
    }

    /// Redraws the line for `sensor_s` simulated seconds done.
    pub fn draw(&mut self, sensor_s: f64, robots: &[RobotProgress]) {
        if !self.enabled {
            return;
        }
        let line = line(sensor_s, self.duration_s, self.started.elapsed().as_secs_f64(), robots);
        // `\r` and "erase to the end of the line": the line shrinks as well as grows.
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r{line}\x1b[K");
        let _ = err.flush();
        self.drawn = Some(Instant::now());
    }

    /// Ends the line, so that what is printed next starts on its own.
    pub fn finish(&mut self) {
        if self.enabled && self.drawn.is_some() {
            let _ = writeln!(std::io::stderr());
        }
    }
}

/// The text of the line.
pub fn line(sensor_s: f64, duration_s: f64, wall_s: f64, robots: &[RobotProgress]) -> String {
    let rtf = if wall_s > 0.0 { sensor_s / wall_s } else { 0.0 };
    let mut text = format!("{sensor_s:>5.0}/{duration_s:.0} s sim, {wall_s:.0} s wall, x{rtf:.2}");
    for r in robots {
        let connected: Vec<String> = r.connected.iter().map(u16::to_string).collect();
        text.push_str(&format!(
            " | r{}: {:.0} m, {} submaps, {} matches, {} detections, with [{}]",
            r.robot,
            r.distance_m,
            r.submaps,
            r.matches,
            r.detections,
            connected.join(",")
        ));
    }
    text
}

/// Length of a trajectory's positions (m).
pub fn path_length_m(trajectory: &[(u64, nalgebra::Isometry3<f64>)]) -> f64 {
    // A fold from +0: `Sum` of no steps is -0, which prints as "-0 m".
    trajectory
        .windows(2)
        .map(|w| (w[1].1.translation.vector - w[0].1.translation.vector).norm())
        .fold(0.0, |a, b| a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_says_time_speed_and_each_robot_s_state() {
        let robots = [
            RobotProgress { robot: 1, distance_m: 12.4, submaps: 2, matches: 1, detections: 3, connected: vec![1, 2] },
            RobotProgress { robot: 2, distance_m: 9.6, submaps: 1, matches: 0, detections: 0, connected: vec![2] },
        ];
        let text = line(30.0, 600.0, 60.0, &robots);
        assert_eq!(
            text,
            "   30/600 s sim, 60 s wall, x0.50 | r1: 12 m, 2 submaps, 1 matches, 3 detections, with [1,2] \
             | r2: 10 m, 1 submaps, 0 matches, 0 detections, with [2]"
        );
        assert!(line(0.0, 10.0, 0.0, &[]).contains("x0.00"));
    }

    #[test]
    fn a_disabled_line_is_never_due() {
        let mut off = Progress::new(false, 10.0);
        assert!(!off.due());
        off.draw(1.0, &[]);
        assert!(!off.due());
        let mut on = Progress::new(true, 10.0);
        assert!(on.due());
        on.drawn = Some(Instant::now());
        assert!(!on.due(), "redrawn at most once per second");
    }

    #[test]
    fn path_length_sums_the_steps() {
        let at = |x: f64, y: f64| nalgebra::Isometry3::translation(x, y, 0.0);
        assert!(path_length_m(&[]).is_sign_positive() && path_length_m(&[]) == 0.0);
        assert!((path_length_m(&[(0, at(0.0, 0.0)), (1, at(3.0, 4.0)), (2, at(3.0, 0.0))]) - 9.0).abs() < 1e-12);
    }
}
