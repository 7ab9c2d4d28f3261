//! Rocks: solids resting on the ground, baked into the heightfield as lumpy ellipsoid caps
//! added to the ground, so the top stands exactly the listed height above the ground beneath
//! the centre.

use nalgebra::Point3;

use super::craters::index_range;
use super::ditches::distance_to_segment_m;
use super::{Ditch, Heightfield, Material, Rock, TerrainConfig};
use crate::rng::Rng;

const ATTEMPTS_PER_ROCK: usize = 30;
/// Gap kept between rocks, and between a rock and a ditch's edge.
const CLEARANCE_M: f64 = 0.1;

/// The shape of one rock in its own frame.
#[derive(Debug, Clone, Copy)]
struct Shape {
    height_m: f64,
    /// Semi-axes of the elliptic footprint before the lobes.
    semi_major_m: f64,
    semi_minor_m: f64,
    cos_yaw: f64,
    sin_yaw: f64,
    /// Angular lobes (3- and 5-fold) that make the outline irregular.
    lobes: [(f64, f64); 2],
    /// Exponent of the cap `(1 − ρ²)^e`: 0.5 is an ellipsoid, smaller is flatter-topped.
    exponent: f64,
}

impl Shape {
    fn radius_m(&self) -> f64 {
        self.semi_major_m * (1.0 + self.lobes[0].0 + self.lobes[1].0)
    }

    /// Height above the ground at offset `(dx, dy)` from the centre, `None` outside.
    fn height_at(&self, dx: f64, dy: f64) -> Option<f64> {
        let u = (dx * self.cos_yaw + dy * self.sin_yaw) / self.semi_major_m;
        let v = (-dx * self.sin_yaw + dy * self.cos_yaw) / self.semi_minor_m;
        let rho2 = u * u + v * v;
        if rho2 >= (1.0 + self.lobes[0].0 + self.lobes[1].0).powi(2) {
            return None;
        }
        let theta = v.atan2(u);
        let lobe = 1.0
            + self.lobes[0].0 * (3.0 * theta + self.lobes[0].1).cos()
            + self.lobes[1].0 * (5.0 * theta + self.lobes[1].1).cos();
        let rho2 = rho2 / (lobe * lobe);
        (rho2 < 1.0).then(|| self.height_m * (1.0 - rho2).powf(self.exponent))
    }
}

/// Draws the rock population of `config`, keeps it clear of ditches, keep-clear areas and other
/// rocks, and bakes it into `hf` and `material`.
pub(super) fn place(
    config: &TerrainConfig,
    hf: &mut Heightfield,
    material: &mut [u8],
    ditches: &[Ditch],
    mut rng: Rng,
) -> Vec<Rock> {
    let (lo, hi) = hf.bounds_m();
    let area_m2 = (hi[0] - lo[0]) * (hi[1] - lo[1]);
    let count = (config.rocks_per_100m2 * area_m2 / 100.0).round().max(0.0) as usize;
    let [h_min, h_max] = config.rock_height_m;
    let b = config.rock_size_exponent;
    if !(h_min > 0.0 && h_max >= h_min && b > 0.0) {
        return Vec::new();
    }
    let res = hf.resolution_m;
    let mut rocks: Vec<Rock> = Vec::with_capacity(count);
    for _ in 0..count {
        let u = rng.uniform();
        let height_m = (h_min.powf(-b) - u * (h_min.powf(-b) - h_max.powf(-b))).powf(-1.0 / b);
        let semi_major_m = height_m * rng.range(1.0, 1.8);
        let (sin_yaw, cos_yaw) = rng.range(0.0, std::f64::consts::PI).sin_cos();
        let shape = Shape {
            height_m,
            semi_major_m,
            semi_minor_m: semi_major_m * rng.range(0.6, 1.0),
            cos_yaw,
            sin_yaw,
            lobes: [
                (rng.range(0.0, 0.12), rng.range(0.0, std::f64::consts::TAU)),
                (rng.range(0.0, 0.08), rng.range(0.0, std::f64::consts::TAU)),
            ],
            exponent: rng.range(0.3, 0.5),
        };
        let radius_m = shape.radius_m();
        let margin = radius_m + 2.0 * res;
        if hi[0] - lo[0] <= 2.0 * margin || hi[1] - lo[1] <= 2.0 * margin {
            continue;
        }
        for _ in 0..ATTEMPTS_PER_ROCK {
            // Centred on a cell centre, so the mesh reproduces the rock's height exactly.
            let col = ((rng.range(lo[0] + margin, hi[0] - margin) - hf.origin_m[0]) / res).round() as usize;
            let row = ((rng.range(lo[1] + margin, hi[1] - margin) - hf.origin_m[1]) / res).round() as usize;
            let centre = hf.cell_centre_m(col, row);
            let blocked = config.touches_clear_area(centre, radius_m)
                || ditches.iter().any(|d| distance_to_segment_m(centre, d) < 0.5 * d.width_m + radius_m + CLEARANCE_M)
                || rocks.iter().any(|r| {
                    (r.base_m.x - centre[0]).hypot(r.base_m.y - centre[1]) < r.radius_m + radius_m + CLEARANCE_M
                });
            if blocked {
                continue;
            }
            let ground_m = f64::from(hf.heights_m[row * hf.cols + col]);
            bake(hf, material, centre, &shape);
            rocks.push(Rock {
                id: rocks.len() as u32,
                base_m: Point3::new(centre[0], centre[1], ground_m),
                radius_m,
                height_m,
            });
            break;
        }
    }
    rocks
}

fn bake(hf: &mut Heightfield, material: &mut [u8], centre: [f64; 2], shape: &Shape) {
    let reach = shape.radius_m();
    let res = hf.resolution_m;
    let (Some((c0, c1)), Some((r0, r1))) = (
        index_range(centre[0] - reach, centre[0] + reach, hf.origin_m[0], res, hf.cols),
        index_range(centre[1] - reach, centre[1] + reach, hf.origin_m[1], res, hf.rows),
    ) else {
        return;
    };
    for row in r0..=r1 {
        for col in c0..=c1 {
            let p = hf.cell_centre_m(col, row);
            if let Some(dh) = shape.height_at(p[0] - centre[0], p[1] - centre[1]) {
                let i = row * hf.cols + col;
                hf.heights_m[i] = (f64::from(hf.heights_m[i]) + dh) as f32;
                material[i] = Material::Rock as u8;
            }
        }
    }
}
