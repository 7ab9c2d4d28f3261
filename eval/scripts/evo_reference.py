"""evo's numbers for eval/tests/vs_evo.rs, computed with evo's own API in one process.

Usage: evo_reference.py GT_FORMAT GT_FILE EST_FILE
GT_FORMAT is `euroc` (state_groundtruth_estimate0 CSV) or `tum`; the estimate is TUM.

Prints one JSON object: {case: {"pairs": n, "stats": {rmse, mean, median, std, min, max, sse}}}
for every case the Rust test compares. Each case starts from freshly loaded, freshly
synchronized trajectories, as separate evo_ape / evo_rpe runs would, because evo's
alignment mutates the estimate in place.
"""

import copy
import json
import sys

from evo.core import sync
from evo.core.metrics import PoseRelation, Unit
from evo.main_ape import ape
from evo.main_rpe import rpe
from evo.tools import file_interface


def load(gt_format, gt_path, est_path):
    if gt_format == "euroc":
        gt = file_interface.read_euroc_csv_trajectory(gt_path)
    elif gt_format == "tum":
        gt = file_interface.read_tum_trajectory_file(gt_path)
    else:
        raise SystemExit(f"unknown ground-truth format {gt_format}")
    est = file_interface.read_tum_trajectory_file(est_path)
    # The defaults of evo_ape / evo_rpe: nearest stamps, max_diff 0.01 s, no offset.
    return sync.associate_trajectories(gt, est, max_diff=0.01, offset_2=0.0)


def stats_of(result):
    return {
        "pairs": int(result.np_arrays["error_array"].size),
        "stats": {k: float(v) for k, v in result.stats.items()},
    }


def main():
    gt_format, gt_path, est_path = sys.argv[1:4]
    synced = load(gt_format, gt_path, est_path)
    out = {}

    def fresh():
        return copy.deepcopy(synced[0]), copy.deepcopy(synced[1])

    relations = {
        "trans": PoseRelation.translation_part,
        "angle_deg": PoseRelation.rotation_angle_deg,
        "angle_rad": PoseRelation.rotation_angle_rad,
        "full": PoseRelation.full_transformation,
        "rot_part": PoseRelation.rotation_part,
    }
    # (align, correct_scale): evo_ape's --align, --align --correct_scale, --correct_scale alone.
    alignments = {
        "none": (False, False),
        "se3": (True, False),
        "sim3": (True, True),
        "scale": (False, True),
    }
    # evo's rotation angles cost ~0.3 ms per pose (scipy plus an SO(3) check), so the other
    # relations run only where they can differ: angles do not depend on scale.
    ape_cases = [(a, r) for a in alignments for r in ("trans", "angle_deg")]
    ape_cases += [(a, r) for a in ("none", "se3") for r in ("angle_rad", "full", "rot_part")]
    for align_name, rel_name in ape_cases:
        align, correct_scale = alignments[align_name]
        gt, est = fresh()
        result = ape(gt, est, relations[rel_name], align=align, correct_scale=correct_scale)
        out[f"ape/{align_name}/{rel_name}"] = stats_of(result)

    deltas = {"1frames": (1, Unit.frames), "1m": (1.0, Unit.meters)}
    for align_name in ("none", "se3", "sim3"):
        align, correct_scale = alignments[align_name]
        for delta_name, (delta, unit) in deltas.items():
            for rel_name in ("trans", "angle_deg"):
                gt, est = fresh()
                result = rpe(
                    gt,
                    est,
                    relations[rel_name],
                    delta=delta,
                    delta_unit=unit,
                    align=align,
                    correct_scale=correct_scale,
                )
                out[f"rpe/{align_name}/{delta_name}/{rel_name}"] = stats_of(result)

    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
