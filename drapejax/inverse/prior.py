"""Parameter prior of real fabrics: a Gaussian mixture fitted to 618 measured fabrics.

Bending follows seed 001 §6.3 (a 5-component GMM over measured parameters, after
[JC20] there) in the density-normalised, log-scaled coordinates of both seeds. The prior works in a
13-d latent space, one coordinate per entry of ``PARAM_KEYS``:

- ``log ρ`` (ρ areal density, kg/m²);
- ``log(k1/ρ)`` per direction (warp, weft, bias; k1 in N·m);
- ``log(1 + 2r)`` per direction with ``r = k2·κ_ref/k1`` and κ_ref = ``KAPPA_RANGE`` (1/m).
  The moment law M = k1·κ + k2·κ² is monotone on [0, κ_ref] iff 1 + 2r > 0, so sampling the
  log of it can never produce a non-monotone (softening past zero stiffness) fabric; the 9 of
  618 measured fabrics that violate it are excluded from the fit;
- ``log α`` per direction (α tensile stiffness per width, N/m) and ``log(1 + β)`` (β > −1;
  the prior puts 99% of fabrics at β ≥ 0, i.e. stiffening).

Stretching is not in the 618-fabric file, so its prior is a documented log-normal model
conditioned on density, with literature sources: see ``STRETCH_PRIOR``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp
from jaxtyping import Array, Float

from ..material import (BENDING_KEYS, KAPPA_RANGE, PARAM_KEYS, STRETCH_KEYS, FabricParams,
                        validity)

FORMAT = "drapejax-prior/1"

LATENT_NAMES = (
    "log_density",
    "log_k1_over_rho_warp", "log_k1_over_rho_weft", "log_k1_over_rho_bias",
    "log_1p2r_warp", "log_1p2r_weft", "log_1p2r_bias",
    "log_alpha_warp", "log_alpha_weft", "log_alpha_bias",
    "log1p_beta_warp", "log1p_beta_weft", "log1p_beta_bias",
)
"""Names of the 13 latent coordinates, in ``PARAM_KEYS`` order."""

_CSV_HEADER = ("density", "linear warp", "linear weft", "linear diag",
               "nonlinear warp", "nonlinear weft", "nonlinear diag")

STRETCH_PRIOR = {
    "rho_ref": 0.2,
    "median_at_rho_ref": [400.0, 250.0, 60.0, 3.0, 3.0, 3.0],
    "density_exponent": [0.3, 0.3, 0.3, 0.0, 0.0, 0.0],
    "log_sd": [0.55, 0.55, 0.55, 0.6, 0.6, 0.6],
    "corr_alpha": 0.6,
    "corr_beta": 0.5,
    "trunc_sigma": 3.0,
}
"""Stretching prior in the latent (log α, log(1 + β)) coordinates, conditioned on ρ.

Literature values: woven fabrics have tensile stiffness of order 1e2–1e3 N/m per width and
shear modulus G of order 10–1e2 N/m (Kawabata & Niwa 1989 KES-F surveys, as summarised in
``shared/spec/units-and-ranges.md``). Each of the two bias springs carries ``alpha_bias``, so
``alpha_bias = 2 G``. Medians are the geometric centres of those ranges (warp stiffer than
weft, as crimp interchange makes the weft the more extensible set): α = 400, 250, 60 N/m at
ρ = 0.2 kg/m²; log-sd 0.55 puts 95% of fabrics within a factor 3 (1e2–1e3 for the tensile
directions). Heavier fabrics are stiffer: α ∝ ρ^0.3, a weak coupling (correlation ≈ 0.35
with log ρ over the 618 densities). The three α share a correlation 0.6 (a fabric stiff in
warp tends to be stiff in weft; seed 001 Fig. 7 shows direction curves of one group moving
together). The exponential stiffening β of seed 001 Eq. (1) is log-normal in 1 + β with
median β = 3 and 99.7% below ≈ 23 (β 0–~20 for stiffening fabrics), independent of α,
correlation 0.5 between directions. Latent residuals are truncated at 3 sd.
"""


class PriorError(ValueError):
    """A malformed prior file or fabric table; the message names the file and field."""


def read_fabric_table(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ρ (n,), k1 (n,3), k2 (n,3)) in SI from a fabric table in the 618-fabric CSV layout
    (Feng et al. 2022: density, linear k1 ×1e-9 N·m and nonlinear k2 ×1e-12 N·m² for warp, weft, diagonal)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise PriorError(f"{path}: fabric table not found") from None
    if not lines:
        raise PriorError(f"{path}: empty file")
    header = tuple(h.strip().split("[")[0].strip() for h in lines[0].split(","))
    if header != _CSV_HEADER:
        raise PriorError(f"{path}: header {lines[0]!r} does not have the columns {list(_CSV_HEADER)} "
                         f"(density[kg.m-2], linear */nonlinear * in SI*1e9 / SI*1e12)")
    rows = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        try:
            vals = [float(v) for v in line.split(",")]
        except ValueError:
            raise PriorError(f"{path}:{lineno}: non-numeric value in {line!r}") from None
        if len(vals) != len(_CSV_HEADER):
            raise PriorError(f"{path}:{lineno}: expected {len(_CSV_HEADER)} values, got {len(vals)}")
        rows.append(vals)
    d = np.asarray(rows, float)
    if not np.all(np.isfinite(d)) or np.any(d[:, :4] <= 0):
        raise PriorError(f"{path}: density and linear coefficients must be finite and positive")
    return d[:, 0], d[:, 1:4] * 1e-9, d[:, 4:7] * 1e-12


def _stretch_moments(spec: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean at rho_ref (6,), slope on log ρ (6,), covariance (6,6)) of the stretch latent."""
    med = np.asarray(spec["median_at_rho_ref"], float)
    mean = np.concatenate([np.log(med[:3]), np.log1p(med[3:])])
    slope = np.asarray(spec["density_exponent"], float)
    sd = np.asarray(spec["log_sd"], float)
    corr = np.eye(6)
    corr[:3, :3] = np.where(np.eye(3) > 0, 1.0, spec["corr_alpha"])
    corr[3:, 3:] = np.where(np.eye(3) > 0, 1.0, spec["corr_beta"])
    return mean, slope, corr * sd[:, None] * sd[None, :]


class FabricPrior(eqx.Module):
    """Prior over ``FabricParams``: a bending GMM plus a density-conditioned stretch log-normal.

    Attributes:
        weights: (K,) mixture weights of the bending GMM.
        means: (K, 7) component means in the bending latent (first 7 of ``LATENT_NAMES``).
        covs: (K, 7, 7) component covariances.
        lo, hi: (13,) latent support box; samples outside it are redrawn (it is the range of
            the fitted data widened by 10% per side, and the stretch model's ±3 sd range).
        stretch_mean: (6,) stretch latent mean at ``rho_ref``.
        stretch_slope: (6,) d(stretch latent)/d(log ρ).
        stretch_cov: (6, 6) stretch latent covariance.
        rho_ref: reference density of the stretch model, kg/m².
        kappa_ref: curvature (1/m) that makes k2 dimensionless, r = k2·κ_ref/k1.
        trunc_sigma: stretch residuals beyond this many sd are redrawn.
        source: provenance text.
    """

    weights: Float[Array, " K"]
    means: Float[Array, "K 7"]
    covs: Float[Array, "K 7 7"]
    lo: Float[Array, " 13"]
    hi: Float[Array, " 13"]
    stretch_mean: Float[Array, " 6"]
    stretch_slope: Float[Array, " 6"]
    stretch_cov: Float[Array, "6 6"]
    rho_ref: float = eqx.field(static=True)
    kappa_ref: float = eqx.field(static=True)
    trunc_sigma: float = eqx.field(static=True)
    source: str = eqx.field(static=True)

    @classmethod
    def fit(cls, path, *, n_components: int = 5, seed: int = 0) -> "FabricPrior":
        """Fit the bending GMM to the 618-fabric CSV (``fabrics_618_bending.csv``).

        Args:
            path: the CSV (density kg/m², k1 ×1e-9 N·m, k2 ×1e-12 N·m², warp/weft/diag).
            n_components: mixture components (5, as seed 001 §6.3).
            seed: sklearn random state (the fit is deterministic given it).
        """
        from sklearn.mixture import GaussianMixture
        from threadpoolctl import threadpool_limits

        path = Path(path)
        rho, k1, k2 = read_fabric_table(path)
        p = FabricParams.make(density=rho, bend_k1_warp=k1[:, 0], bend_k1_weft=k1[:, 1],
                              bend_k1_bias=k1[:, 2], bend_k2_warp=k2[:, 0], bend_k2_weft=k2[:, 1],
                              bend_k2_bias=k2[:, 2])
        ok = np.asarray(validity(p))
        u = np.maximum(1.0 + 2.0 * k2 * KAPPA_RANGE / k1, 1e-300)  # <= 0 only where not ok
        z = np.column_stack([np.log(rho), np.log(k1 / rho[:, None]), np.log(u)])[ok]
        with threadpool_limits(1):  # 609×7 data: BLAS/OpenMP threads only add overhead
            gmm = GaussianMixture(n_components, covariance_type="full", n_init=5, random_state=seed,
                                  reg_covar=1e-6).fit(z)
        spec = STRETCH_PRIOR
        s_mean, s_slope, s_cov = _stretch_moments(spec)
        zlo, zhi = z.min(0), z.max(0)
        pad = 0.1 * (zhi - zlo)
        ts = spec["trunc_sigma"]
        s_sd = np.sqrt(np.diag(s_cov))
        dlo, dhi = zlo[0] - pad[0] - np.log(spec["rho_ref"]), zhi[0] + pad[0] - np.log(spec["rho_ref"])
        s_lo = s_mean + np.minimum(s_slope * dlo, s_slope * dhi) - ts * s_sd
        s_hi = s_mean + np.maximum(s_slope * dlo, s_slope * dhi) + ts * s_sd
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
        source = (f"GMM({n_components}, full, seed={seed}) on {ok.sum()} of {len(ok)} fabrics in "
                  f"{path.name} (sha256 {digest}; {len(ok) - ok.sum()} with a non-monotone moment "
                  f"law on [0, {KAPPA_RANGE:g}] 1/m excluded); stretch: STRETCH_PRIOR literature model")
        f = jnp.asarray
        return cls(weights=f(gmm.weights_), means=f(gmm.means_), covs=f(gmm.covariances_),
                   lo=f(np.concatenate([zlo - pad, s_lo])), hi=f(np.concatenate([zhi + pad, s_hi])),
                   stretch_mean=f(s_mean), stretch_slope=f(s_slope), stretch_cov=f(s_cov),
                   rho_ref=float(spec["rho_ref"]), kappa_ref=float(KAPPA_RANGE),
                   trunc_sigma=float(ts), source=source)

    def to_latent(self, params: FabricParams) -> Float[Array, "*b 13"]:
        """Map parameters to the 13-d latent coordinates (``LATENT_NAMES``)."""
        rho = params.density
        k1 = [getattr(params, k) for k in BENDING_KEYS[:3]]
        k2 = [getattr(params, k) for k in BENDING_KEYS[3:]]
        cols = [jnp.log(rho)] + [jnp.log(a / rho) for a in k1]
        cols += [jnp.log1p(2.0 * b * self.kappa_ref / a) for a, b in zip(k1, k2)]
        cols += [jnp.log(getattr(params, k)) for k in STRETCH_KEYS[:3]]
        cols += [jnp.log1p(getattr(params, k)) for k in STRETCH_KEYS[3:]]
        return jnp.stack(cols, -1)

    def from_latent(self, z: Float[Array, "*b 13"]) -> FabricParams:
        """Inverse of ``to_latent``."""
        z = jnp.asarray(z)
        rho = jnp.exp(z[..., 0])
        k1 = [rho * jnp.exp(z[..., 1 + i]) for i in range(3)]
        k2 = [0.5 * jnp.expm1(z[..., 4 + i]) * k1[i] / self.kappa_ref for i in range(3)]
        vals = [rho] + k1 + k2 + [jnp.exp(z[..., 7 + i]) for i in range(3)]
        vals += [jnp.expm1(z[..., 10 + i]) for i in range(3)]
        return FabricParams(**dict(zip(PARAM_KEYS, vals)))

    def log_prob(self, params: FabricParams) -> Float[Array, " *b"]:
        """Log prior density of ``params`` with respect to the latent coordinates.

        Differentiable (pure jax.numpy). The density is that of the untruncated model: the
        support box, stretch truncation and validity redraw about 4% of draws in ``sample``,
        which shifts the normalisation by a constant (about 0.04) that is ignored here.
        """
        z = self.to_latent(params)
        lead = (None,) * (z.ndim - 1)
        d = z[..., None, :7] - self.means[lead]  # (*b, K, 7)
        chol = jnp.linalg.cholesky(self.covs)
        white = jnp.einsum("kij,...kj->...ki", jnp.linalg.inv(chol), d)
        logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol, axis1=-2, axis2=-1)), -1)
        comp = -0.5 * (jnp.sum(white**2, -1) + logdet[lead] + 7 * jnp.log(2 * jnp.pi))
        lp_bend = logsumexp(comp + jnp.log(self.weights)[lead], axis=-1)
        mean = self.stretch_mean[lead] + self.stretch_slope[lead] * (z[..., :1] - jnp.log(self.rho_ref))
        sc = jnp.linalg.cholesky(self.stretch_cov)
        ss = jnp.einsum("ij,...j->...i", jnp.linalg.inv(sc), z[..., 7:] - mean)
        lp_str = -0.5 * (jnp.sum(ss**2, -1) + 2.0 * jnp.sum(jnp.log(jnp.diag(sc)))
                         + 6 * jnp.log(2 * jnp.pi))
        return lp_bend + lp_str

    def sample(self, n: int, seed: int) -> FabricParams:
        """Draw ``n`` valid fabrics; member i depends only on (seed, i).

        Every member passes ``drapejax.material.validity`` and lies in the support box;
        invalid draws are redrawn from the member's own random stream.
        """
        return self.sample_indices(np.arange(n), seed)

    def sample_indices(self, indices, seed: int) -> FabricParams:
        """Members ``indices`` of the infinite sequence ``sample(∞, seed)`` (batched)."""
        cw = np.cumsum(np.asarray(self.weights, float))
        mu = np.asarray(self.means, float)
        ch = np.linalg.cholesky(np.asarray(self.covs, float))
        s_cov = np.asarray(self.stretch_cov, float)
        s_ch, s_sd = np.linalg.cholesky(s_cov), np.sqrt(np.diag(s_cov))
        smean, sslope = np.asarray(self.stretch_mean, float), np.asarray(self.stretch_slope, float)

        def transform(raw):
            k = np.minimum(np.searchsorted(cw / cw[-1], raw[:, 0], side="right"), len(cw) - 1)
            zb = mu[k] + np.einsum("bij,bj->bi", ch[k], raw[:, 1:8])
            eps = raw[:, 8:] @ s_ch.T
            eps[np.any(np.abs(eps) > self.trunc_sigma * s_sd, axis=1)] = np.nan
            return np.concatenate([zb, smean + sslope * (zb[:, :1] - np.log(self.rho_ref)) + eps], 1)

        return self._rejection(indices, seed, transform)

    def sample_uniform_box(self, n: int, seed: int) -> FabricParams:
        """Draw ``n`` valid fabrics uniformly in the latent support box (uniform in log).

        For coverage studies and datasets that must not under-represent rare fabrics;
        member i depends only on (seed, i).
        """
        from scipy.special import ndtr

        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        return self._rejection(np.arange(n), seed, lambda raw: lo + (hi - lo) * ndtr(raw[:, 1:]))

    def _rejection(self, indices, seed: int, transform) -> FabricParams:
        """Redraw members until valid and inside the box, each from its own stream (seed, index).

        Every candidate consumes one uniform and 13 standard normals of its stream; ``transform``
        maps a (b, 14) block of [uniform, 13 normals] to latent candidates (NaN = reject).
        """
        indices = np.asarray(indices, np.int64).reshape(-1)
        rngs = [np.random.default_rng([int(seed), int(i)]) for i in indices]
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        z = np.full((len(indices), 13), np.nan)
        todo = np.arange(len(indices))
        for _ in range(1000):
            if todo.size == 0:
                out = _from_latent_jit(self, jnp.asarray(_pad(z)))
                return FabricParams(**{k: jnp.asarray(np.asarray(getattr(out, k))[:len(z)]) for k in PARAM_KEYS})
            raw = np.stack([np.concatenate([rngs[j].random(1), rngs[j].standard_normal(13)])
                            for j in todo])
            cand = transform(raw)
            inside = np.all((cand >= lo) & (cand <= hi), axis=1)
            ok = inside & _valid_latent(self, cand)
            z[todo[ok]] = cand[ok]
            todo = todo[~ok]
        raise PriorError(f"prior ({self.source}): could not draw valid fabrics for {todo.size} "
                         f"member(s) in 1000 tries; the support box excludes its own density")

    def to_json(self) -> str:
        """Serialise to a small JSON document (format ``drapejax-prior/1``)."""
        d = {
            "format": FORMAT,
            "source": self.source,
            "latent": list(LATENT_NAMES),
            "kappa_ref": self.kappa_ref,
            "rho_ref": self.rho_ref,
            "trunc_sigma": self.trunc_sigma,
            "bending_gmm": {"weights": np.asarray(self.weights).tolist(),
                            "means": np.asarray(self.means).tolist(),
                            "covariances": np.asarray(self.covs).tolist()},
            "support": {"lo": np.asarray(self.lo).tolist(), "hi": np.asarray(self.hi).tolist()},
            "stretch": {"mean": np.asarray(self.stretch_mean).tolist(),
                        "slope_log_density": np.asarray(self.stretch_slope).tolist(),
                        "covariance": np.asarray(self.stretch_cov).tolist()},
        }
        return json.dumps(d, indent=1)

    @classmethod
    def from_json(cls, text: str, *, source: str = "prior JSON") -> "FabricPrior":
        """Parse ``to_json`` output; ``source`` names the file in error messages."""
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise PriorError(f"{source}: invalid JSON ({e.msg} at line {e.lineno})") from None
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise PriorError(f"{source}: 'format' must be {FORMAT!r}")
        if d.get("latent") != list(LATENT_NAMES):
            raise PriorError(f"{source}: 'latent' must list {list(LATENT_NAMES)}")

        def arr(path: str, shape):
            node = d
            for key in path.split("."):
                if not isinstance(node, dict) or key not in node:
                    raise PriorError(f"{source}: missing field '{path}'")
                node = node[key]
            try:
                a = np.asarray(node, float)
            except (TypeError, ValueError):
                raise PriorError(f"{source}: '{path}' must be numeric") from None
            if a.shape != shape(a) or not np.all(np.isfinite(a)):
                raise PriorError(f"{source}: '{path}' has shape {a.shape} or non-finite values")
            return jnp.asarray(a)

        w = arr("bending_gmm.weights", lambda a: (a.size,))
        k = w.shape[0]
        return cls(weights=w, means=arr("bending_gmm.means", lambda a: (k, 7)),
                   covs=arr("bending_gmm.covariances", lambda a: (k, 7, 7)),
                   lo=arr("support.lo", lambda a: (13,)), hi=arr("support.hi", lambda a: (13,)),
                   stretch_mean=arr("stretch.mean", lambda a: (6,)),
                   stretch_slope=arr("stretch.slope_log_density", lambda a: (6,)),
                   stretch_cov=arr("stretch.covariance", lambda a: (6, 6)),
                   rho_ref=float(arr("rho_ref", lambda a: ())), kappa_ref=float(arr("kappa_ref", lambda a: ())),
                   trunc_sigma=float(arr("trunc_sigma", lambda a: ())), source=str(d.get("source", source)))


_from_latent_jit = eqx.filter_jit(FabricPrior.from_latent)


@eqx.filter_jit
def _valid_latent_jit(prior: FabricPrior, z: Float[Array, "b 13"]):
    return validity(prior.from_latent(z))


def _pad(z: np.ndarray) -> np.ndarray:
    """Zero-pad rows to a power of two (at least 64) so compiled functions are reused, NaN → 0."""
    b = len(z)
    size = max(64, 1 << max(0, (b - 1).bit_length()))
    return np.concatenate([np.nan_to_num(z), np.zeros((size - b, z.shape[1]))])


def _valid_latent(prior: FabricPrior, z: np.ndarray) -> np.ndarray:
    """``validity`` of latent rows (rows with NaN are invalid)."""
    ok = np.asarray(_valid_latent_jit(prior, jnp.asarray(_pad(z))))[:len(z)]
    return ok & np.all(np.isfinite(z), 1)


def default_prior() -> FabricPrior:
    """The prior fitted to the 618 measured fabrics, shipped as ``drapejax/data/prior_618.json``.

    That file is ``FabricPrior.fit("../shared/data/reference/fabrics_618_bending.csv").to_json()``.
    """
    path = Path(__file__).resolve().parents[1] / "data" / "prior_618.json"
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise PriorError(f"{path}: shipped prior not found (reinstall drapejax)") from None
    return FabricPrior.from_json(text, source=str(path))


__all__ = ["FabricPrior", "PriorError", "default_prior", "read_fabric_table", "LATENT_NAMES", "STRETCH_PRIOR"]
