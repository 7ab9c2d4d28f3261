#!/usr/bin/env python3
"""Tabulates sil/scripts/team_vs_solo.sh: per world, seed and robot the online mean error of the
team run, of the same robot alone, and with ground-truth closures; whether the team's frames
were connected; and how often the team beat the robot alone.

    python3 sil/scripts/team_vs_solo.py OUT
"""
import json
import sys
from pathlib import Path


def load(path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def main():
    out = Path(sys.argv[1])
    runs = {}
    for path in sorted(out.glob("*-s*-*/report.json")):
        world, seed, variant = path.parent.name.rsplit("-", 2)
        runs.setdefault((world, int(seed[1:])), {})[variant] = load(path)
    print("| world | seed | robot | distance | team: mean error | connected | detections in graph "
          "| alone: mean error | truth closures: mean error | team better than alone |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    better = total = 0
    sums = {"team": 0.0, "solo": 0.0, "truth": 0.0}
    for (world, seed), variants in sorted(runs.items()):
        if not all(variants.get(v) for v in ("team", "solo", "truth")):
            continue
        for i, robot in enumerate(variants["team"]["robots"]):
            error = {v: variants[v]["robots"][i]["mean_error_m"] for v in ("team", "solo", "truth")}
            if None in error.values():
                continue
            connected = len(robot.get("connected", [])) == len(variants["team"]["robots"])
            total += 1
            better += error["team"] < error["solo"]
            for v in sums:
                sums[v] += error[v]
            print(
                f"| {world} | {seed} | {robot['robot']} | {robot['distance_m']:.1f} m | {error['team']:.3f} m "
                f"| {'yes' if connected else 'no'} | {robot.get('marker_detections', '–')} "
                f"| {error['solo']:.3f} m | {error['truth']:.3f} m | {'yes' if error['team'] < error['solo'] else 'no'} |"
            )
    if total:
        print()
        print(
            f"team better than alone for {better} of {total} robots; mean over robots: team "
            f"{sums['team'] / total:.3f} m, alone {sums['solo'] / total:.3f} m, truth closures "
            f"{sums['truth'] / total:.3f} m"
        )


if __name__ == "__main__":
    main()
