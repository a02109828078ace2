"""How much of the bending parameters a dataset's observations hold: a linear baseline for the networks.

    python experiments/inverse_baseline.py DATASET [--invariant] [--mlp] [--redrop M] [--out rows.jsonl]

Hand-made features of each drape, then ridge regression (scikit-learn, penalty chosen by internal
cross-validation) on the targets of ``train_inverse.py``:

- the hem curve's radius r(s) and height z(s) around the specimen: amplitudes of harmonics 0-15
  (unchanged by an in-plane rotation);
- the top-view height map's mean over 24 rings around the centre (also rotation-invariant);
- unless ``--invariant``: the real and imaginary parts of harmonics 0-4 of r and z, which carry
  the warp/weft direction the simulated drapes are aligned with.

Prints one JSON line per evaluation: on ``train_inverse.py``'s own split (same seed, same 10 %
held out, so its ``r2_val_*`` compare line for line) and 10-fold cross-validation over all
converged drapes (less noisy than one split of a small dataset). With ``--mlp``, also the package's
equinox ``MLPRegressor`` on the same features and split, trained as ``train_inverse.py`` trains its
regressors (standardised targets, early stopping on the held-out part). With ``--redrop M``, how
much of the baseline's error is fold noise: M fresh prior members (indices from 5000, not in the
dataset's first 5000) are each dropped with three seeds at the dataset's mesh spacing, and the
variance of the ridge's predictions (trained on all drapes) between the seeds of one member is
reported as a fraction of the targets' variance: the R² that drop-to-drop noise alone costs it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from sklearn.linear_model import RidgeCV
from sklearn.metrics import r2_score
from sklearn.model_selection import KFold, cross_val_predict
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from drapejax.inverse import estimate as est

sys.path.insert(0, str(Path(__file__).resolve().parent))
from jsonl import emit  # noqa: E402
from train_inverse import K1_COLUMNS, load_dataset, split  # noqa: E402

RINGS = 24


def harmonics(a: np.ndarray, k: int, phase: bool) -> np.ndarray:
    """(b, s) periodic signals → amplitudes of harmonics 0..k-1, or their real and imaginary parts."""
    c = np.fft.rfft(a, axis=1)[:, :k] / a.shape[1]
    return np.concatenate([c.real, c.imag], 1) if phase else np.abs(c)


def ring_profile(height: np.ndarray) -> np.ndarray:
    """(b, n, n) height maps (NaN off the fabric, counted as 0) → mean over ``RINGS`` rings, (b, RINGS)."""
    n = height.shape[-1]
    yy, xx = np.mgrid[:n, :n]
    ring = np.minimum((np.hypot(yy - n / 2 + 0.5, xx - n / 2 + 0.5) / (n / 2) * RINGS).astype(int), RINGS)
    count = np.bincount(ring.ravel(), minlength=RINGS + 1)[:RINGS]
    h = np.nan_to_num(height, nan=0.0).reshape(len(height), -1)
    sums = np.stack([np.bincount(ring.ravel(), weights=row, minlength=RINGS + 1)[:RINGS] for row in h])
    return sums / count


def features(data: dict, invariant: bool) -> np.ndarray:
    b = data["boundary"]
    r, z = np.linalg.norm(b[..., :2], axis=-1), b[..., 2]
    parts = [harmonics(r, 16, False), harmonics(z, 16, False), ring_profile(data["height"])]
    if not invariant:
        parts += [harmonics(r, 5, True), harmonics(z, 5, True)]
    return np.concatenate(parts, 1)


def scores(y: np.ndarray, pred: np.ndarray) -> dict:
    out = {f"r2_{name}": float(r2_score(y[:, i], pred[:, i])) for i, name in enumerate(est.TARGET_NAMES)}
    out["r2_log_k1_mean_per_density"] = float(r2_score(y[:, K1_COLUMNS].mean(1), pred[:, K1_COLUMNS].mean(1)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--invariant", action="store_true", help="rotation-invariant features only")
    ap.add_argument("--val-fraction", type=float, default=0.1, help="as train_inverse.py's data.val_fraction")
    ap.add_argument("--split-seed", type=int, default=0, help="as train_inverse.py's data.seed")
    ap.add_argument("--mlp", action="store_true", help="also the equinox MLP regressor on the same features")
    ap.add_argument("--redrop", type=int, default=0, metavar="M",
                    help="fresh members dropped with three seeds each, for the fold-noise share (0: none)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    data = load_dataset(a.dataset, None)
    x, y = features(data, a.invariant), est.targets_from_params(data["params"])
    model = lambda: make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 3, 13)))
    n = len(y)
    val, train = split(n, a.val_fraction, a.split_seed)
    n_val = len(val)
    common = {"dataset": str(Path(a.dataset).resolve()), "features": x.shape[1], "invariant": a.invariant}
    pred = model().fit(x[train], y[train]).predict(x[val])
    emit({**common, "evaluation": "train_inverse split", "n_train": len(train), "n_val": n_val,
          **scores(y[val], pred)}, a.out)
    pred = cross_val_predict(model(), x, y, cv=KFold(10, shuffle=True, random_state=a.split_seed))
    emit({**common, "evaluation": "10-fold", "n": n, **scores(y, pred)}, a.out)
    if a.mlp:  # before --redrop, whose simulator switches JAX to float64 for the rest of the process
        emit({**common, "evaluation": "train_inverse split, equinox MLP", "n_train": len(train), "n_val": n_val,
              **scores(y[val], mlp_predict(x, y, train, val))}, a.out)
    if a.redrop:
        emit({**common, "evaluation": "drop-seed noise", **seed_noise(model().fit(x, y), y, a.dataset, a.redrop,
                                                                       a.invariant)}, a.out)


def seed_noise(model, y: np.ndarray, dataset: str, members: int, invariant: bool, seeds: int = 3) -> dict:
    """Between-seed variance of ``model``'s predictions over fresh members, / the variance of targets ``y``."""
    import jax
    import jax.numpy as jnp

    from drapejax.inverse.dataset import named_observer, quick_simulate
    from drapejax.inverse.prior import default_prior
    from drapejax.mesh import cusick_mesh

    jax.config.update("jax_enable_x64", True)
    mesh = cusick_mesh(json.loads((Path(dataset) / "dataset.json").read_text())["mesh_spacing_m"])
    faces = np.asarray(mesh.faces)
    params = default_prior().sample_indices(np.arange(5000, 5000 + members), 0)
    res = quick_simulate(mesh, jax.tree.map(lambda v: jnp.repeat(jnp.asarray(v), seeds, 0), params),
                         np.arange(members * seeds) + 777)
    x, status = np.asarray(res.x), np.asarray(res.status)
    obs = {name: np.stack([named_observer(name)(v, faces) for v in x]) for name in ("boundary", "height")}
    at_rest = (status.reshape(members, seeds) == 0).all(1)
    pred = model.predict(features(obs, invariant)).reshape(members, seeds, -1)[at_rest]
    out = {"members": int(at_rest.sum()), "seeds": seeds,
           **{f"seed_var_over_var_{est.TARGET_NAMES[i]}": float(pred[:, :, i].var(1, ddof=1).mean() / y[:, i].var())
              for i in K1_COLUMNS}}
    out["seed_var_over_var_log_k1_mean_per_density"] = float(pred[:, :, K1_COLUMNS].mean(2).var(1, ddof=1).mean()
                                                             / y[:, K1_COLUMNS].mean(1).var())
    return out


def mlp_predict(x: np.ndarray, y: np.ndarray, train: np.ndarray, val: np.ndarray) -> np.ndarray:
    """A ``drapejax.inverse.train.train_regressor`` MLP (hidden 64, 64) on standardised features and targets."""
    import jax
    import jax.numpy as jnp

    from drapejax.inverse.nets import Standardizer
    from drapejax.inverse.train import predict, train_regressor

    x_norm, y_norm = Standardizer.fit(jnp.asarray(x[train])), Standardizer.fit(jnp.asarray(y[train]))
    xs, ys = np.asarray(x_norm(jnp.asarray(x)), np.float32), np.asarray(y_norm(jnp.asarray(y)), np.float32)
    empty = np.zeros((len(x), 0), np.float32)
    reg, _ = train_regressor(xs[train], ys[train], key=jax.random.PRNGKey(0), hidden=(64, 64), epochs=300,
                             val_data=(xs[val], empty[val], ys[val]), patience=30)
    return np.asarray(y_norm.inverse(jnp.asarray(predict(reg, xs[val], empty[val]))))


if __name__ == "__main__":
    main()
