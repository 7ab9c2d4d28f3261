//! Negative edges (cliffs) straight in the depth image (thesis eq. 5.1, spec trap 12).
//!
//! Each pixel is compared with its upper neighbour only. A depth jump above the threshold makes
//! the pair a candidate; which of the two points is the cliff's top is decided by their heights
//! in the gravity-aligned frame, not by the image row (with a downward-looking camera the upper
//! pixel usually sees the farther, lower ground). The minimal slope between top and bottom,
//! `s_min = (top_z − bottom_z) / horizontal distance`, is what the rover would have to descend.
//!
//! A zero-disparity pixel (infinite depth) next to a finite one is a jump too: the ray through
//! it passes the finite point and never meets the ground again, so the ground beyond the finite
//! point (the top) stays below that ray and falls at least as steeply as the ray itself. `s_min`
//! is then the ray's downward slope; a ray above the horizon (sky) gives `s_min ≤ 0`, no edge.
//! Invalid pixels (NaN, no match) never form a pair themselves. **Unknown beyond a rim**
//! (`ObstacleConfig::bridge_invalid_px`): a valid pixel is also paired with the nearest valid
//! pixel below it across a short run of unmatched ones. Stereo leaves the ground beyond a rim
//! unmatched where it is hidden (the far side of a crater edge) or black (a shadowed ditch); the
//! next valid pixel up the column is then the first ground seen again, and the test between the
//! rim and it is the thesis's test across the hidden strip: the ground in between is not seen,
//! so the rover may not assume it is there, and `s_min` from the rim down to the far point is
//! the least it would have to descend. Where the unseen strip is only a small shadow on level
//! ground (behind a rock), the far point is as high as the near one and `s_min` stays small.
//! Across a bridged run an infinite upper pixel's ray passes a little above the rim, so its
//! slope bounds the drop only up to that margin, which a short run keeps small.

/// What a pixel contributes to the test, in the gravity-aligned local frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) enum EdgePixel {
    #[default]
    Invalid,
    /// Direction of the pixel's ray (any length).
    Infinite {
        ray_local: [f64; 3],
    },
    Finite {
        depth_m: f32,
        p_local: [f64; 3],
    },
}

/// Which pixel of a candidate pair is the cliff's top.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Top {
    Upper,
    Lower,
}

/// `s_min` of eq. 5.1 for a top `p` and bottom `q`; infinite when they are vertically aligned.
pub fn min_slope(p_top: &[f64; 3], q_bottom: &[f64; 3]) -> f64 {
    let horizontal = (q_bottom[0] - p_top[0]).hypot(q_bottom[1] - p_top[1]);
    let drop = p_top[2] - q_bottom[2];
    if horizontal > 0.0 { drop / horizontal } else { f64::INFINITY * drop.signum() }
}

/// Downward slope of a ray (positive below the horizon).
fn ray_slope(ray: &[f64; 3]) -> f64 {
    let horizontal = ray[0].hypot(ray[1]);
    if horizontal > 0.0 { -ray[2] / horizontal } else { f64::INFINITY * (-ray[2]).signum() }
}

/// The top pixel and `s_min` of an upper/lower pixel pair, when their depths jump by more than
/// `jump_m`.
pub(crate) fn test_pair(upper: &EdgePixel, lower: &EdgePixel, jump_m: f64) -> Option<(Top, f64)> {
    match (upper, lower) {
        (EdgePixel::Finite { depth_m: a, p_local: pa }, EdgePixel::Finite { depth_m: b, p_local: pb }) => {
            if f64::from((a - b).abs()) <= jump_m {
                return None;
            }
            Some(if pa[2] >= pb[2] { (Top::Upper, min_slope(pa, pb)) } else { (Top::Lower, min_slope(pb, pa)) })
        }
        (EdgePixel::Infinite { ray_local }, EdgePixel::Finite { .. }) => Some((Top::Lower, ray_slope(ray_local))),
        (EdgePixel::Finite { .. }, EdgePixel::Infinite { ray_local }) => Some((Top::Upper, ray_slope(ray_local))),
        _ => None,
    }
}

/// **Hidden drop** (`ObstacleConfig::hidden_drops`): the drop from a rim down to the next
/// ground seen beyond it in the same column, when that ground lies farther from the camera
/// (`cam_xy`), more than `min_drop_m` lower, and the depths jump by more than `jump_m` (or
/// unmatched pixels lie between). The ground in between is out of view (below the ray grazing
/// the rim, or unmatched), so nothing says the rover could descend it, whatever the slope of the
/// straight line from rim to far point; the thesis's test would call a far crater floor seen
/// over a rim traversable when that line is gentle.
pub(crate) fn hidden_drop(
    upper: &EdgePixel,
    lower: &EdgePixel,
    jump_m: f64,
    cam_xy: [f64; 2],
    min_drop_m: impl Fn(f32) -> f64,
) -> Option<f64> {
    let (
        EdgePixel::Finite { depth_m: far_depth, p_local: far },
        EdgePixel::Finite { depth_m: rim_depth, p_local: rim },
    ) = (upper, lower)
    else {
        return None;
    };
    if f64::from(far_depth - rim_depth) <= jump_m {
        return None;
    }
    let reach = |p: &[f64; 3]| (p[0] - cam_xy[0]).hypot(p[1] - cam_xy[1]);
    let drop = rim[2] - far[2];
    (reach(far) > reach(rim) && drop > min_drop_m(*far_depth)).then_some(drop)
}

/// The ground hidden between a rim (`lower`) and the next ground seen beyond it (`upper`)
/// across unmatched pixels: the horizontal distance between them, when the far point is
/// farther from the camera and not higher than the rim (a rising far side is a wall the step
/// test sees).
pub(crate) fn unseen_gap(upper: &EdgePixel, lower: &EdgePixel, cam_xy: [f64; 2]) -> Option<f64> {
    let (EdgePixel::Finite { p_local: far, .. }, EdgePixel::Finite { p_local: rim, .. }) = (upper, lower) else {
        return None;
    };
    let reach = |p: &[f64; 3]| (p[0] - cam_xy[0]).hypot(p[1] - cam_xy[1]);
    (reach(far) > reach(rim) && far[2] <= rim[2]).then(|| (far[0] - rim[0]).hypot(far[1] - rim[1]))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn finite(depth_m: f32, p_local: [f64; 3]) -> EdgePixel {
        EdgePixel::Finite { depth_m, p_local }
    }

    #[test]
    fn top_is_the_higher_point_whatever_the_row() {
        // Upper pixel sees far ground 1 m below the near edge: the lower pixel is the top.
        let (top, s) = test_pair(&finite(4.0, [4.0, 0.0, -1.0]), &finite(3.0, [3.0, 0.0, 0.0]), 0.2).unwrap();
        assert_eq!(top, Top::Lower);
        assert!((s - 1.0).abs() < 1e-12);
        // A rock face below, ground behind it lower: the rock top (lower pixel) again.
        let (top, _) = test_pair(&finite(3.5, [3.5, 0.0, 0.0]), &finite(3.2, [3.2, 0.0, 0.4]), 0.2).unwrap();
        assert_eq!(top, Top::Lower);
        // An overhang seen from below: the upper pixel's point is higher.
        let (top, _) = test_pair(&finite(2.0, [2.0, 0.0, 0.5]), &finite(3.0, [3.0, 0.0, 0.0]), 0.2).unwrap();
        assert_eq!(top, Top::Upper);
    }

    #[test]
    fn small_jumps_and_invalid_pixels_are_no_edge() {
        assert_eq!(test_pair(&finite(3.1, [3.1, 0.0, 0.0]), &finite(3.0, [3.0, 0.0, 0.0]), 0.2), None);
        assert_eq!(test_pair(&EdgePixel::Invalid, &finite(3.0, [3.0, 0.0, 0.0]), 0.2), None);
        assert_eq!(test_pair(&finite(3.0, [3.0, 0.0, 0.0]), &EdgePixel::Invalid, 0.2), None);
    }

    #[test]
    fn a_far_point_lower_than_the_rim_by_more_than_the_step_is_a_hidden_drop() {
        let rim = finite(3.0, [3.0, 0.0, 0.0]);
        let floor = finite(4.6, [4.5, 0.0, -0.4]);
        assert_eq!(hidden_drop(&floor, &rim, 0.2, [0.0, 0.0], |_| 0.15), Some(0.4));
        // Less than the step, nearer than the rim, or no jump: none.
        assert_eq!(hidden_drop(&finite(4.6, [4.5, 0.0, -0.1]), &rim, 0.2, [0.0, 0.0], |_| 0.15), None);
        assert_eq!(hidden_drop(&floor, &rim, 0.2, [10.0, 0.0], |_| 0.15), None);
        assert_eq!(hidden_drop(&finite(3.1, [3.1, 0.0, -0.4]), &rim, 0.2, [0.0, 0.0], |_| 0.15), None);
        assert_eq!(hidden_drop(&EdgePixel::Invalid, &rim, 0.2, [0.0, 0.0], |_| 0.15), None);
    }

    #[test]
    fn infinite_depth_gives_the_ray_slope() {
        let below = EdgePixel::Infinite { ray_local: [2.0, 0.0, -1.0] };
        let (top, s) = test_pair(&below, &finite(3.0, [3.0, 0.0, 0.0]), 0.2).unwrap();
        assert_eq!(top, Top::Lower);
        assert!((s - 0.5).abs() < 1e-12);
        let sky = EdgePixel::Infinite { ray_local: [1.0, 0.0, 0.1] };
        let (_, s) = test_pair(&sky, &finite(3.0, [3.0, 0.0, 0.0]), 0.2).unwrap();
        assert!(s < 0.0);
    }
}
