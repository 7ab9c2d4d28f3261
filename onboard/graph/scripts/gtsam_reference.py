#!/usr/bin/env python3
"""GTSAM 4.3 reference for the `posegraph` optimizer (3D pose graphs in g2o format).

Runs inside the project venv (`.venv`, created by `scripts/test`; pins in the project-level
scripts/requirements.txt, gtsam==4.3.0). Every subcommand prints ONE JSON object on stdout
(floats as Python's repr, i.e. the shortest text that reads back to the same double); errors
go to stderr with a non-zero exit status.

Graph set-up, exactly as GTSAM's python/gtsam/examples/Pose3SLAMExample_g2o.py:
    graph, initial = gtsam.readG2o(path, True)
plus a PriorFactorPose3 on the first vertex (smallest key; key 0 in our datasets) at its initial
value, with noiseModel.Diagonal.Variances([1e-6]*3 + [1e-4]*3) (GTSAM's tangent order is
[rotation, translation], so: rotation variance 1e-6 rad^2, translation variance 1e-4 m^2). In
all our datasets vertex 0 is the identity, as the example's prior on Pose3() assumes.

Subcommands:
  batch      --in G.g2o [--out O.g2o] [--robust cauchy:C|huber:K]
             Levenberg-Marquardt; initial/final cost (graph.error), iterations, wall time of
             optimize() only. --robust wraps the loop closures (between factors with
             |i - j| != 1) in a Cauchy or Huber M-estimator.
  isam2      --in G.g2o [--relinearize-threshold 0.1] [--relinearize-skip 1]
             [--partial-relinearization-check]
             Feeds the graph to ISAM2 one pose at a time in key order; per-update times and
             the variables re-eliminated (summed over the updates). The last flag sets
             ISAM2Params.enablePartialRelinearizationCheck (GTSAM's default: off).
  marginals  --in G.g2o (--keys 0,5,... | --all) [--runs N] [--no-covariances]
             Batch LM result, then marginal covariances, converted to OUR tangent order
             [translation, rotation]. --all: every pose. marginals_ms: wall time of
             gtsam.Marginals(graph, result) plus marginalCovariance of every requested key
             (the LM excluded), repeated --runs times (default 1) on the same LM result;
             marginals_median_ms is their median. --no-covariances leaves the matrices and
             poses out of the JSON (for timing all keys of a large graph).
  error      --in G.g2o --values V.g2o
             graph.error at the poses of another g2o file (e.g. our optimizer's output).
  gt-rmse    --in sphere2500.g2o --gt sphere2500_groundtruth.g2o
             RMSE of translation (m) and rotation angle (rad) of the initial values and of
             the LM result against the ground truth composed along the chain of the legacy
             EDGE3 records 0->1->...->N-1, without alignment and after a rigid SE(3) alignment
             (Horn/Umeyama on the positions, no scale).

Example:
  .venv/bin/python onboard/graph/scripts/gtsam_reference.py batch \\
      --in data/posegraph/sphere2500.g2o
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np

import gtsam

PRIOR_VARIANCES = [1e-6] * 3 + [1e-4] * 3  # GTSAM order: rotation (rad^2), translation (m^2)

# ours = P @ Sigma_gtsam @ P.T: GTSAM's tangent order is [rot(3), trans(3)], ours is
# [trans(3), rot(3)]; P swaps the two 3-blocks (P is symmetric and its own inverse).
PERM = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])


class CliError(Exception):
    """A user-facing error: printed to stderr, exit status 2."""


# --------------------------------------------------------------------------------------------
# Set-up
# --------------------------------------------------------------------------------------------


def check_file(path, what):
    if not os.path.isfile(path):
        raise CliError(f"{what} file not found: {path}")
    if not os.access(path, os.R_OK):
        raise CliError(f"{what} file not readable: {path}")


def read_g2o(path, what="input"):
    """gtsam.readG2o(path, is3D=True), with clear errors."""
    check_file(path, what)
    try:
        graph, values = gtsam.readG2o(path, True)
    except Exception as exc:  # gtsam raises ValueError/RuntimeError on malformed input
        raise CliError(f"cannot read {what} g2o file {path}: {exc}") from exc
    return graph, values


def pose_keys(values):
    return sorted(int(k) for k in values.keys())


def load_problem(path):
    """(graph with prior, initial values, read graph without prior)."""
    read_graph, initial = read_g2o(path)
    if initial.size() == 0:
        raise CliError(f"no 3D vertices (VERTEX_SE3:QUAT) in {path}")
    graph = gtsam.NonlinearFactorGraph(read_graph)  # copy: the read graph stays prior-free
    first = pose_keys(initial)[0]
    prior_model = gtsam.noiseModel.Diagonal.Variances(np.array(PRIOR_VARIANCES))
    graph.add(gtsam.PriorFactorPose3(first, initial.atPose3(first), prior_model))
    return graph, initial, read_graph


def between_factors(graph):
    """(index, factor) of every BetweenFactorPose3 in the graph."""
    out = []
    for idx in range(graph.size()):
        factor = graph.at(idx)
        if isinstance(factor, gtsam.BetweenFactorPose3):
            out.append((idx, factor))
    return out


def parse_robust(spec):
    """'cauchy:C' or 'huber:K' -> mEstimator."""
    try:
        name, value = spec.split(":", 1)
        k = float(value)
    except ValueError:
        raise CliError(f"--robust must be cauchy:C or huber:K, got {spec!r}") from None
    if not (k > 0 and math.isfinite(k)):
        raise CliError(f"--robust parameter must be a positive number, got {value!r}")
    name = name.lower()
    if name == "cauchy":
        return gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    if name == "huber":
        return gtsam.noiseModel.mEstimator.Huber.Create(k)
    raise CliError(f"--robust kernel must be cauchy or huber, got {name!r}")


def robustify_loop_closures(graph, estimator):
    """Copy of graph where every BetweenFactorPose3 with |i - j| != 1 has its noise model
    wrapped in noiseModel.Robust(estimator, base model). Returns (graph, count)."""
    out = gtsam.NonlinearFactorGraph()
    wrapped = 0
    for idx in range(graph.size()):
        factor = graph.at(idx)
        if isinstance(factor, gtsam.BetweenFactorPose3):
            i, j = (int(k) for k in factor.keys())
            if abs(i - j) != 1:
                model = gtsam.noiseModel.Robust.Create(estimator, factor.noiseModel())
                factor = gtsam.BetweenFactorPose3(i, j, factor.measured(), model)
                wrapped += 1
        out.add(factor)
    return out, wrapped


def lm_params():
    # Default gtsam.LevenbergMarquardtParams() of gtsam 4.3.0, except maxIterations (set to 100
    # explicitly; it is also the default): relativeErrorTol 1e-5, absoluteErrorTol 1e-5,
    # errorTol 0, linear solver MULTIFRONTAL_CHOLESKY, ordering COLAMD, lambdaInitial 1e-5,
    # lambdaFactor 10, lambdaUpperBound 1e5, lambdaLowerBound 0, useFixedLambdaFactor true,
    # diagonalDamping false (damping lambda * I, clamped to [minDiagonal 1e-6, maxDiagonal
    # 1e32]), minModelFidelity 1e-3, verbosity SILENT.
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    return params


def run_lm(graph, initial):
    """(result, iterations, optimize() wall time in ms)."""
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params())
    t0 = time.perf_counter()
    result = optimizer.optimize()
    elapsed_ms = (time.perf_counter() - t0) * 1e3
    return result, int(optimizer.iterations()), elapsed_ms


def pose_list(pose):
    """x y z qw qx qy qz."""
    t = pose.translation()
    q = pose.rotation().toQuaternion()
    return [float(t[0]), float(t[1]), float(t[2]), q.w(), q.x(), q.y(), q.z()]


# --------------------------------------------------------------------------------------------
# Subcommands
# --------------------------------------------------------------------------------------------


def cmd_batch(args):
    graph, initial, read_graph = load_problem(args.input)
    out = {"dataset": os.path.basename(args.input)}
    if args.robust:
        estimator = parse_robust(args.robust)
        graph, wrapped = robustify_loop_closures(graph, estimator)
        out["robust"] = args.robust
        out["robust_factors"] = wrapped
    initial_cost = graph.error(initial)
    result, iterations, elapsed_ms = run_lm(graph, initial)
    out.update(
        {
            "initial_cost": initial_cost,
            "final_cost": graph.error(result),
            "iterations": iterations,
            "time_ms": elapsed_ms,
            "vertices": int(initial.size()),
            "factors": int(graph.size()),
        }
    )
    if args.out:
        # As in Pose3SLAMExample_g2o.py: the read graph (no prior, no robust wrapper) with the
        # optimized values.
        gtsam.writeG2o(read_graph, result, args.out)
        out["out"] = args.out
    return out


def cmd_isam2(args):
    graph, initial, read_graph = load_problem(args.input)
    keys = pose_keys(initial)
    prior = graph.at(graph.size() - 1)  # load_problem appends the prior last

    # Between factors grouped by their larger key: fed with that pose. Odometry: (k-1 -> k).
    by_max_key = {k: [] for k in keys}
    odometry = {}
    for _, factor in between_factors(read_graph):
        i, j = (int(k) for k in factor.keys())
        if i not in by_max_key or j not in by_max_key:
            raise CliError(f"edge {i} {j} refers to a vertex missing from {args.input}")
        by_max_key[max(i, j)].append(factor)
        if j == i + 1:
            odometry.setdefault(j, factor.measured())

    params = gtsam.ISAM2Params()
    # Gauss-Newton (ISAM2GaussNewtonParams, wildfireThreshold 1e-3) and CHOLESKY are the
    # defaults; set explicitly. Other defaults: enableRelinearization true, cacheLinearizedFactors
    # true, evaluateNonlinearError false, findUnusedFactorSlots false.
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams())
    params.setFactorization("CHOLESKY")
    params.setRelinearizeThreshold(args.relinearize_threshold)
    params.relinearizeSkip = args.relinearize_skip
    params.enablePartialRelinearizationCheck = args.partial_relinearization_check
    isam2 = gtsam.ISAM2(params)

    update_ms = []
    reeliminated = 0
    for n, k in enumerate(keys):
        factors = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if n == 0:
            factors.add(prior)
            values.insert(k, initial.atPose3(k))
        else:
            prev = keys[n - 1]
            if k in odometry and prev == k - 1:
                guess = isam2.calculateEstimatePose3(prev).compose(odometry[k])
            else:
                guess = initial.atPose3(k)
            values.insert(k, guess)
        for factor in by_max_key[k]:
            factors.add(factor)
        t0 = time.perf_counter()
        result = isam2.update(factors, values)
        update_ms.append((time.perf_counter() - t0) * 1e3)
        reeliminated += result.getVariablesReeliminated()

    final_cost = graph.error(isam2.calculateEstimate())
    for _ in range(3):
        isam2.update()
    final_cost_extra = graph.error(isam2.calculateEstimate())

    ms = np.array(update_ms)
    return {
        "dataset": os.path.basename(args.input),
        "relinearize_threshold": args.relinearize_threshold,
        "relinearize_skip": args.relinearize_skip,
        "partial_relinearization_check": args.partial_relinearization_check,
        "vertices": len(keys),
        "factors": int(graph.size()),
        "updates": len(update_ms),
        # median/p95: numpy's default (linear interpolation between order statistics).
        "median_update_ms": float(np.median(ms)),
        "p95_update_ms": float(np.percentile(ms, 95)),
        "max_update_ms": float(ms.max()),
        "total_ms": float(ms.sum()),
        "final_cost": final_cost,
        "final_cost_after_extra_updates": final_cost_extra,
        # ISAM2Result.variablesReeliminated summed over the updates: the variables of the
        # re-eliminated top plus the new ones, as our UpdateStats counts them. (Its
        # variablesRelinearized is not reported: GTSAM 4.x sets it to the number of marked keys,
        # which includes every key of the new factors, so it does not count relinearizations.)
        "reeliminated_variables": reeliminated,
        "update_ms": [float(x) for x in update_ms],
    }


def cmd_marginals(args):
    graph, initial, _ = load_problem(args.input)
    if args.all:
        keys = pose_keys(initial)
    else:
        try:
            keys = [int(k) for k in args.keys.split(",") if k.strip() != ""]
        except ValueError:
            raise CliError(f"--keys must be a comma-separated list of integers, got {args.keys!r}")
        if not keys:
            raise CliError("--keys is empty")
    missing = [k for k in keys if not initial.exists(k)]
    if missing:
        raise CliError(f"keys not in {args.input}: {missing}")
    result, iterations, elapsed_ms = run_lm(graph, initial)
    marginals_ms = []
    for _ in range(args.runs):
        # Timed as a user of the marginals pays for them: linearize and factor at the result
        # (the constructor), then one query per key; the conversion to our order is left out.
        t0 = time.perf_counter()
        marginals = gtsam.Marginals(graph, result)
        sigmas = [marginals.marginalCovariance(k) for k in keys]
        marginals_ms.append((time.perf_counter() - t0) * 1e3)
    covariances = {}
    poses = {}
    if not args.no_covariances:
        for k, sigma in zip(keys, sigmas):
            covariances[str(k)] = (PERM @ np.asarray(sigma) @ PERM.T).tolist()
            poses[str(k)] = pose_list(result.atPose3(k))
    return {
        "dataset": os.path.basename(args.input),
        "keys": keys,
        "initial_cost": graph.error(initial),
        "final_cost": graph.error(result),
        "iterations": iterations,
        "time_ms": elapsed_ms,
        "covariance_order": "[tx, ty, tz, rx, ry, rz] (ours; GTSAM's is [rot, trans])",
        "pose_order": "x y z qw qx qy qz",
        "covariances": covariances,
        "poses": poses,
        "marginals_ms": marginals_ms,
        "marginals_median_ms": float(np.median(marginals_ms)),
    }


def cmd_error(args):
    graph, initial, read_graph = load_problem(args.input)
    _, values = read_g2o(args.values, "values")
    missing = [k for k in pose_keys(initial) if not values.exists(k)]
    if missing:
        shown = missing[:10] + (["..."] if len(missing) > 10 else [])
        raise CliError(f"{args.values} lacks {len(missing)} vertices of {args.input}: {shown}")
    return {
        "dataset": os.path.basename(args.input),
        "values": os.path.basename(args.values),
        "cost": graph.error(values),
        "cost_without_prior": read_graph.error(values),
        "vertices": int(initial.size()),
        "factors": int(graph.size()),
    }


def read_legacy_edge3(path):
    """[(i, j, Pose3)] of the `EDGE3 i j x y z roll pitch yaw I(21)` lines of a legacy file,
    rotation = Rot3.Ypr(yaw, pitch, roll) (as GTSAM's readG2o)."""
    check_file(path, "ground-truth")
    edges = []
    with open(path) as fh:
        for lineno, line in enumerate(fh, 1):
            tok = line.split()
            if not tok or tok[0] != "EDGE3":
                continue
            try:
                i, j = int(tok[1]), int(tok[2])
                x, y, z, roll, pitch, yaw = (float(v) for v in tok[3:9])
            except (ValueError, IndexError):
                raise CliError(f"{path}:{lineno}: malformed EDGE3 line") from None
            rot = gtsam.Rot3.Ypr(yaw, pitch, roll)
            edges.append((i, j, gtsam.Pose3(rot, np.array([x, y, z]))))
    if not edges:
        raise CliError(f"no EDGE3 lines in {path}")
    return edges


def chain_ground_truth(edges, keys):
    """Poses composed along the chain keys[0] (identity) -> keys[1] -> ..."""
    step = {}
    for i, j, pose in edges:
        if j == i + 1:
            step[j] = pose
        elif i == j + 1:
            step[i] = pose.inverse()
    gt = {keys[0]: gtsam.Pose3()}
    for prev, k in zip(keys, keys[1:]):
        if k != prev + 1 or k not in step:
            raise CliError(f"ground truth has no chain edge {prev} -> {k}")
        gt[k] = gt[prev].compose(step[k])
    return gt


def horn_alignment(src, dst):
    """Rigid (R, t) minimizing sum |R src_i + t - dst_i|^2 (Umeyama 1991, no scale)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - mu_d).T @ (src - mu_s) / len(src)
    u, _, vt = np.linalg.svd(cov)
    d = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2, 2] = -1.0
    r = u @ d @ vt
    return r, mu_d - r @ mu_s


def rmse_against(values, gt, keys):
    est_t = np.array([values.atPose3(k).translation() for k in keys])
    est_r = [values.atPose3(k).rotation().matrix() for k in keys]
    gt_t = np.array([gt[k].translation() for k in keys])
    gt_r = [gt[k].rotation().matrix() for k in keys]

    def rmse(r_align, t_align):
        terr = (est_t @ r_align.T + t_align) - gt_t
        angles = [
            np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(g.T @ r_align @ e)))
            for e, g in zip(est_r, gt_r)
        ]
        return (
            float(math.sqrt(np.mean(np.sum(terr**2, axis=1)))),
            float(math.sqrt(np.mean(np.square(angles)))),
        )

    raw_t, raw_r = rmse(np.eye(3), np.zeros(3))
    r_align, t_align = horn_alignment(est_t, gt_t)
    al_t, al_r = rmse(r_align, t_align)
    return {
        "translation_rmse_m": raw_t,
        "rotation_rmse_rad": raw_r,
        "aligned_translation_rmse_m": al_t,
        "aligned_rotation_rmse_rad": al_r,
        "alignment_rotation_angle_rad": float(
            np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(r_align)))
        ),
        "alignment_translation_m": float(np.linalg.norm(t_align)),
    }


def cmd_gt_rmse(args):
    graph, initial, _ = load_problem(args.input)
    keys = pose_keys(initial)
    edges = read_legacy_edge3(args.gt)
    gt = chain_ground_truth(edges, keys)

    # Consistency of the ground truth: every EDGE3 (chain or not) against the composed poses.
    worst_t = worst_r = 0.0
    for i, j, pose in edges:
        if i in gt and j in gt:
            d = pose.between(gt[i].between(gt[j]))
            worst_t = max(worst_t, float(np.linalg.norm(d.translation())))
            worst_r = max(worst_r, float(np.linalg.norm(gtsam.Rot3.Logmap(d.rotation()))))

    result, iterations, elapsed_ms = run_lm(graph, initial)
    return {
        "dataset": os.path.basename(args.input),
        "ground_truth": os.path.basename(args.gt),
        "vertices": len(keys),
        "gt_edges": len(edges),
        "gt_max_edge_inconsistency_m": worst_t,
        "gt_max_edge_inconsistency_rad": worst_r,
        "initial_cost": graph.error(initial),
        "final_cost": graph.error(result),
        "iterations": iterations,
        "time_ms": elapsed_ms,
        "initial": rmse_against(initial, gt, keys),
        "lm_result": rmse_against(result, gt, keys),
    }


# --------------------------------------------------------------------------------------------


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="GTSAM 4.3 reference runs on 3D g2o pose graphs (JSON on stdout)."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("batch", help="Levenberg-Marquardt on the whole graph")
    p.add_argument("--in", dest="input", required=True, metavar="G.g2o")
    p.add_argument("--out", metavar="O.g2o", help="write the optimized graph (gtsam.writeG2o)")
    p.add_argument("--robust", metavar="cauchy:C|huber:K", help="robust loop closures")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("isam2", help="incremental ISAM2, one pose per update")
    p.add_argument("--in", dest="input", required=True, metavar="G.g2o")
    p.add_argument("--relinearize-threshold", type=float, default=0.1)
    p.add_argument("--relinearize-skip", type=int, default=1)
    p.add_argument("--partial-relinearization-check", action="store_true")
    p.set_defaults(func=cmd_isam2)

    p = sub.add_parser("marginals", help="marginal covariances after batch LM")
    p.add_argument("--in", dest="input", required=True, metavar="G.g2o")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--keys", metavar="0,5,...")
    which.add_argument("--all", action="store_true", help="every pose")
    p.add_argument("--runs", type=int, default=1, help="timed repetitions of the marginals")
    p.add_argument("--no-covariances", action="store_true", help="timing only: no matrices")
    p.set_defaults(func=cmd_marginals)

    p = sub.add_parser("error", help="graph.error at the poses of another g2o file")
    p.add_argument("--in", dest="input", required=True, metavar="G.g2o")
    p.add_argument("--values", required=True, metavar="V.g2o")
    p.set_defaults(func=cmd_error)

    p = sub.add_parser("gt-rmse", help="RMSE against a legacy EDGE3 ground-truth chain")
    p.add_argument("--in", dest="input", required=True, metavar="G.g2o")
    p.add_argument("--gt", required=True, metavar="GT.g2o")
    p.set_defaults(func=cmd_gt_rmse)

    args = parser.parse_args(argv)
    if getattr(args, "relinearize_skip", 1) < 1:
        parser.error("--relinearize-skip must be >= 1")
    if getattr(args, "runs", 1) < 1:
        parser.error("--runs must be >= 1")
    try:
        out = args.func(args)
    except CliError as exc:
        print(f"gtsam_reference.py: error: {exc}", file=sys.stderr)
        return 2
    json.dump(out, sys.stdout, allow_nan=True)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
