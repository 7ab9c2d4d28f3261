//! CPU time of the filter's steps (`cargo bench -p filter`): IMU propagation with 0 and 8 clones,
//! a relative-pose update, a wheel update, and the share of one core at 200 Hz IMU + 10 Hz VO +
//! 50 Hz wheel odometry.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use filter::{Filter, FilterConfig, RelativePoseMeasurement};
use hal::sensor::{ImuSample, WheelOdomSample};
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use std::hint::black_box;
use std::time::Instant;

const PERIOD_NS: u64 = 5_000_000;

fn sample(k: u64) -> ImuSample {
    let t = k as f64 * 0.005;
    ImuSample {
        stamp_ns: 1_000_000_000 + k * PERIOD_NS,
        gyro_radps: Vector3::new(0.01 * t.sin(), 0.02 * t.cos(), 0.05),
        accel_mps2: Vector3::new(0.1 * t.cos(), 0.05, 1.62),
    }
}

fn filter_with_clones(clones: usize) -> (Filter, u64) {
    let config = FilterConfig { max_keyframe_clones: 8, ..FilterConfig::default() };
    let mut f = Filter::new(config);
    f.initialize_at_rest(1_000_000_000, &Vector3::new(0.0, 0.0, 1.62), &Vector3::zeros()).unwrap();
    let mut k = 1;
    f.propagate(&sample(0)).unwrap();
    for i in 0..clones {
        f.propagate(&sample(k)).unwrap();
        f.clone_at(sample(k).stamp_ns).unwrap();
        if i + 1 < clones {
            f.mark_keyframe(sample(k).stamp_ns);
        }
        k += 1;
    }
    (f, k)
}

fn time_per_call(iterations: u64, mut body: impl FnMut(u64)) -> f64 {
    let start = Instant::now();
    for i in 0..iterations {
        body(i);
    }
    start.elapsed().as_secs_f64() / iterations as f64
}

fn main() {
    let n = 200_000;
    let mut results = Vec::new();
    for clones in [0, 8] {
        let (mut f, k0) = filter_with_clones(clones);
        let t = time_per_call(n, |i| f.propagate(black_box(&sample(k0 + i))).unwrap());
        println!("propagate, {clones} clones: {:.2} µs", t * 1e6);
        results.push(t);
    }
    let (base, k0) = filter_with_clones(8);
    let stamps: Vec<u64> = base.clone_stamps().map(|(s, _)| s).collect();
    let m = RelativePoseMeasurement {
        from_stamp_ns: stamps[0],
        to_stamp_ns: stamps[7],
        t_from_to: Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity()),
        covariance: Matrix6::identity() * 1e-4,
    };
    let mut f = base.clone();
    let updates = 20_000;
    let t_rel = time_per_call(updates, |_| {
        // Each call updates against the same two clones (the released `to` clone stays held until
        // the next `clone_at`), so the cost is that of one 8-clone update.
        black_box(f.update_relative_pose(black_box(&m)).unwrap());
    });
    println!("relative-pose update, 8 clones: {:.2} µs", t_rel * 1e6);
    let w = WheelOdomSample {
        stamp_ns: sample(k0).stamp_ns,
        linear_mps: Vector3::new(0.0, 0.0, 0.0),
        angular_radps: Vector3::zeros(),
        sigma: [0.02; 6],
    };
    let mut f = base.clone();
    let t_wheel = time_per_call(updates, |_| {
        black_box(f.update_wheel_odometry(black_box(&w)).unwrap());
    });
    println!("wheel update, 8 clones: {:.2} µs", t_wheel * 1e6);
    let mut f = base.clone();
    let mut k = k0;
    let t_clone = time_per_call(2_000, |_| {
        f.propagate(&sample(k)).unwrap();
        f.clone_at(sample(k).stamp_ns).unwrap();
        k += 1;
    });
    println!("propagate + clone_at (with pruning/eviction), 8+ clones: {:.2} µs", t_clone * 1e6);
    let per_second = 200.0 * results[1] + 10.0 * (t_rel + t_clone) + 50.0 * t_wheel;
    println!(
        "share of one core at 200 Hz IMU + 10 Hz VO + 50 Hz wheel (8 clones): {:.3} % ({:.0} µs per second)",
        100.0 * per_second,
        per_second * 1e6
    );
}
