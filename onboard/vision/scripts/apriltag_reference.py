#!/usr/bin/env python3
"""The upstream C AprilTag 3.4.5 detector (wheel `apriltag-python`) on images, printing the same
JSON lines as `vision`'s `apriltag --json` CLI: the reference for `vision::apriltag`.

    apriltag_reference.py [--decimate N] [--max-hamming N] [--min-margin M] [--runs R]
                          [--no-refine-edges] IMAGE...

One line per image: {"image", "width", "height", "time_ms", "time_ms_mean", "cpu_ms", "runs",
"detections": [{"id", "hamming", "decision_margin", "center", "corners"}]}.

- Pixels: colour images become grey with Pillow's "L" conversion, ITU-R 601 luma
  (19595 R + 38470 G + 7471 B + 32768) >> 16, the same integer formula as the Rust CLI. JPEGs are
  decoded by Pillow's libjpeg, which can differ from the Rust CLI's decoder by a grey level on some
  pixels; the comparison tests therefore feed this script PNGs of the grey pixels the Rust side
  decoded.
- Coordinates: the C library puts pixel centres at +0.5 (pixel i covers [i, i + 1]); `vision`
  puts them at integers (OpenCV's convention). Centre and corners are printed in `vision`'s
  convention, i.e. 0.5 is subtracted (measured on a rendered tag with known corners, see the
  vision README).
- Corner order: the library's `lb-rb-rt-lt` (counter-clockwise as seen in the image, starting at
  the tag's bottom-left), unchanged.
- Detector: family tag36h11, one thread, blur 0, decode sharpening 0.25 (the library's default),
  refine_edges on unless --no-refine-edges. The library reports every decoded tag (no margin
  threshold); --min-margin drops those below M afterwards, as the Rust detector's
  `min_decision_margin` does.
- Timing: only `detect()` on the grey array, once to warm up, then R times (default 5); time_ms is
  the best run's wall-clock time, time_ms_mean the mean, cpu_ms the best run's thread CPU time
  (immune to other load on the machine).
"""

import argparse
import json
import sys
import time

import numpy as np
from PIL import Image

import apriltag


def grey_pixels(path):
    image = Image.open(path)
    image.load()
    if image.mode != "L":
        image = image.convert("L")
    return np.ascontiguousarray(np.asarray(image, dtype=np.uint8))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("images", nargs="+")
    parser.add_argument("--decimate", type=float, default=1.0)
    parser.add_argument("--max-hamming", type=int, default=2)
    parser.add_argument("--min-margin", type=float, default=0.0)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--no-refine-edges", action="store_true")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")

    detector = apriltag.apriltag(
        "tag36h11",
        threads=1,
        maxhamming=args.max_hamming,
        decimate=args.decimate,
        blur=0.0,
        refine_edges=not args.no_refine_edges,
    )
    for path in args.images:
        grey = grey_pixels(path)
        detections = detector.detect(grey)  # warm-up (and the result)
        times, cpu_times = [], []
        for _ in range(args.runs):
            start, cpu_start = time.perf_counter(), time.thread_time()
            detections = detector.detect(grey)
            times.append((time.perf_counter() - start) * 1e3)
            cpu_times.append((time.thread_time() - cpu_start) * 1e3)
        out = []
        for d in detections:
            if d["margin"] < args.min_margin:
                continue
            corners = np.asarray(d["lb-rb-rt-lt"], dtype=float) - 0.5
            centre = np.asarray(d["center"], dtype=float) - 0.5
            out.append(
                {
                    "id": int(d["id"]),
                    "hamming": int(d["hamming"]),
                    "decision_margin": float(d["margin"]),
                    "center": [float(centre[0]), float(centre[1])],
                    "corners": [[float(x), float(y)] for x, y in corners],
                }
            )
        record = {
            "image": path,
            "width": int(grey.shape[1]),
            "height": int(grey.shape[0]),
            "time_ms": min(times),
            "time_ms_mean": sum(times) / len(times),
            "cpu_ms": min(cpu_times),
            "runs": args.runs,
            "detections": out,
        }
        print(json.dumps(record), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
