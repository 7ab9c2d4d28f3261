#!/usr/bin/env python3
"""OpenCV's IPPE for square tags: the reference of vision's marker_pose::ippe
(tests/marker_pose.rs runs it in the project venv).

Usage: opencv_ippe_square.py IN.txt OUT.txt

IN.txt: one case per line, "fx fy cx cy size u0 v0 u1 v1 u2 v2 u3 v3", corners in the AprilTag
order (tag frame x right, y up: (-s/2,-s/2), (s/2,-s/2), (s/2,s/2), (-s/2,s/2)).
OUT.txt: first line "opencv VERSION", then per case "n" followed by n times
"rms rx ry rz tx ty tz" (OpenCV's order, best first; rvec/tvec of the tag frame in the camera
frame, full float precision), or "error MESSAGE".

SOLVEPNP_IPPE_SQUARE wants the object points in its own order, (-s/2, s/2), (s/2, s/2),
(s/2, -s/2), (-s/2, -s/2) in the same tag frame: the AprilTag corners 3, 2, 1, 0.
"""

import sys

import cv2
import numpy as np


def solve(values):
    fx, fy, cx, cy, s = values[:5]
    c = np.array(values[5:13], dtype=np.float64).reshape(4, 2)
    obj = np.array(
        [[-s / 2, s / 2, 0], [s / 2, s / 2, 0], [s / 2, -s / 2, 0], [-s / 2, -s / 2, 0]], dtype=np.float64
    )
    img = np.ascontiguousarray(c[[3, 2, 1, 0]])
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    fields = [str(n)]
    errs = np.asarray(errs).ravel()
    for i in range(n):
        fields.append(repr(float(errs[i])))
        fields += [repr(float(v)) for v in np.asarray(rvecs[i]).ravel()]
        fields += [repr(float(v)) for v in np.asarray(tvecs[i]).ravel()]
    return " ".join(fields)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    out = ["opencv " + cv2.__version__]
    with open(sys.argv[1]) as f:
        for line in f:
            if not line.strip():
                continue
            try:
                out.append(solve([float(v) for v in line.split()]))
            except cv2.error as e:
                out.append("error " + " ".join(str(e).split()))
    with open(sys.argv[2], "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
