"""Certified global optimisation of pose graphs (SE-Sync; Rosen, Carlone, Bandeira, Leonard,
IJRR 2019; Shonan averaging, Dellaert et al., ECCV 2020).

The objective is SE-Sync's isotropic one (no 1/2),

    F = sum_e kappa_e ||R_j - R_i R~_ij||_F^2 + tau_e ||t_j - t_i - R_i t~_ij||^2,

with ``kappa`` and ``tau`` from each edge's information matrix
(:func:`~microlie.optim.certify.problem.isotropic_weights`). For an isotropic information
matrix ``diag(tau I, omega I)`` in 3-D (``kappa = omega / 2``) and small residuals ``F`` is
twice GTSAM's error (:meth:`~microlie.optim.io.pose_graph.PoseGraph.cost`), up to the chordal
versus geodesic rotation distance; with anisotropic information the two objectives differ.

- :func:`certified_pose_graph` solves ``F`` by the Riemannian staircase and returns the poses
  with the smallest eigenvalue of the certificate matrix ``S = Q - Lambda`` and its tolerance
  (``certified`` is ``lambda_min(S) >= -tolerance``: the poses are a global minimiser of ``F``).
- :func:`certify_poses` says whether given poses (a Levenberg-Marquardt answer) are at the
  global minimum of ``F``.
- ``microlie optimize FILE --init certified`` starts LM from the certified solution;
  ``--certify`` certifies LM's answer.
"""

from .problem import SESyncProblem, isotropic_weights
from .solver import CertifiedResult, certified_pose_graph, certify_poses, min_eigenvalue

__all__ = ["SESyncProblem", "isotropic_weights", "CertifiedResult", "certified_pose_graph",
           "certify_poses", "min_eigenvalue"]
