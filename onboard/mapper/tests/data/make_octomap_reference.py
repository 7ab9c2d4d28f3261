# Generates tests/data/octomap_reference.bt with the real OctoMap library (see README.md).
# Produces a small reference .bt with the real OctoMap library (octomap-python 1.10):
# a 0.1 m tree with a 1 m x 1 m occupied floor at z = 0 and a 1 m x 1 m x 0.5 m free box above it.
import numpy as np, octomap, sys
t = octomap.OcTree(0.1)
for i in range(10):
    for j in range(10):
        t.updateNode(np.array([0.05 + 0.1 * i, 0.05 + 0.1 * j, 0.05]), True)
        for k in range(1, 6):
            t.updateNode(np.array([0.05 + 0.1 * i, 0.05 + 0.1 * j, 0.05 + 0.1 * k]), False)
t.updateNode(np.array([-1.05, -2.05, 0.35]), True)
t.writeBinary(sys.argv[1].encode())
print("nodes", t.size(), "leaves", t.getNumLeafNodes())
