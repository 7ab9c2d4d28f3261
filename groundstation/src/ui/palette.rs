//! Colours shared by the panels: one per robot, a height ramp, and the status colours.

use egui::Color32;

/// Obstacles on the map and in the 3D view.
pub const OBSTACLE: Color32 = Color32::from_rgb(230, 40, 40);
pub const STALE: Color32 = Color32::from_rgb(240, 190, 40);
pub const LOST: Color32 = Color32::from_rgb(240, 60, 60);
pub const GOOD: Color32 = Color32::from_rgb(90, 200, 110);
pub const DETECTION_EDGE: Color32 = Color32::from_rgb(255, 150, 40);
pub const MATCH_EDGE: Color32 = Color32::from_rgb(80, 220, 240);
/// The robots' live hazard cells on the map: a warning orange that none of the robots, the
/// edges or the height ramp uses, apart from the composed map's red obstacles.
pub const HAZARD: Color32 = Color32::from_rgb(255, 100, 20);
/// Hazard cells older than [`crate::ui::map::HAZARD_FRESH_NS`]: the same colour, faded.
pub const HAZARD_OLD: Color32 = Color32::from_rgba_premultiplied(102, 40, 8, 102);

/// Distinct, saturated colours that stay readable on the height ramp.
const ROBOT_COLOURS: [Color32; 8] = [
    Color32::from_rgb(255, 255, 255),
    Color32::from_rgb(255, 80, 200),
    Color32::from_rgb(255, 220, 0),
    Color32::from_rgb(0, 230, 255),
    Color32::from_rgb(160, 120, 255),
    Color32::from_rgb(255, 140, 0),
    Color32::from_rgb(120, 255, 120),
    Color32::from_rgb(255, 120, 120),
];

pub fn robot_colour(robot: u8) -> Color32 {
    ROBOT_COLOURS[usize::from(robot) % ROBOT_COLOURS.len()]
}

/// A perceptually ordered blue → green → yellow ramp (red is kept for obstacles); `t` in [0, 1].
pub fn height_colour(t: f32) -> Color32 {
    const STOPS: [[f32; 3]; 5] =
        [[40.0, 30.0, 110.0], [30.0, 100.0, 150.0], [30.0, 150.0, 120.0], [120.0, 190.0, 60.0], [235.0, 225.0, 90.0]];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let x = t * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |k: usize| (a[k] + (b[k] - a[k]) * f).round() as u8;
    Color32::from_rgb(mix(0), mix(1), mix(2))
}

/// The range of finite values, widened to at least 0.1 m so a flat map is not all noise.
pub fn finite_range(values: impl Iterator<Item = f32>) -> Option<(f32, f32)> {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return None;
    }
    let mid = 0.5 * (lo + hi);
    Some(if hi - lo < 0.1 { (mid - 0.05, mid + 0.05) } else { (lo, hi) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_ends_and_nan() {
        assert_eq!(height_colour(0.0), Color32::from_rgb(40, 30, 110));
        assert_eq!(height_colour(1.0), Color32::from_rgb(235, 225, 90));
        assert_eq!(height_colour(f32::NAN), height_colour(0.0));
        assert_eq!(height_colour(7.0), height_colour(1.0));
    }

    #[test]
    fn range_ignores_nan_and_widens_flat() {
        assert_eq!(finite_range([f32::NAN, 1.0, 3.0].into_iter()), Some((1.0, 3.0)));
        assert_eq!(finite_range([f32::NAN].into_iter()), None);
        let (lo, hi) = finite_range([2.0, 2.0].into_iter()).unwrap_or_default();
        assert!((hi - lo - 0.1).abs() < 1e-6);
    }
}
