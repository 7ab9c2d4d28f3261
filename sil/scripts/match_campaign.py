#!/usr/bin/env python3
"""Aggregates a submap-matching campaign (sil/scripts/match_campaign.sh) into Markdown.

    python3 sil/scripts/match_campaign.py OUT

Reads OUT/*/report.json. Per world: the robots' live matchers (attempts, accepted, false
positives) and the pair evaluation (every truly overlapping pair matched in 4D and 6D with the
same prior): accepted, false positives, translation and yaw error of the accepted matches
against the truth, and the mean NEES of their covariances (6 DoF, consistent covariances give 6;
the thesis's 4D-vs-6D count comparison is on the same pairs).
"""
import json
import statistics
import sys
from pathlib import Path


def quantile(values, q):
    if not values:
        return float("nan")
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def mode_row(label, runs, key):
    attempts = accepted = fp = 0
    rejected = {}
    matches = []
    times = []
    for r in runs:
        m = r["pair_evaluation"][key]
        attempts += m["attempts"]
        accepted += m["accepted"]
        fp += m["false_positives"]
        matches += m["matches"]
        if m["attempts"]:
            times.append(m["mean_attempt_s"])
        for k, v in m["rejected"].items():
            rejected[k] = rejected.get(k, 0) + v
    good = [m for m in matches if not m["false_positive"]]
    t = [m["translation_error_m"] for m in good]
    yaw = [m["yaw_error_deg"] for m in good]
    nees = [m["nees"] for m in good]
    why = ", ".join(f"{k} {v}" for k, v in sorted(rejected.items(), key=lambda kv: -kv[1])) or "none"
    if good:
        errors = (
            f"{statistics.median(t):.3f} / {quantile(t, 0.9):.3f} m | "
            f"{statistics.median(yaw):.2f} / {quantile(yaw, 0.9):.2f}° | "
            f"{statistics.mean(nees):.1f} (median {statistics.median(nees):.1f})"
        )
    else:
        errors = "– | – | –"
    mean_s = statistics.mean(times) if times else float("nan")
    return f"| {label} | {key} | {attempts} | {accepted} | {fp} | {errors} | {mean_s:.2f} s | {why} |"


def main():
    out = Path(sys.argv[1])
    reports = {}
    for path in sorted(out.glob("*/report.json")):
        report = json.loads(path.read_text())
        reports.setdefault(report["scenario"], []).append(report)
    print("| world | mode | pairs matched | accepted | false positives | translation error median / p90 "
          "| yaw error median / p90 | NEES mean (6 DoF) | time per pair | rejections |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for world, runs in sorted(reports.items()):
        runs = [r for r in runs if r.get("pair_evaluation")]
        seeds = sorted(r["seed"] for r in runs)
        label = f"{world} ({len(runs)} seeds: {', '.join(map(str, seeds))})"
        for key in ("4d", "6d"):
            print(mode_row(label, runs, key))
    print()
    print("| world | seed | overlapping pairs | sharing ≥ 10 keypoints | submaps (suitable / checked) | live attempts | live accepted "
          "| live false positives | team mean error |")
    print("|---|---|---|---|---|---|---|---|---|")
    for world, runs in sorted(reports.items()):
        for r in sorted(runs, key=lambda r: r["seed"]):
            live = [x["matching"] for x in r["robots"] if x.get("matching")]
            checked = sum(m["submaps_checked"] for m in live)
            unsuitable = sum(m["submaps_unsuitable"] for m in live)
            evaluation = r.get("pair_evaluation") or {}
            print(
                f"| {world} | {r['seed']} | {evaluation.get('overlapping_pairs', '–')} "
                f"| {evaluation.get('sharing_pairs', '–')} "
                f"| {checked - unsuitable} / {checked} | {sum(m['attempts'] for m in live)} "
                f"| {sum(m['accepted'] for m in live)} | {sum(m['false_positives'] for m in live)} "
                f"| {r['mean_error_m']:.3f} m |"
            )


if __name__ == "__main__":
    main()
