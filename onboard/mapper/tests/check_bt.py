#!/usr/bin/env python3
"""Reads a .bt file with the real OctoMap library (the `octomap-python` binding) and compares
its voxels with an expected list.

Usage: check_bt.py MAP.bt EXPECTED.txt
EXPECTED.txt: one voxel per line, `kx ky kz occupied` with the mapper's voxel keys (voxel k spans
[k*res, (k+1)*res)) and occupied 0 or 1. Pruned leaves are expanded. Exit status 0 when the
voxel sets and states match exactly, 1 otherwise.

Install: python3 -m venv /tmp/venv && /tmp/venv/bin/pip install octomap-python
"""
import math
import sys

import octomap


def main():
    bt_path, expected_path = sys.argv[1], sys.argv[2]
    tree = octomap.OcTree(bt_path.encode())
    res = tree.getResolution()
    got = {}
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        n = int(round(size / res))
        c = leaf.getCoordinate()
        lo = [int(math.floor((c[a] - size / 2) / res + 0.5)) for a in range(3)]
        occupied = bool(tree.isNodeOccupied(leaf))
        for dz in range(n):
            for dy in range(n):
                for dx in range(n):
                    got[(lo[0] + dx, lo[1] + dy, lo[2] + dz)] = occupied
    expected = {}
    with open(expected_path) as f:
        for line in f:
            kx, ky, kz, occ = line.split()
            expected[(int(kx), int(ky), int(kz))] = occ == "1"
    occupied = sum(got.values())
    print(f"octomap read {bt_path}: res {res}, {tree.size()} nodes, {len(got)} voxels ({occupied} occupied)")
    if got != expected:
        missing = len(expected.keys() - got.keys())
        extra = len(got.keys() - expected.keys())
        wrong = sum(1 for k in expected.keys() & got.keys() if expected[k] != got[k])
        print(f"MISMATCH: {missing} missing, {extra} extra, {wrong} with the wrong state")
        return 1
    print("match")
    return 0


if __name__ == "__main__":
    sys.exit(main())
