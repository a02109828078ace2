r"""The membrane that strip tensile readings imply (Kawabata 1980, KES-FB1; ISO 13934-1).

A drape tells little about the membrane, yet on the coarse fit mesh a light fabric's drape
follows it: a fit that holds a membrane four times too soft explains the difference with an
effect that is not there (``docs/results/2026-12-06-membrane-scan.md``). Every fit holds the
membrane of its start (the network's estimate), so a tensile test of the fabric, when a folder
holds one (``io.BenchRecord`` with ``test="tensile"``), sets it instead.

The forward model is the simulator's own membrane energy (``energy.Membrane``) under the strip
test's homogeneous deformation. A strip cut at angle φ to the warp is pulled to nominal strain ε
with its long edges free: in the strip's frame $F_s = \begin{pmatrix}1+\epsilon & g\\ 0 & 1+e
\end{pmatrix}$, turned into the material frame by the rotation $Q(φ)$, $F = Q F_s Q^\top$, and the
lateral strain $e$ and shear $g$ minimise the energy density ψ(F) (free edges carry no traction).
The force per unit width is $\partial\psi/\partial\epsilon$ at that minimum (the envelope theorem:
$e$ and $g$ are held). At small strain along the warp this is $\epsilon(\alpha_w + \alpha_b
\alpha_f/(2\alpha_f + \alpha_b))$: the bias springs add to the warp's what the free contraction
leaves of them.

The inverse holds each direction's exponential stiffening β and fits log α: one overall scale
free, and each direction's departure from the start's direction ratios under a Gaussian prior of
``RATIO_STD`` (a reading along one cut rescales the whole membrane; readings along warp, weft and
bias set each). Readings are whitened by ``io.READING_STD`` as a log force. Gauss–Newton on
the exact (nonlinear) forward model.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..energy import Membrane
from ..io import CUT_ANGLES_DEG, READING_STD, BenchRecord
from ..material import DIRECTIONS, FabricParams, with_stretch_alpha

RATIO_STD = 0.5
"""Prior std of each direction's log α about the start's direction ratios (a factor e^0.5 ≈ 1.6)."""
TENSILE_STRAIN = 0.01
"""The strain at which the virtual lab reads its strips (1 %: the initial, nearly linear part of
a woven's KES-FB1 curve, where α, the stiffness at zero strain, is read)."""
_LATERAL_ITERATIONS = 30
"""Most Newton steps on the free strains; fewer than 6 at the 1–2 % strains of a reading."""
_FIT_ITERATIONS = 10


def _energy_density(f: jax.Array, params: FabricParams) -> jax.Array:
    """ψ(F), J/m², of the membrane under the in-plane deformation gradient ``f`` (2, 2) in the
    material frame: ``Membrane``'s element energy of a unit right triangle (rest legs along warp
    and weft, area 1), so the strip test sees exactly the simulator's membrane."""
    xe = jnp.concatenate([jnp.zeros((3, 2)).at[1].set(f[:, 0]).at[2].set(f[:, 1]), jnp.zeros((3, 1))], axis=1)
    return Membrane().element_energy(xe, (jnp.eye(2), jnp.asarray(1.0)), params)


def _force(params: FabricParams, phi, strain) -> jax.Array:
    """Force per unit width of a strip cut at angle ``phi`` (rad) from the warp (module docstring)."""
    c, s = jnp.cos(phi), jnp.sin(phi)
    q = jnp.stack([jnp.stack([c, -s]), jnp.stack([s, c])])

    def psi(eps, free):
        g, e = free[0], free[1]
        fs = jnp.stack([jnp.stack([1.0 + eps, g]), jnp.stack([jnp.zeros_like(g), 1.0 + e])])
        return _energy_density(q @ fs @ q.T, params)

    held = jax.lax.stop_gradient(strain)
    tol = jnp.sqrt(jnp.finfo(held.dtype).eps)

    def newton(state):  # the two free strains: a smooth, convex 2-D problem
        it, free, _ = state
        (pull, g) = jax.grad(psi, (0, 1))(held, free)
        (a, b), (c, d) = jax.hessian(psi, 1)(held, free)
        unbalanced = jnp.max(jnp.abs(g)) > tol * (jnp.abs(pull) + tol)  # edge traction relative to the pull
        step = jnp.stack([d * g[0] - b * g[1], a * g[1] - c * g[0]]) / (a * d - b * c)  # the 2x2 solve
        return it + 1, jnp.where(unbalanced, free - step, free), unbalanced

    def unconverged(state):
        return (state[0] < _LATERAL_ITERATIONS) & state[2]

    _, free, unbalanced = jax.lax.while_loop(unconverged, newton, (0, jnp.zeros(2, held.dtype), jnp.asarray(True)))
    force = jax.grad(psi, 0)(strain, jax.lax.stop_gradient(free))
    # NaN where the free edges' equilibrium was not reached: a reading at a strain the law cannot take
    return jnp.where(unbalanced, jnp.nan, force)


@jax.jit
def _forces(params: FabricParams, phi: jax.Array, strain: jax.Array) -> jax.Array:
    """``_force`` of each (angle, strain) pair: one compiled program for every strip of a fabric."""
    return jax.vmap(lambda a, e: _force(params, a, e))(phi, strain)


def tensile_force(params: FabricParams, direction: str, strain) -> jax.Array:
    """Force per unit width, N/m, of a strip cut along ``direction`` (``io.CUT_ANGLES_DEG``)
    pulled to nominal ``strain`` with free long edges (module docstring). Differentiable in
    ``params``; one fabric (no batch dims). NaN where the free strains' equilibrium was not found
    within ``_LATERAL_ITERATIONS`` Newton steps."""
    eps = jnp.atleast_1d(jnp.asarray(strain, jnp.result_type(float)))
    return _forces(params, jnp.full(eps.shape, np.deg2rad(CUT_ANGLES_DEG[direction]), eps.dtype), eps)[0]


def tensile_readings(readings: Sequence[BenchRecord]) -> tuple[BenchRecord, ...]:
    """The tensile readings among ``readings`` (a measurement's ``bench``)."""
    return tuple(r for r in readings if r.test == "tensile")


def membrane_from_tensile(readings: Sequence[BenchRecord], params: FabricParams, *, std: float = READING_STD,
                          ratio_std: float = RATIO_STD) -> tuple[FabricParams, dict]:
    """``params`` with the tensile stiffness α that ``readings`` imply (module docstring); the other
    fields, β included, kept. ``readings``: tensile ``BenchRecord`` objects (others are ignored).

    Returns (params, record): record {"readings" (count), "alpha" {direction: N/m}, "factor"
    {direction: the new α over the start's}, "rms_log_error" (the readings' RMS log misfit after
    the fit; about ``std`` when the membrane law fits them), "std_log_alpha" {direction: Gauss–Newton
    std of log α}, "std_log_scale" (std of the mean log α over the three directions: the overall
    membrane scale that the identifiability analysis frees)}. Raises ValueError without a tensile reading."""
    rs = tensile_readings(readings)
    if not rs:
        raise ValueError("membrane_from_tensile needs at least one tensile reading")
    log_meas = np.log([r.measured for r in rs])
    phi = jnp.asarray([np.deg2rad(CUT_ANGLES_DEG[r.direction]) for r in rs])
    strain = jnp.asarray([r.values["strain"] for r in rs], phi.dtype)
    log0 = np.log([float(getattr(params, f"stretch_alpha_{d}")) for d in DIRECTIONS])
    lift = np.hstack([np.ones((3, 1)), np.eye(3)])  # log α = log α0 + s + δ, z = (s, δ)
    prior = np.hstack([np.zeros((3, 1)), np.eye(3)]) / ratio_std

    def residuals(z):
        pred = np.log(np.asarray(_forces(with_stretch_alpha(params, jnp.exp(log0 + lift @ z)), phi, strain), float))
        return np.concatenate([(pred - log_meas) / std, prior @ z])

    def jacobian(z, r, h=1e-4):  # forward differences: the force is smooth in log α
        return np.stack([(residuals(z + h * e) - r) / h for e in np.eye(4)], 1)

    z = np.zeros(4)
    r = residuals(z)
    bad = [f"{rd.direction} at strain {rd.values['strain']}" for rd, ok in zip(rs, np.isfinite(r)) if not ok]
    if bad:
        raise ValueError(f"tensile reading(s) {', '.join(bad)}: the strip's free edges find no equilibrium under the "
                         "start's membrane law (a strain beyond what the law takes?)")
    for _ in range(_FIT_ITERATIONS):  # Gauss–Newton, halving a step that leaves the law's range
        step = np.linalg.lstsq(jacobian(z, r), -r, rcond=None)[0]
        for _ in range(20):
            r_next = residuals(z + step)
            if np.all(np.isfinite(r_next)):
                break
            step = 0.5 * step
        else:  # no step keeps the law in range: stay at the last finite point
            break
        z, r = z + step, r_next
        if np.max(np.abs(step)) < 1e-6:
            break
    jac = jacobian(z, r)
    cov = np.linalg.pinv(jac.T @ jac)
    cov_log = lift @ cov @ lift.T
    sd = np.sqrt(np.diag(cov_log))
    out = with_stretch_alpha(params, jnp.exp(log0 + lift @ z))
    alpha = {d: float(getattr(out, f"stretch_alpha_{d}")) for d in DIRECTIONS}
    return out, {"readings": len(rs), "alpha": alpha,
                 "factor": {d: alpha[d] / float(getattr(params, f"stretch_alpha_{d}")) for d in DIRECTIONS},
                 "rms_log_error": float(np.sqrt(np.mean((r[:len(rs)] * std) ** 2))),
                 "std_log_alpha": dict(zip(DIRECTIONS, sd.tolist())),
                 "std_log_scale": float(np.sqrt(cov_log.sum()) / 3.0)}


def measured_membrane_std(record: dict | None) -> float | None:
    """The std of the overall log α scale a ``membrane_of_captures`` record sets; None when no
    tensile reading set the membrane (none held, or left out)."""
    return None if record is None or "ignored" in record else float(record["std_log_scale"])


def membrane_of_captures(measurements: Sequence, params: FabricParams) -> tuple[FabricParams, dict | None]:
    """The start of a fit of ``measurements`` (captures of one fabric) with the membrane their
    tensile readings imply (``membrane_from_tensile``; each distinct reading once), or ``params``
    unchanged and None when they hold none. With the areal density unknown the fit works in k/ρ at
    a nominal density, where a measured α (not α/ρ) has no place: the readings are then left out,
    and the record says so ({"ignored": reason})."""
    seen = {}
    for m in measurements:
        for r in tensile_readings(m.bench):
            seen.setdefault(tuple(sorted(r.to_json().items())), r)
    if not seen:
        return params, None
    if any(m.areal_density_kg_m2 is None for m in measurements):
        return params, {"readings": len(seen), "ignored": "the areal density is unknown, so the drape sets "
                        "α/ρ and a measured α cannot be placed; the start's membrane is kept"}
    return membrane_from_tensile(tuple(seen.values()), params)


__all__ = ["tensile_force", "tensile_readings", "membrane_from_tensile", "membrane_of_captures",
           "measured_membrane_std", "RATIO_STD", "TENSILE_STRAIN"]
