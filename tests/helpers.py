"""Shared test fixtures that are plain values or functions: a parametric drape mesh, an estimate's
parameters with their stds, and a stand-in fit problem with no drape."""

import numpy as np

from drapejax.material import example_params, from_log_theta

R_DISK, R_SPEC = 0.09, 0.15

PARAMS = {"density": 0.192, "bend_k1_warp": 1.61e-05, "bend_k1_weft": 1.91e-05, "bend_k1_bias": 1.66e-05,
          "bend_k2_warp": -4.4e-08, "bend_k2_weft": -4.2e-08, "bend_k2_bias": -3.7e-08,
          "stretch_alpha_warp": 406.8, "stretch_alpha_weft": 249.4, "stretch_alpha_bias": 61.1,
          "stretch_beta_warp": 3.05, "stretch_beta_weft": 2.9, "stretch_beta_bias": 3.07}
"""A fabric's parameters as ``estimate`` reports them (SI)."""
STD = {k: (v * 0.1 if k.startswith("bend_k1") else None) for k, v in PARAMS.items()}
"""Their stds: 10 % on k1, none elsewhere."""


def drape_mesh(folds=5, n_ring=24, n_ang=240, knee=0.015, beta0=55.0, amp=25.0, tilt=8.0, disc_rings=8):
    """Parametric drape (no simulator): a flat disc of ``disc_rings`` rings and a skirt whose
    generators bend over a knee and run down at an angle below horizontal that varies with azimuth
    (``folds`` folds of ``amp`` degrees about ``beta0``, and a one-sided ``tilt``)."""
    phi = np.linspace(0.0, 2 * np.pi, n_ang, endpoint=False)
    beta = np.deg2rad(beta0 + amp * np.cos(folds * phi + 0.3) + tilt * np.cos(phi))
    rings = [np.stack([s * np.cos(phi), s * np.sin(phi), 0 * phi], 1)
             for s in np.linspace(R_DISK / disc_rings, R_DISK, disc_rings)]
    for u in np.linspace(0.0, R_SPEC - R_DISK, n_ring + 1)[1:]:
        arc = np.minimum(u, knee * beta)
        r = R_DISK + knee * np.sin(arc / knee) + (u - arc) * np.cos(beta)
        z = -(knee * (1 - np.cos(arc / knee)) + (u - arc) * np.sin(beta))
        rings.append(np.stack([r * np.cos(phi), r * np.sin(phi), z], 1))
    verts = np.concatenate([np.zeros((1, 3))] + rings)
    j = np.arange(n_ang)
    faces = [np.stack([np.zeros_like(j), 1 + j, 1 + (j + 1) % n_ang], 1)]
    for i in range(len(rings) - 1):
        a, b = 1 + i * n_ang, 1 + (i + 1) * n_ang
        faces += [np.stack([a + j, b + j, b + (j + 1) % n_ang], 1),
                  np.stack([a + j, b + (j + 1) % n_ang, a + (j + 1) % n_ang], 1)]
    return verts, np.concatenate(faces)


class QuadraticProblem:
    """A stand-in fit problem for ``refine.run_lm``: no drape, residual θ − target, the fourth
    parameter bounded below at −1 (its best value, −3, lies beyond the bound)."""

    init = example_params("mid")
    max_step, prior_sqrt_info, x = np.ones(4), np.eye(4), None
    lower = np.array([-np.inf, -np.inf, -np.inf, -1.0])
    target = np.array([0.1, -0.2, 0.3, -3.0])

    def rest(self, theta, seed):
        return np.zeros((1, 3))

    def params(self, theta):
        return from_log_theta(self.init, theta[:3])

    def evaluate(self, theta, x, jacobian):
        return theta - self.target, (np.eye(4) if jacobian else None)
