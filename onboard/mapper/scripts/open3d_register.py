#!/usr/bin/env python3
"""Open3D's global registration of two point clouds, the reference for `submap-match`.

The standard Open3D pipeline (its "global registration" tutorial's method, point-to-point ICP
refinement): voxel down-sampling, PCA normals, FPFH features, RANSAC on mutual feature matches
(`registration_ransac_based_on_feature_matching` with the edge-length and distance checkers),
then point-to-point ICP on the down-sampled clouds. Every length is a multiple of `--voxel-m`,
the clouds' resolution, so one call fits a 15 cm bunny and a 100 m lidar sweep alike:

    normals radius 2 v (30 neighbours at most), FPFH radius 5 v (100 at most),
    RANSAC inlier distance 1.5 v, ICP pair distance 1.5 v.

Prints one JSON object: success, transform (4x4 row-major, maps source into target coordinates),
fitness and inlier RMSE of RANSAC and ICP, time_ms (down-sampling to ICP, not file reading),
stages_ms, points after down-sampling, threads.

Usage: open3d_register.py SOURCE TARGET --voxel-m V [--seed S] [--max-iterations N]
(run by `cargo bench -p mapper --features cli --bench submap_match_real`).
"""

import argparse
import json
import os
import sys
import time

import numpy as np
import open3d as o3d


def prepare(cloud, voxel_m):
    """Down-sampled cloud with normals and its FPFH features."""
    down = cloud.voxel_down_sample(voxel_m)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * voxel_m, max_nn=30))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel_m, max_nn=100)
    )
    return down, fpfh


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("target")
    parser.add_argument("--voxel-m", type=float, required=True, help="the clouds' resolution (down-sampling voxel), m")
    parser.add_argument("--seed", type=int, default=2019)
    parser.add_argument("--max-iterations", type=int, default=100000, help="RANSAC iterations at most")
    args = parser.parse_args()
    if not args.voxel_m > 0.0:
        sys.exit("--voxel-m must be positive")

    source = o3d.io.read_point_cloud(args.source)
    target = o3d.io.read_point_cloud(args.target)
    for path, cloud in ((args.source, source), (args.target, target)):
        if not cloud.has_points():
            sys.exit(f"{path}: Open3D read no points")
    o3d.utility.random.seed(args.seed)
    reg = o3d.pipelines.registration
    v = args.voxel_m

    start = time.perf_counter()
    source_down, source_fpfh = prepare(source, v)
    target_down, target_fpfh = prepare(target, v)
    features_done = time.perf_counter()
    ransac = reg.registration_ransac_based_on_feature_matching(
        source_down,
        target_down,
        source_fpfh,
        target_fpfh,
        True,  # mutual filter
        1.5 * v,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
        reg.RANSACConvergenceCriteria(args.max_iterations, 0.999),
    )
    ransac_done = time.perf_counter()
    icp = reg.registration_icp(
        source_down,
        target_down,
        1.5 * v,
        ransac.transformation,
        reg.TransformationEstimationPointToPoint(False),
        reg.ICPConvergenceCriteria(max_iteration=50),
    )
    end = time.perf_counter()

    # RANSAC always returns a matrix; it found something when it has inlier correspondences.
    success = len(ransac.correspondence_set) >= 3 and icp.fitness > 0.0
    print(
        json.dumps(
            {
                "success": bool(success),
                "transform": np.asarray(icp.transformation).tolist(),
                "ransac_fitness": ransac.fitness,
                "ransac_inlier_rmse_m": ransac.inlier_rmse,
                "fitness": icp.fitness,
                "inlier_rmse_m": icp.inlier_rmse,
                "points": {"source": len(source_down.points), "target": len(target_down.points)},
                "time_ms": (end - start) * 1e3,
                "stages_ms": {
                    "features": (features_done - start) * 1e3,
                    "ransac": (ransac_done - features_done) * 1e3,
                    "icp": (end - ransac_done) * 1e3,
                },
                "threads": os.environ.get("OMP_NUM_THREADS", "all"),
                "open3d": o3d.__version__,
            }
        )
    )


if __name__ == "__main__":
    main()
