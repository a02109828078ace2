"""What a fit determines: the Laplace covariance of θ (``laplace_cov``) and how much of it the
drape rather than the prior supplies (``identified``, ``best_combination``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import Float

from .errors import RefineError
from .problem import K_PRIOR_STD, Problem, prior_sqrt_information


def laplace_cov(prob: Problem, theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Gauss–Newton (Laplace) covariance ``(JᵀJ)⁻¹`` of θ at θ with rest state ``x``, prior rows
    included: the covariance ``run_lm`` reports at its end point, for a model reached otherwise
    (a fresh drop kept by a scan)."""
    _, j = prob.evaluate(np.asarray(theta, float), np.asarray(x), jacobian=True)
    return np.linalg.inv(j.T @ j)


def best_combination(info: Float[np.ndarray, "k k"]) -> tuple[np.ndarray, float | None]:
    """Best-determined linear combination of the parameters under the information matrix ``info``.

    Returns the leading eigenvector, scaled so that its weights sum to 1 in absolute value with
    the largest positive, and the std of that combination (None when ``info`` carries nothing).
    """
    w, v = np.linalg.eigh(0.5 * (info + info.T))
    best = v[:, -1] / np.sum(np.abs(v[:, -1]))
    best = best if best[np.argmax(np.abs(best))] > 0 else -best
    return best, (float(np.linalg.norm(best) / np.sqrt(w[-1])) if w[-1] > 0 else None)


def identified(cov: Float[np.ndarray, "3 3"], prior_std: Sequence[float] = K_PRIOR_STD) -> dict:
    """What the data, rather than the prior, determine of log k1 (warp, weft, bias) in a fit.

    A fit's precision ``cov⁻¹`` is the data's information plus the prior's
    (``prior_sqrt_information``), so their difference is what the drape told. One capture
    typically pins one combination of the three k1 to a few per cent and leaves another free
    (``experiments/k1_information.py``), so per direction this reports the share of the
    posterior precision that the data supply: near 0 the value restates the prior (the
    network's direction ratios), near 1 the drape set it.

    Returns:
        ``{"weights": (3,), "std_log": float | None, "data_share": (3,)}``: the best-determined
        combination of log k1 (``best_combination`` of the data information) with its data-only
        std, and the data's share per direction.
    """
    cov = np.asarray(cov, float)
    if cov.shape != (3, 3):
        raise RefineError(f"identified: expected the 3x3 covariance of log k1, got shape {cov.shape}")
    lp = prior_sqrt_information(np.asarray(prior_std, float), 3)
    prec = np.linalg.inv(cov)
    data = prec - lp.T @ lp
    best, std = best_combination(data)
    share = np.clip(np.diag(data) / np.diag(prec), 0.0, 1.0)
    return {"weights": best, "std_log": std, "data_share": share}
