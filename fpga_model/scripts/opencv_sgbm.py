#!/usr/bin/env python3
"""OpenCV StereoSGBM as the comparison for the FPGA SGM core model.

Runs inside the project venv (`.venv`, created by `scripts/test`; pins in the project-level
scripts/requirements.txt).

Modes:
  accuracy  For each --scene NAME LEFT RIGHT D, run StereoSGBM over the grid of documented
            settings below and write each disparity map as a Middlebury PFM (disparity / 16 in
            px, invalid -> inf) into --out, plus --out/index.json. Scoring is NOT done here: the
            Rust `fpga_model::eval` scores these PFMs exactly as it scores our core, so both
            matchers share one scoring implementation. The grid points run in parallel worker
            processes (--jobs, default all cores), each with cv2.setNumThreads(1).
  speed     Time StereoSGBM (one mode and block size) on one pair: median over --runs of
            compute() alone (no I/O), once with cv2.setNumThreads(1) and once with all
            threads; print one JSON object.

Input is the same PNG files our core reads, converted to gray with the same integer luma as
`fpga_model::io::read_gray_png`: (77 R + 150 G + 29 B + 128) >> 8, 16-bit -> high byte, alpha
ignored. So both matchers see identical pixels (index.json records pixel sums to check this).

The grid (OpenCV's StereoSGBM docs and samples/python/stereo_match.py; cn = 1 for gray):
  mode             MODE_SGBM (5 paths), MODE_HH (8 paths, full buffer), MODE_SGBM_3WAY
  blockSize        1, 3, 5, 7            with P1 = 8 cn bs^2, P2 = 32 cn bs^2
  uniquenessRatio  0, 5, 10, 15          (docs: "5-15 is usually good enough")
  speckle          off (window 0), window 100 with speckleRange 2 (docs: "1 or 2"), window 100
                   with speckleRange 32 (the python sample)
  disp12MaxDiff    1 (the sample), -1 (left-right check off)
  minDisparity 0, numDisparities = the scene's D, preFilterCap left at its default.
"""

import argparse
import itertools
import json
import multiprocessing
import os
import statistics
import sys
import time

import cv2
import numpy as np

MODES = {
    "SGBM": cv2.STEREO_SGBM_MODE_SGBM,
    "HH": cv2.STEREO_SGBM_MODE_HH,
    "SGBM_3WAY": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
}
BLOCK_SIZES = [1, 3, 5, 7]
UNIQUENESS = [0, 5, 10, 15]
SPECKLE = [(0, 0), (100, 2), (100, 32)]  # (speckleWindowSize, speckleRange)
DISP12_MAX_DIFF = [1, -1]


def read_gray(path):
    """The PNG as uint8 gray, with the integer luma of fpga_model::io::read_gray_png."""
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"error: cannot read image {path}")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise SystemExit(f"error: {path}: unsupported sample type {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] in (3, 4):
        # OpenCV decodes colour as BGR(A).
        b, g, r = (image[:, :, i].astype(np.uint32) for i in range(3))
        return ((77 * r + 150 * g + 29 * b + 128) >> 8).astype(np.uint8)
    raise SystemExit(f"error: {path}: unsupported shape {image.shape}")


def make_sgbm(disparities, mode, block_size, uniqueness=10, speckle_window=0, speckle_range=0, disp12=1):
    cn = 1
    return cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=disparities,
        blockSize=block_size,
        P1=8 * cn * block_size * block_size,
        P2=32 * cn * block_size * block_size,
        disp12MaxDiff=disp12,
        uniquenessRatio=uniqueness,
        speckleWindowSize=speckle_window,
        speckleRange=speckle_range,
        mode=MODES[mode],
    )


def to_px(raw):
    """OpenCV's fixed-point disparity (1/16 px, int16) -> px, invalid (< minDisparity 0) -> inf."""
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw < 0] = np.inf
    return disparity


def write_pfm(path, values):
    """Middlebury PFM: 'Pf', 'W H', scale -1 (little endian), rows bottom to top."""
    height, width = values.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{width} {height}\n-1\n".encode("ascii"))
        f.write(np.ascontiguousarray(np.flipud(values), dtype="<f4").tobytes())


_IMAGES = {}


def _init_worker():
    # One OpenCV thread per worker process: the grid is spread over processes instead, which
    # also parallelises the modes OpenCV runs single-threaded (MODE_SGBM, MODE_HH).
    cv2.setNumThreads(1)


def _run_setting(task):
    """Runs one grid point on one scene and writes its PFM; returns its index entry."""
    name, left_path, right_path, disparities, scene_dir, rel_dir, (mode, bs, uniq, (sw, sr), d12) = task
    key = (left_path, right_path)
    if key not in _IMAGES:
        _IMAGES[key] = (read_gray(left_path), read_gray(right_path))
    left, right = _IMAGES[key]
    settings = {"mode": mode, "blockSize": bs, "P1": 8 * bs * bs, "P2": 32 * bs * bs,
                "uniquenessRatio": uniq, "speckleWindowSize": sw, "speckleRange": sr,
                "disp12MaxDiff": d12, "numDisparities": disparities, "minDisparity": 0}
    sgbm = make_sgbm(disparities, mode, bs, uniq, sw, sr, d12)
    start = time.perf_counter()
    raw = sgbm.compute(left, right)
    elapsed_ms = (time.perf_counter() - start) * 1e3
    file = f"{mode}_bs{bs}_u{uniq}_sw{sw}_sr{sr}_d12{d12}.pfm"
    write_pfm(os.path.join(scene_dir, file), to_px(raw))
    return {"scene": name, "file": f"{rel_dir}/{file}", "settings": settings, "time_ms_1_thread": elapsed_ms}


def accuracy(args):
    os.makedirs(args.out, exist_ok=True)
    index = {"opencv": cv2.__version__, "numpy": np.__version__, "scenes": {}, "results": []}
    grid = list(itertools.product(MODES, BLOCK_SIZES, UNIQUENESS, SPECKLE, DISP12_MAX_DIFF))
    tasks = []
    for name, left_path, right_path, disparities in args.scene:
        disparities = int(disparities)
        if disparities <= 0 or disparities % 16 != 0:
            raise SystemExit(f"error: scene {name}: numDisparities {disparities} must be a positive multiple of 16")
        left, right = read_gray(left_path), read_gray(right_path)
        if left.shape != right.shape:
            raise SystemExit(f"error: scene {name}: left {left.shape} and right {right.shape} differ")
        index["scenes"][name] = {
            "width": left.shape[1], "height": left.shape[0], "disparities": disparities,
            "left_pixel_sum": int(left.sum(dtype=np.uint64)), "right_pixel_sum": int(right.sum(dtype=np.uint64)),
        }
        scene_dir = os.path.join(args.out, name)
        os.makedirs(scene_dir, exist_ok=True)
        tasks += [(name, left_path, right_path, disparities, scene_dir, name, point) for point in grid]
    jobs = args.jobs or os.cpu_count() or 1
    with multiprocessing.Pool(jobs, initializer=_init_worker) as pool:
        # Ordered results keep index.json deterministic; chunks of 4 amortise the IPC.
        index["results"] = pool.map(_run_setting, tasks, chunksize=4)
    index["jobs"] = jobs
    with open(os.path.join(args.out, "index.json"), "w") as f:
        json.dump(index, f, indent=1)
    print(json.dumps({"results": len(index["results"]), "index": os.path.join(args.out, "index.json")}))


def speed(args):
    left, right = read_gray(args.left), read_gray(args.right)
    if left.shape != right.shape:
        raise SystemExit(f"error: left {left.shape} and right {right.shape} differ")
    all_threads = cv2.getNumThreads()
    report = {"opencv": cv2.__version__, "mode": args.mode, "blockSize": args.block_size,
              "P1": 8 * args.block_size ** 2, "P2": 32 * args.block_size ** 2,
              "width": left.shape[1], "height": left.shape[0], "disparities": args.disparities,
              "runs": args.runs, "results": []}
    for threads in (1, all_threads):
        cv2.setNumThreads(threads)
        sgbm = make_sgbm(args.disparities, args.mode, args.block_size)
        sgbm.compute(left, right)  # warm-up: allocation and first-touch page faults
        times_ms = []
        for _ in range(args.runs):
            start = time.perf_counter()
            sgbm.compute(left, right)
            times_ms.append((time.perf_counter() - start) * 1e3)
        median_ms = statistics.median(times_ms)
        report["results"].append({"threads": threads, "median_ms": median_ms, "fps": 1e3 / median_ms,
                                  "min_ms": min(times_ms), "max_ms": max(times_ms)})
    cv2.setNumThreads(all_threads)
    print(json.dumps(report))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    acc = sub.add_parser("accuracy", help="run the settings grid on scenes, write PFMs and index.json")
    acc.add_argument("--out", required=True, help="output directory")
    acc.add_argument("--scene", nargs=4, action="append", required=True, metavar=("NAME", "LEFT", "RIGHT", "D"),
                     help="scene name, left and right PNG, number of disparities (repeatable)")
    acc.add_argument("--jobs", type=int, default=0, help="worker processes (default: all cores)")
    spd = sub.add_parser("speed", help="time one StereoSGBM setting with 1 and all threads")
    spd.add_argument("--left", required=True)
    spd.add_argument("--right", required=True)
    spd.add_argument("--disparities", type=int, default=128)
    spd.add_argument("--mode", choices=sorted(MODES), default="SGBM")
    spd.add_argument("--block-size", type=int, default=5)
    spd.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    if args.command == "accuracy":
        accuracy(args)
    else:
        if args.runs < 1:
            raise SystemExit("error: --runs must be >= 1")
        speed(args)


if __name__ == "__main__":
    sys.exit(main())
