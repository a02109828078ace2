"""Fabric material parameters: one pytree of float arrays in SI units.

The same flat JSON schema is used everywhere (``simulate --params``, ``estimate`` output,
``truth.json``). Every field may carry leading batch dimensions so the pytree can be
``vmap``-ed and differentiated.

Bending (seed 000, Feng et al. 2022): the moment per unit width in a direction is
$M(\\kappa) = k_1\\kappa + k_2\\kappa|\\kappa|$. ``k1`` values are the strip (cantilever)
rigidities measured along warp, weft and bias, as in the 618-fabric file. Stretching (seed 001):
tension per width $T(\\epsilon) = \\alpha\\,e^{\\beta\\epsilon}\\epsilon$ with
$\\epsilon = l/l_0 - 1$, i.e. the tangent stiffness law $k(l) = \\alpha e^{\\beta(l/l_0-1)}$.
"""

from __future__ import annotations

import json
import math
import os
import types
from collections.abc import Mapping
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

G = 9.81
"""Gravitational acceleration, m/s²."""

KAPPA_RANGE = 50.0
"""Curvature range (1/m, bend radius 2 cm) over which the measured k2 of real fabrics applies.

The moment law must be monotone on [0, KAPPA_RANGE]; beyond it the moment is continued
linearly with the slope it has there, so a softening k2 never makes bending energy concave.
98% of the 618 measured fabrics are monotone on this range."""

BENDING_KEYS = (
    "bend_k1_warp", "bend_k1_weft", "bend_k1_bias",
    "bend_k2_warp", "bend_k2_weft", "bend_k2_bias",
)
STRETCH_KEYS = (
    "stretch_alpha_warp", "stretch_alpha_weft", "stretch_alpha_bias",
    "stretch_beta_warp", "stretch_beta_weft", "stretch_beta_bias",
)
PARAM_KEYS = ("density",) + BENDING_KEYS + STRETCH_KEYS
DIRECTIONS = ("warp", "weft", "bias")
"""The three measured directions, in the order of every per-direction field."""
PER_DENSITY_SUFFIX = "_per_density"
"""Suffix of the density-normalised keys (k/ρ) of the per-density dict (``to_per_density``)."""
LOG_TARGET_NAMES = (tuple(f"log_k1_{d}_per_density" for d in DIRECTIONS)
                    + tuple(f"r_{d}" for d in DIRECTIONS))
"""Names of the six bending log targets (``to_log_targets``)."""
LOG_STRETCH_NAMES = (tuple(f"log_alpha_{d}_per_density" for d in DIRECTIONS)
                     + tuple(f"beta_{d}" for d in DIRECTIONS))
"""Names of the six stretching log inputs (``to_log_stretch``)."""

DEFAULTS = {
    "bend_k2_warp": 0.0,
    "bend_k2_weft": 0.0,
    "bend_k2_bias": 0.0,
    # A typical plain woven: tensile stiffness of order 1e2-1e3 N/m per width and shear
    # modulus of order 10-100 N/m (Kawabata KES-F surveys; units-and-ranges.md). Each of the
    # two bias directions carries ``stretch_alpha_bias`` (shear modulus = alpha_bias / 2).
    "stretch_alpha_warp": 600.0,
    "stretch_alpha_weft": 400.0,
    "stretch_alpha_bias": 80.0,
    "stretch_beta_warp": 0.0,
    "stretch_beta_weft": 0.0,
    "stretch_beta_bias": 0.0,
}

UNITS = {
    "density": "kg/m^2",
    **{k: "N*m" for k in BENDING_KEYS[:3]},
    **{k: "N*m^2" for k in BENDING_KEYS[3:]},
    **{k: "N/m" for k in STRETCH_KEYS[:3]},
    **{k: "1" for k in STRETCH_KEYS[3:]},
}

# Plausibility bounds that catch wrong units (e.g. CLO g*mm^2/s^2 or µN·m given as SI).
_BOUNDS = {
    "density": (0.0, 5.0),
    "bend_k1": (0.0, 1e-2),
    "bend_k2": (-1e-3, 1e-3),
    "stretch_alpha": (0.0, 1e6),
    "stretch_beta": (-50.0, 200.0),
}


class ParameterError(ValueError):
    """An impossible or wrongly-scaled material parameter; the message names it."""


class FabricParams(eqx.Module):
    """Material parameters of one fabric (or a batch: every field shares leading dims).

    Attributes:
        density: areal density, kg/m².
        bend_k1_warp, bend_k1_weft, bend_k1_bias: linear bending rigidity per width, N·m.
        bend_k2_warp, bend_k2_weft, bend_k2_bias: quadratic moment coefficient, N·m².
        stretch_alpha_*: tensile stiffness per width at zero strain, N/m.
        stretch_beta_*: exponential stiffening exponent (dimensionless).
    """

    density: Float[Array, "*b"]
    bend_k1_warp: Float[Array, "*b"]
    bend_k1_weft: Float[Array, "*b"]
    bend_k1_bias: Float[Array, "*b"]
    bend_k2_warp: Float[Array, "*b"]
    bend_k2_weft: Float[Array, "*b"]
    bend_k2_bias: Float[Array, "*b"]
    stretch_alpha_warp: Float[Array, "*b"]
    stretch_alpha_weft: Float[Array, "*b"]
    stretch_alpha_bias: Float[Array, "*b"]
    stretch_beta_warp: Float[Array, "*b"]
    stretch_beta_weft: Float[Array, "*b"]
    stretch_beta_bias: Float[Array, "*b"]

    @classmethod
    def make(cls, *, density, bend_k1_warp, bend_k1_weft, bend_k1_bias, dtype=None, **rest):
        """Build from keyword values (SI), filling documented defaults for omitted keys."""
        unknown = set(rest) - set(PARAM_KEYS)
        if unknown:
            raise ParameterError(f"unknown parameter(s): {sorted(unknown)}; known: {list(PARAM_KEYS)}")
        vals = dict(DEFAULTS)
        vals.update(rest)
        vals.update(density=density, bend_k1_warp=bend_k1_warp, bend_k1_weft=bend_k1_weft,
                    bend_k1_bias=bend_k1_bias)
        dtype = dtype or jnp.result_type(float)
        return cls(**{k: jnp.asarray(vals[k], dtype=dtype) for k in PARAM_KEYS})

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "parameters") -> "FabricParams":
        """Parse the flat JSON schema; unknown keys, missing keys and implausible values raise."""
        if not isinstance(d, dict):
            raise ParameterError(f"{source}: expected a JSON object of parameters, got {type(d).__name__}")
        unknown = sorted(set(d) - set(PARAM_KEYS))
        if unknown:
            raise ParameterError(f"{source}: unknown key(s) {unknown}; allowed: {list(PARAM_KEYS)}")
        missing = [k for k in ("density", "bend_k1_warp", "bend_k1_weft", "bend_k1_bias") if k not in d]
        if missing:
            raise ParameterError(f"{source}: missing required key(s) {missing}")
        vals = {}
        for k, v in d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ParameterError(f"{source}: '{k}' must be a number in {UNITS[k]}, got {v!r}")
            vals[k] = float(v)
        p = cls.make(**vals)
        check(p, source=source)
        return p

    def to_dict(self) -> dict:
        """Flat dict of Python floats (single fabric) in SI units."""
        return {k: float(np.asarray(getattr(self, k))) for k in PARAM_KEYS}

    def astype(self, dtype) -> "FabricParams":
        return FabricParams(**{k: jnp.asarray(getattr(self, k), dtype) for k in PARAM_KEYS})


def stack(params: list[FabricParams]) -> FabricParams:
    """Stack single-fabric parameters into a batch along a new leading axis."""
    return FabricParams(**{k: jnp.stack([getattr(p, k) for p in params]) for k in PARAM_KEYS})


def unstack(params: FabricParams) -> list[FabricParams]:
    n = params.density.shape[0]
    return [FabricParams(**{k: getattr(params, k)[i] for k in PARAM_KEYS}) for i in range(n)]


# --------------------------------------------------------------------------- parameter forms
#
# A fabric travels as: FabricParams (the pytree); the flat SI dict (``FabricParams.to_dict`` /
# ``from_dict``); the per-density dict (k/ρ, when the density is unknown); the (..., 13) matrix
# (datasets); the network's log targets and stretching inputs; and refine's log θ (k1 scales).


def to_matrix(params: FabricParams) -> Float[np.ndarray, "*b 13"]:
    """float64 array of ``params`` with the fields along the last axis in ``PARAM_KEYS`` order
    (the ``params`` column block of dataset shards)."""
    return np.stack([np.asarray(getattr(params, k), np.float64) for k in PARAM_KEYS], -1)


def from_matrix(m, dtype=None) -> FabricParams:
    """Inverse of ``to_matrix``: the last axis of ``m`` holds the 13 fields in ``PARAM_KEYS`` order;
    ``dtype`` defaults to JAX's float (float64 only in 64-bit mode), as ``FabricParams.make``."""
    m = np.asarray(m)
    if m.shape[-1:] != (len(PARAM_KEYS),):
        raise ParameterError(f"expected {len(PARAM_KEYS)} parameter columns (PARAM_KEYS), got shape {m.shape}")
    dtype = dtype or jnp.result_type(float)
    return FabricParams(**{k: jnp.asarray(m[..., i], dtype=dtype) for i, k in enumerate(PARAM_KEYS)})


def _rows(params) -> np.ndarray:
    return to_matrix(params) if isinstance(params, FabricParams) else np.asarray(params, float)


def to_per_density(p: FabricParams) -> dict:
    """Flat dict of one fabric without its density: every field but ``stretch_beta_*`` as k/ρ
    under ``<key>_per_density`` (SI per kg/m²), ``stretch_beta_*`` unchanged, in ``PARAM_KEYS`` order.

    This is what ``drapejax estimate`` reports when the capture gives no areal density: a drape
    determines the stiffnesses only relative to its weight. ``from_per_density`` undoes it."""
    pd = p.to_dict()
    inv = 1.0 / float(pd["density"])
    return {k if k.startswith("stretch_beta") else k + PER_DENSITY_SUFFIX:
            float(v) * (1.0 if k.startswith("stretch_beta") else inv)
            for k, v in pd.items() if k != "density"}


def from_per_density(d: Mapping, density: float, *, source: str = "parameters") -> dict:
    """The flat SI dict of a per-density dict ``d`` at areal density ``density`` (kg/m²).

    ``<key>_per_density`` values are multiplied by ``density`` and stored under ``<key>``; other
    keys pass unchanged (checking them is ``FabricParams.from_dict``'s job). A per-density
    value that is not a number raises ``ParameterError`` naming ``source`` and the key."""
    vals = {"density": density}
    for k, v in d.items():
        if k.endswith(PER_DENSITY_SUFFIX):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ParameterError(f"{source}: '{k}' must be a number, got {v!r}")
            vals[k[:-len(PER_DENSITY_SUFFIX)]] = float(v) * density
        else:
            vals[k] = v
    return vals


def to_log_targets(params) -> Float[np.ndarray, "*b 6"]:
    """The network's bending targets (``LOG_TARGET_NAMES``) of a ``FabricParams`` or of (..., 13)
    rows in ``PARAM_KEYS`` order: log(k1/ρ) per direction (k1/ρ in m³/s²), then the softening
    ratio r = k2·KAPPA_RANGE/k1 (the moment law is monotone for r > −1/2). Dividing by ρ lets the
    network work without the density, which a drape does not determine."""
    m = _rows(params)
    rho = m[..., 0]
    k1 = [m[..., PARAM_KEYS.index(f"bend_k1_{d}")] for d in DIRECTIONS]
    r = [m[..., PARAM_KEYS.index(f"bend_k2_{d}")] * KAPPA_RANGE / k for d, k in zip(DIRECTIONS, k1)]
    return np.stack([np.log(k / rho) for k in k1] + r, axis=-1)


def to_log_stretch(params, density: float | None = None) -> Float[np.ndarray, "*b 6"]:
    """The network's stretching inputs (``LOG_STRETCH_NAMES``): log(α/ρ) per direction (α/ρ in
    m²/s²), then β per direction.

    ``params`` is a ``FabricParams`` or (..., 13) rows in ``PARAM_KEYS`` order (ρ from the rows,
    ``density`` None), or a mapping holding ``STRETCH_KEYS`` of one fabric with its ``density``
    given apart (a (6,) array, computed in Python floats)."""
    if isinstance(params, Mapping):
        if density is None:
            raise ParameterError("to_log_stretch: a mapping of stretching parameters needs the density")
        return np.array([math.log(float(params[f"stretch_alpha_{d}"]) / density) for d in DIRECTIONS]
                        + [float(params[f"stretch_beta_{d}"]) for d in DIRECTIONS])
    if density is not None:
        raise ParameterError("to_log_stretch: the density is taken from the parameters; give it only with a mapping")
    m = _rows(params)
    rho = m[..., 0]
    return np.stack([np.log(m[..., PARAM_KEYS.index(f"stretch_alpha_{d}")] / rho) for d in DIRECTIONS]
                    + [m[..., PARAM_KEYS.index(f"stretch_beta_{d}")] for d in DIRECTIONS], axis=-1)


def from_log_stretch(s: Float[np.ndarray, "6"], density: float) -> dict:
    """The stretching fields (``STRETCH_KEYS``, SI, Python floats) of the network's stretching
    inputs ``s`` (``to_log_stretch``'s order) for a fabric of areal ``density`` (kg/m²): its inverse."""
    s = np.asarray(s, float)
    alpha, beta = density * np.exp(s[:3]), s[3:]
    return {**{f"stretch_alpha_{d}": float(alpha[i]) for i, d in enumerate(DIRECTIONS)},
            **{f"stretch_beta_{d}": float(beta[i]) for i, d in enumerate(DIRECTIONS)}}


def from_log_targets(y: Float[np.ndarray, "6"], s: Float[np.ndarray, "6"], density: float | None, *,
                     r_min: float | None = None, bias_fraction: float | None = None) -> dict:
    """One fabric's parameter dict of bending targets ``y`` (``to_log_targets``) and stretching
    inputs ``s`` (``to_log_stretch``).

    Args:
        y, s: (6,) arrays in ``LOG_TARGET_NAMES`` / ``LOG_STRETCH_NAMES`` order.
        density: areal density in kg/m²: the flat SI dict (``PARAM_KEYS`` order); None: the
            per-density dict (``to_per_density``'s keys and order).
        r_min: when given, r is clipped below at it (a monotone moment law needs r > −1/2).
        bias_fraction: when given, k1_bias is capped at this fraction of the largest value a
            positive-definite plate allows with the warp and weft k1 (``validity``).

    Both limits are invariant under the density scaling, so they apply to k/ρ. The values are
    Python floats and are not checked (``check``)."""
    y, s = np.asarray(y, float), np.asarray(s, float)
    k1 = np.exp(y[:3])
    if bias_fraction is not None:
        bound = 4.0 / (np.sqrt(1.0 / k1[0]) - np.sqrt(1.0 / k1[1])) ** 2 if k1[0] != k1[1] else np.inf
        k1[2] = min(k1[2], bias_fraction * bound)
    r = y[3:] if r_min is None else np.maximum(y[3:], r_min)
    k2 = r * k1 / KAPPA_RANGE
    if density is None:
        groups = (("bend_k1", PER_DENSITY_SUFFIX, k1), ("bend_k2", PER_DENSITY_SUFFIX, k2),
                  ("stretch_alpha", PER_DENSITY_SUFFIX, np.exp(s[:3])), ("stretch_beta", "", s[3:]))
        return {f"{name}_{d}{suffix}": float(v[i]) for name, suffix, v in groups for i, d in enumerate(DIRECTIONS)}
    vals = {"density": float(density), **from_log_stretch(s, density)}
    for name, v in (("bend_k1", density * k1), ("bend_k2", density * k2)):
        vals.update({f"{name}_{d}": float(v[i]) for i, d in enumerate(DIRECTIONS)})
    return {k: vals[k] for k in PARAM_KEYS}


def from_log_theta(init: FabricParams, theta: Float[Array, "*b 3"]) -> FabricParams:
    """The fabric at refine's θ: ``init`` with k1 and k2 per direction (``DIRECTIONS``) scaled by
    exp(θ), so the shape of each moment law (k2/k1) stays that of ``init``; jittable and
    differentiable in θ (the fit's parameter vector starts with these three log scales)."""
    s = jnp.exp(theta)
    kw = {f: getattr(init, f) for f in PARAM_KEYS}
    for i, d in enumerate(DIRECTIONS):
        kw[f"bend_k1_{d}"] = getattr(init, f"bend_k1_{d}") * s[..., i]
        kw[f"bend_k2_{d}"] = getattr(init, f"bend_k2_{d}") * s[..., i]
    return FabricParams(**kw)


def with_stretch_alpha(p: FabricParams, alpha) -> FabricParams:
    """``p`` with its tensile and shear stiffness α per direction (``DIRECTIONS``) set to ``alpha``
    (N/m; a (3,) array, jittable) and every other field, the exponential law's β included, kept."""
    kw = {f: getattr(p, f) for f in PARAM_KEYS}
    for i, d in enumerate(DIRECTIONS):
        kw[f"stretch_alpha_{d}"] = alpha[i]
    return FabricParams(**kw)


def scale_stretch(p: FabricParams, factor: float) -> FabricParams:
    """``p`` with its tensile and shear stiffness α along every direction times ``factor`` (the
    exponential law's β, the shape of its stiffening, kept): one overall membrane stiffness scale."""
    return with_stretch_alpha(p, [getattr(p, f"stretch_alpha_{d}") * factor for d in DIRECTIONS])


def to_log_theta(p: FabricParams, init: FabricParams) -> Float[Array, "*b 3"]:
    """Refine's θ of ``p`` relative to ``init``: log(k1/k1_init) per direction. ``from_log_theta``
    gives ``p`` back where ``p`` has ``init``'s other fields and k2/k1 ratios."""
    return jnp.stack([jnp.log(getattr(p, f"bend_k1_{d}") / getattr(init, f"bend_k1_{d}")) for d in DIRECTIONS], -1)


def _moment_monotone(k1, k2, xp=jnp):
    return k1 + 2.0 * xp.minimum(k2, 0.0) * KAPPA_RANGE > 0.0


def validity(p: FabricParams | types.SimpleNamespace, *, xp=jnp) -> Array | np.ndarray | np.bool_:
    """Per-member validity (bool array with the batch shape) without raising.

    Valid means: positive finite density and k1, alpha; a moment law monotone on
    [0, KAPPA_RANGE]; and bias rigidity compatible with a positive-definite plate
    (see ``plate_compliance``). ``xp=numpy`` evaluates it on the host (``check`` does, so that
    checking one parameter set compiles nothing).
    """
    ok = xp.ones(xp.shape(p.density), bool)
    for k in PARAM_KEYS:
        v = getattr(p, k)
        ok = ok & xp.isfinite(v)
    ok = ok & (p.density > 0) & (p.bend_k1_warp > 0) & (p.bend_k1_weft > 0) & (p.bend_k1_bias > 0)
    ok = ok & (p.stretch_alpha_warp > 0) & (p.stretch_alpha_weft > 0) & (p.stretch_alpha_bias > 0)
    for d in ("warp", "weft", "bias"):
        ok = ok & _moment_monotone(getattr(p, f"bend_k1_{d}"), getattr(p, f"bend_k2_{d}"), xp)
    s11, s22 = 1.0 / p.bend_k1_warp, 1.0 / p.bend_k1_weft
    ok = ok & (4.0 / p.bend_k1_bias > (xp.sqrt(s11) - xp.sqrt(s22)) ** 2)
    return ok


def check(p: FabricParams, *, source: str = "parameters") -> None:
    """Raise ParameterError naming the first impossible or wrongly-scaled parameter."""
    for k in PARAM_KEYS:
        v = np.asarray(getattr(p, k), dtype=float)
        if not np.all(np.isfinite(v)):
            raise ParameterError(f"{source}: '{k}' is not finite ({v})")
        group = k if k == "density" else k.rsplit("_", 1)[0]
        lo, hi = _BOUNDS[group]
        strict_pos = group in ("density", "bend_k1", "stretch_alpha")
        if np.any(v <= lo if strict_pos else v < lo) or np.any(v > hi):
            raise ParameterError(
                f"{source}: '{k}' = {v.tolist()} {UNITS[k]} is outside the physical range "
                f"({'>' if strict_pos else '>='} {lo:g}, <= {hi:g}); check the units "
                f"(drapejax.units converts CLO, KES, FAST and BS 3356 values)")
    for d in ("warp", "weft", "bias"):
        k1 = np.asarray(getattr(p, f"bend_k1_{d}"), float)
        k2 = np.asarray(getattr(p, f"bend_k2_{d}"), float)
        if not np.all(_moment_monotone(k1, k2, np)):
            raise ParameterError(
                f"{source}: bending moment k1*kappa + k2*kappa^2 in the {d} direction is not monotone "
                f"for curvature up to {KAPPA_RANGE:g} 1/m (needs bend_k1_{d} + 2*bend_k2_{d}*{KAPPA_RANGE:g} > 0; "
                f"got k1={k1.tolist()}, k2={k2.tolist()})")
    host = types.SimpleNamespace(**{k: np.asarray(getattr(p, k), float) for k in PARAM_KEYS})
    if not np.all(validity(host, xp=np)):
        raise ParameterError(
            f"{source}: bend_k1_bias is incompatible with bend_k1_warp and bend_k1_weft "
            f"(no positive-definite orthotropic plate has these three strip rigidities)")


def plate_compliance(p: FabricParams) -> Float[Array, "*b 3 3"]:
    """Orthotropic bending compliance in the material frame, acting on (κ_uu, κ_vv, 2κ_uv).

    Chosen so that a narrow strip cut along warp, weft or bias has exactly the measured
    rigidity k1 (strip rigidity in direction φ is $1/(c^4 S_{11} + s^4 S_{22} + c^2 s^2 (2S_{12}+S_{66}))$).
    The Poisson-like coupling S12 is zero unless positive-definiteness needs it.
    """
    s11, s22 = 1.0 / p.bend_k1_warp, 1.0 / p.bend_k1_weft
    c = 4.0 / p.bend_k1_bias - s11 - s22
    g = c + 2.0 * jnp.sqrt(s11 * s22)
    s66 = jnp.maximum(c, 0.5 * g)
    s12 = 0.5 * (c - s66)
    z = jnp.zeros_like(s11)
    return jnp.stack([
        jnp.stack([s11, s12, z], -1),
        jnp.stack([s12, s22, z], -1),
        jnp.stack([z, z, s66], -1),
    ], -2)


def plate_stiffness(p: FabricParams) -> Float[Array, "*b 3 3"]:
    """Inverse of ``plate_compliance``: N·m, acting on (κ_uu, κ_vv, 2κ_uv)."""
    return jnp.linalg.inv(plate_compliance(p))


def strip_rigidity(p: FabricParams, angle_deg) -> Array:
    """Bending rigidity (N·m) of a narrow strip cut at ``angle_deg`` to the warp.

    This is the directional rigidity the interpolation predicts; at 0, 90 and 45 degrees it
    equals bend_k1_warp, bend_k1_weft and bend_k1_bias.
    """
    s = plate_compliance(p)
    a = jnp.deg2rad(jnp.asarray(angle_deg, float))
    c, sn = jnp.cos(a), jnp.sin(a)
    m = jnp.stack([c * c, sn * sn, c * sn], -1)
    return 1.0 / jnp.einsum("...i,...ij,...j->...", m, s, m)


def k2_directional(p: FabricParams) -> Float[Array, "*b 3"]:
    """(k2_warp, k2_weft, k2_bias) in N·m²."""
    return jnp.stack([p.bend_k2_warp, p.bend_k2_weft, p.bend_k2_bias], -1)


def mean_k1(p: FabricParams) -> Array:
    """The fabric's overall linear rigidity: the geometric mean of k1 over warp, weft and bias, N·m."""
    return (p.bend_k1_warp * p.bend_k1_weft * p.bend_k1_bias) ** (1.0 / 3.0)


def bending_length(p: FabricParams, direction: str = "warp") -> Array:
    """Peirce bending length c = (k1/(ρ g))^(1/3), m; ``direction="mean"`` uses ``mean_k1`` (the
    fabric's overall length, which sets the width of its Cusick folds)."""
    if direction == "mean":
        k1 = mean_k1(p)
    else:
        k1 = getattr(p, f"bend_k1_{direction}")
    return (k1 / (p.density * G)) ** (1.0 / 3.0)


def load_params(path: str | os.PathLike) -> FabricParams:
    """Read a parameter JSON file (flat SI schema); errors name the file and key."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"{path}: parameter file not found") from None
    except json.JSONDecodeError as e:
        raise ParameterError(f"{path}: invalid JSON ({e.msg} at line {e.lineno})") from None
    if isinstance(d, dict) and "params" in d and isinstance(d["params"], dict):
        d = d["params"]
    return FabricParams.from_dict(d, source=str(path))


def example_params(name: str = "mid") -> FabricParams:
    """Embedded example fabrics (no data download): 'light', 'mid', 'heavy'.

    Values are close to the 5%, 50% and 95% quantiles of the 618 measured fabrics
    (units-and-ranges.md).
    """
    table = {
        "light": dict(density=0.08, bend_k1_warp=2.0e-6, bend_k1_weft=1.5e-6, bend_k1_bias=1.8e-6,
                      bend_k2_warp=-4e-9, bend_k2_weft=-3e-9, bend_k2_bias=-3e-9),
        "mid": dict(density=0.197, bend_k1_warp=13.8e-6, bend_k1_weft=8.8e-6, bend_k1_bias=11.5e-6,
                    bend_k2_warp=-3.5e-8, bend_k2_weft=-2.2e-8, bend_k2_bias=-3e-8),
        "heavy": dict(density=0.40, bend_k1_warp=80e-6, bend_k1_weft=45e-6, bend_k1_bias=55e-6,
                      bend_k2_warp=-2e-7, bend_k2_weft=-1e-7, bend_k2_bias=-1.2e-7),
    }
    if name not in table:
        raise ParameterError(f"unknown example fabric {name!r}; choose from {sorted(table)}")
    return FabricParams.make(**table[name])


def gamma_cusick(p: FabricParams, overhang_m: float = 0.06, direction: str = "warp") -> Array:
    """Gravito-bending number Γ = ρ g L³ / k1 of a drape with overhang L."""
    return p.density * G * overhang_m**3 / getattr(p, f"bend_k1_{direction}")


__all__ = [
    "FabricParams", "ParameterError", "PARAM_KEYS", "BENDING_KEYS", "STRETCH_KEYS", "DEFAULTS",
    "UNITS", "G", "KAPPA_RANGE", "check", "validity", "stack", "unstack", "plate_compliance",
    "plate_stiffness", "strip_rigidity", "k2_directional", "mean_k1", "bending_length", "load_params",
    "example_params", "gamma_cusick", "DIRECTIONS", "PER_DENSITY_SUFFIX", "LOG_TARGET_NAMES",
    "LOG_STRETCH_NAMES", "to_matrix", "from_matrix", "to_per_density", "from_per_density", "to_log_targets",
    "to_log_stretch", "from_log_stretch", "from_log_targets", "from_log_theta", "to_log_theta",
    "scale_stretch", "with_stretch_alpha",
]
