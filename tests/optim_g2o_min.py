"""A minimal g2o reader for the optimiser's own tests (the full reader is microlie.optim.g2o).

VERTEX_SE2 / EDGE_SE2 (information order x, y, theta) and VERTEX_SE3:QUAT / EDGE_SE3:QUAT
(information upper triangle in [t, R] order, which is our (rho, phi) tangent order).
"""

from __future__ import annotations

import numpy as np

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, FactorGraph, Information


def read(path):
    verts, edges = {}, []
    is3d = False
    for line in open(path):
        f = line.split()
        if not f:
            continue
        if f[0] == "VERTEX_SE2":
            x, y, th = map(float, f[2:5])
            verts[int(f[1])] = [x, y, np.cos(th), np.sin(th)]
        elif f[0] == "VERTEX_SE3:QUAT":
            is3d = True
            verts[int(f[1])] = list(map(float, f[2:9]))
        elif f[0] == "EDGE_SE2":
            v = list(map(float, f[3:12]))
            I = np.zeros((3, 3))
            I[np.triu_indices(3)] = v[3:]
            edges.append((int(f[1]), int(f[2]), v[:3], I + np.triu(I, 1).T))
        elif f[0] == "EDGE_SE3:QUAT":
            is3d = True
            v = list(map(float, f[3:31]))
            I = np.zeros((6, 6))
            I[np.triu_indices(6)] = v[7:]
            edges.append((int(f[1]), int(f[2]), v[:7], I + np.triu(I, 1).T))
    return is3d, verts, edges


def odometry(is3d, n, edges):
    G = SE3 if is3d else SE2
    Z = {(i, j): z for i, j, z, _ in edges}
    p = [G.identity().params]
    for k in range(1, n):
        z = Z[(k - 1, k)]
        zp = z if is3d else [z[0], z[1], np.cos(z[2]), np.sin(z[2])]
        p.append((G(np.asarray(p[-1])) @ G(np.asarray(zp, float), normalize=True)).params)
    return G(np.array(p))


def build(path, init="file"):
    """A graph with pose 0 fixed (the gauge; it adds nothing to the cost)."""
    is3d, verts, edges = read(path)
    G = SE3 if is3d else SE2
    n = max(max(i, j) for i, j, _, _ in edges) + 1
    if init == "file":
        X = G(np.array([verts[k] for k in range(n)]), normalize=True)
    else:
        X = odometry(is3d, n, edges)
    g = FactorGraph()
    poses = g.add_variables(X, fixed=[0], name="poses")
    i = np.array([e[0] for e in edges])
    j = np.array([e[1] for e in edges])
    z = np.array([e[2] for e in edges])
    if is3d:
        Z = SE3(z, normalize=True)
    else:
        Z = SE2.exp(np.c_[np.zeros((len(z), 2)), z[:, 2]]) if False else \
            SE2(np.c_[z[:, :2], np.cos(z[:, 2]), np.sin(z[:, 2])])
    g.add(BetweenFactor(poses, i, j, Z, Information(np.array([e[3] for e in edges]))))
    return g, poses
