//! The map's world ↔ screen transform: reference-frame metres (x right, y up) to egui points
//! (x right, y down), a uniform scale and no rotation.

use egui::{Pos2, Rect, Vec2, pos2};

/// Closest and farthest zoom, px per m: a 1 cm cell fills 50 px; 1000 km fit in 100 px.
pub const MIN_PX_PER_M: f64 = 1e-4;
pub const MAX_PX_PER_M: f64 = 5_000.0;

/// Where the reference frame sits on the screen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapTransform {
    /// The world point drawn at the centre of `screen_rect`, m.
    pub center_ref_m: [f64; 2],
    /// Screen points per metre.
    pub px_per_m: f64,
    /// The map's area on the screen.
    pub screen_rect: Rect,
}

impl MapTransform {
    pub fn new(center_ref_m: [f64; 2], px_per_m: f64, screen_rect: Rect) -> Self {
        Self { center_ref_m, px_per_m: px_per_m.clamp(MIN_PX_PER_M, MAX_PX_PER_M), screen_rect }
    }

    pub fn world_to_screen(&self, x_ref_m: f64, y_ref_m: f64) -> Pos2 {
        let c = self.screen_rect.center();
        // Screen y grows downwards, world y upwards.
        pos2(
            (f64::from(c.x) + (x_ref_m - self.center_ref_m[0]) * self.px_per_m) as f32,
            (f64::from(c.y) - (y_ref_m - self.center_ref_m[1]) * self.px_per_m) as f32,
        )
    }

    /// The exact inverse of [`Self::world_to_screen`] (up to f32 rounding of the screen point).
    pub fn screen_to_world(&self, p: Pos2) -> [f64; 2] {
        let c = self.screen_rect.center();
        [
            self.center_ref_m[0] + f64::from(p.x - c.x) / self.px_per_m,
            self.center_ref_m[1] - f64::from(p.y - c.y) / self.px_per_m,
        ]
    }

    /// Moves the content with the pointer by `delta_px`.
    pub fn pan(&mut self, delta_px: Vec2) {
        self.center_ref_m[0] -= f64::from(delta_px.x) / self.px_per_m;
        self.center_ref_m[1] += f64::from(delta_px.y) / self.px_per_m;
    }

    /// Scales by `factor` keeping the world point under `anchor` (the pointer) where it is.
    pub fn zoom_about(&mut self, anchor: Pos2, factor: f64) {
        if !factor.is_finite() || factor <= 0.0 {
            return;
        }
        let anchor_ref_m = self.screen_to_world(anchor);
        self.px_per_m = (self.px_per_m * factor).clamp(MIN_PX_PER_M, MAX_PX_PER_M);
        let c = self.screen_rect.center();
        self.center_ref_m = [
            anchor_ref_m[0] - f64::from(anchor.x - c.x) / self.px_per_m,
            anchor_ref_m[1] + f64::from(anchor.y - c.y) / self.px_per_m,
        ];
    }

    /// Centres and scales so that the world box `[min_x, min_y, max_x, max_y]` fills the screen
    /// with a margin of `margin` (fraction of the screen).
    pub fn fit(&mut self, bounds_ref_m: [f64; 4], margin: f64) {
        let [min_x, min_y, max_x, max_y] = bounds_ref_m;
        if ![min_x, min_y, max_x, max_y].iter().all(|v| v.is_finite()) || max_x < min_x || max_y < min_y {
            return;
        }
        self.center_ref_m = [0.5 * (min_x + max_x), 0.5 * (min_y + max_y)];
        // A single point (one pose, nothing else) gets a 20 m wide view.
        let width_m = (max_x - min_x).max(1e-3);
        let height_m = (max_y - min_y).max(1e-3);
        let usable = (1.0 - 2.0 * margin).clamp(0.1, 1.0);
        let sx = f64::from(self.screen_rect.width()) * usable / width_m;
        let sy = f64::from(self.screen_rect.height()) * usable / height_m;
        let scale =
            if width_m <= 1e-3 && height_m <= 1e-3 { f64::from(self.screen_rect.width()) / 20.0 } else { sx.min(sy) };
        self.px_per_m = scale.clamp(MIN_PX_PER_M, MAX_PX_PER_M);
    }

    /// The world box visible on the screen, `[min_x, min_y, max_x, max_y]`.
    pub fn visible_ref_m(&self) -> [f64; 4] {
        let a = self.screen_to_world(self.screen_rect.left_bottom());
        let b = self.screen_to_world(self.screen_rect.right_top());
        [a[0], a[1], b[0], b[1]]
    }
}

/// A "nice" scale-bar length (1, 2 or 5 × 10^k m) no longer than `max_px` on the screen.
pub fn scale_bar_m(px_per_m: f64, max_px: f64) -> f64 {
    let max_m = max_px / px_per_m;
    if !max_m.is_finite() || max_m <= 0.0 {
        return 1.0;
    }
    let decade = 10f64.powf(max_m.log10().floor());
    [5.0, 2.0, 1.0].into_iter().map(|k| k * decade).find(|&len| len <= max_m).unwrap_or(decade)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use proptest::prelude::*;

    fn rect() -> Rect {
        Rect::from_min_size(pos2(100.0, 50.0), egui::vec2(800.0, 600.0))
    }

    #[test]
    fn centre_and_axes() {
        let t = MapTransform::new([10.0, -5.0], 4.0, rect());
        assert_eq!(t.world_to_screen(10.0, -5.0), pos2(500.0, 350.0));
        // +x is right, +y is up on the screen.
        assert_eq!(t.world_to_screen(11.0, -5.0), pos2(504.0, 350.0));
        assert_eq!(t.world_to_screen(10.0, -4.0), pos2(500.0, 346.0));
        assert_eq!(t.screen_to_world(pos2(100.0, 50.0)), [10.0 - 100.0, -5.0 + 75.0]);
    }

    #[test]
    fn fit_contains_the_box() {
        let mut t = MapTransform::new([0.0, 0.0], 1.0, rect());
        t.fit([-100.0, 20.0, 100.0, 60.0], 0.05);
        for (x, y) in [(-100.0, 20.0), (100.0, 60.0)] {
            assert!(t.screen_rect.contains(t.world_to_screen(x, y)));
        }
        // The limiting axis (x: 200 m into 720 px) is used.
        assert!((t.px_per_m - 720.0 / 200.0).abs() < 1e-9);
    }

    #[test]
    fn scale_bar_is_nice_and_short_enough() {
        assert_eq!(scale_bar_m(1.0, 120.0), 100.0);
        assert_eq!(scale_bar_m(10.0, 120.0), 10.0);
        assert_eq!(scale_bar_m(3.0, 120.0), 20.0);
        assert_eq!(scale_bar_m(0.5, 120.0), 200.0);
        assert_eq!(scale_bar_m(0.1, 120.0), 1000.0);
    }

    proptest! {
        #[test]
        fn screen_world_round_trip(cx in -1e4f64..1e4, cy in -1e4f64..1e4, s in 0.01f64..100.0,
                                   px in 100f32..900.0, py in 50f32..650.0) {
            let t = MapTransform::new([cx, cy], s, rect());
            let w = t.screen_to_world(pos2(px, py));
            let back = t.world_to_screen(w[0], w[1]);
            // f32 screen coordinates: ~1e-3 px at 1e4 m / 0.01 px/m.
            prop_assert!((back.x - px).abs() < 0.01 && (back.y - py).abs() < 0.01);
        }

        #[test]
        fn zoom_keeps_the_anchor_fixed(cx in -1e3f64..1e3, cy in -1e3f64..1e3, s in 0.1f64..50.0,
                                       ax in 100f32..900.0, ay in 50f32..650.0, f in 0.2f64..5.0) {
            let mut t = MapTransform::new([cx, cy], s, rect());
            let before = t.screen_to_world(pos2(ax, ay));
            t.zoom_about(pos2(ax, ay), f);
            let after = t.screen_to_world(pos2(ax, ay));
            prop_assert!((before[0] - after[0]).abs() < 1e-6 && (before[1] - after[1]).abs() < 1e-6);
            prop_assert!((t.px_per_m - s * f).abs() < 1e-9 * s * f);
        }

        #[test]
        fn pan_moves_content_with_the_pointer(dx in -500f32..500.0, dy in -500f32..500.0) {
            let mut t = MapTransform::new([3.0, 4.0], 2.5, rect());
            let before = t.world_to_screen(7.0, -2.0);
            t.pan(egui::vec2(dx, dy));
            let after = t.world_to_screen(7.0, -2.0);
            prop_assert!((after.x - before.x - dx).abs() < 1e-3 && (after.y - before.y - dy).abs() < 1e-3);
        }
    }
}
