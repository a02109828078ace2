"""How much of the bending parameters a dataset's observations hold: the 3DH ridge, cross-validated.

    python -m experiments.inverse_baseline DATASET [DATASET ...] [--invariant] [--stretch]
        [--height-pcs N | --height-pixels B] [--symmetric] [--redrop M [--simulate MODULE:FUNCTION]]
        [--test DATASET2 [--checkpoint MODEL.eqx ...]] [--out rows.jsonl]

The descriptor of ``drapejax.inverse.estimate.harmonic_feature`` (hem harmonics, height and
coverage ring profiles outside the support; ``--invariant``: without the complex hem harmonics
that carry the warp direction), then ridge regression (scikit-learn ``RidgeCV``, one penalty per
target by leave-one-out) on the targets of ``train_inverse.py`` (whose ``net=3dh`` trains the same
model as a checkpoint). ``--stretch`` adds the true stretching inputs (``STRETCH_INPUT_NAMES``), as
the "+S" methods take them from a tag; ``--height-pcs N`` adds the first N principal components
of the raw height map, fitted inside each training fold (a descriptor the ring profiles may miss;
not rotation-invariant). ``--symmetric`` first averages the height map over the material's
symmetries (the 180° turn and the mirrors in the warp and weft axes, which leave an orthotropic
fabric with equal bias directions unchanged), so that the components are not spent on where the
folds happened to form; the average is then one quadrant of the map. ``--height-pixels B`` adds
the height map's pixels themselves instead, averaged over B × B blocks, each standardised; the
block is scaled by a weight chosen inside each training fold (``pixel_model``), since the one
ridge penalty cannot set the pixels' share apart from the descriptor's.

Prints one JSON line per evaluation: on ``train_inverse.py``'s own split (same seed, same 10 %
held out, so its ``r2_val_*`` compare line for line) and 10-fold cross-validation over all
converged drapes (less noisy than one split of a small dataset), with the overall stiffness's error
in fifths of the prior from soft to stiff. With ``--redrop M``, how much of
the error is fold noise: M fresh prior members (indices from 5000, not in the dataset's first
5000) are each dropped with three seeds on the dataset's mesh with its ``simulate`` (the one
``dataset.json`` records, else ``--simulate``, default ``quick_simulate``), and the variance of the
ridge's predictions (trained on all drapes) between the seeds of one member is reported as a
fraction of the targets' variance: the R² that drop-to-drop noise alone costs it.

Several DATASETs are pooled, as one dataset of all their converged drapes: they must share the
mesh, the simulate, the prior and the observations (``dataset.json``), and differ in their seed, so
that no prior member is drawn twice (e.g. a second ``drapejax dataset --seed 1`` run, to see how
the score grows with the number of drapes).

With ``--test DATASET2`` the ridge trained on all of DATASET is scored on DATASET2's drapes: a
transfer check, e.g. from a coarse training mesh to drapes on a converged 5 mm mesh. A DATASET2 of
repeated drops (``drapejax dataset --drops-per-member D``) is also scored by the mean prediction
over each member's D drops, as several specimens of one fabric are read (a training DATASET may
not have repeats: its folds would split a member's drops). Each
``--checkpoint`` (a 3DH checkpoint such as the packaged ``drapejax/data/inverse_3dh*.eqx``) is
scored on the same drapes, with its own descriptor settings.
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

import numpy as np
from sklearn.compose import ColumnTransformer
from sklearn.decomposition import PCA
from sklearn.linear_model import RidgeCV
from sklearn.metrics import make_scorer, r2_score
from sklearn.model_selection import GridSearchCV, KFold, cross_val_predict
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import FunctionTransformer, StandardScaler

from drapejax.inverse import estimate as est

if __package__:  # python -m experiments.inverse_baseline
    from .common import K1_COLUMNS, drops_per_member, emit, harmonic_features, harmonic_meta, load_dataset, split
else:  # python experiments/inverse_baseline.py
    from common import K1_COLUMNS, drops_per_member, emit, harmonic_features, harmonic_meta, load_dataset, split


POOLED_KEYS = ("mesh_spacing_m", "mesh_rim_spacing_m", "simulate", "prior_sha256", "observations", "param_keys")
"""``dataset.json`` entries that pooled datasets must share."""


def pooled(directories: list[str]) -> tuple[dict[str, np.ndarray], dict]:
    """The converged drapes of several datasets concatenated, and the first one's ``dataset.json``.
    Raises SystemExit naming the dataset whose ``POOLED_KEYS`` differ from the first's or whose seed
    repeats an earlier one's (the same prior members again)."""
    cfgs = [json.loads((Path(d) / "dataset.json").read_text()) for d in directories]
    seen = {}
    for d, c in zip(directories, cfgs):
        for k in POOLED_KEYS:
            if c.get(k) != cfgs[0].get(k):
                raise SystemExit(f"{d}: dataset.json {k} = {c.get(k)!r}, but {directories[0]} has {cfgs[0].get(k)!r}")
        if c["seed"] in seen:
            raise SystemExit(f"{d}: seed {c['seed']} repeats {seen[c['seed']]}'s (the same prior members)")
        seen[c["seed"]] = d
    parts = [load_dataset(d, None) for d in directories]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, cfgs[0]


def features(data: dict, invariant: bool, stretch: bool = False, height_pcs: int = 0,
             symmetric: bool = False, height_pixels: int = 0) -> np.ndarray:
    """Design matrix: the 3DH descriptor, then the stretching inputs (``stretch``), then the raw
    height map (NaN as 0) when ``height_pcs`` asks for its principal components (``ridge_model``)
    or ``height_pixels`` for its pixels averaged over blocks of that side (``pixel_model``);
    ``symmetric``: one quadrant of its average over the material's symmetries (``height_columns``)."""
    parts = [harmonic_features(data, harmonic_meta(data, 0 if invariant else est.PHASE_HARMONICS))]
    if stretch:
        parts.append(est.stretch_inputs_from_params(data["params"]))
    if height_pcs or height_pixels:
        parts.append(height_columns(data["height"], symmetric, max(height_pixels, 1)))
    return np.hstack(parts)


def height_columns(height: np.ndarray, symmetric: bool, block: int = 1) -> np.ndarray:
    """(b, columns): height maps (b, n, m) with NaN as 0, averaged over ``block`` × ``block``
    pixels and flattened; ``symmetric``: only the top-left quadrant of each map's average over the
    180° turn and the two axis mirrors (the grid is centred on the disc and its axes are warp and
    weft), whose other quadrants mirror it. Raises SystemExit when ``block`` does not divide it."""
    h = np.nan_to_num(np.asarray(height, float))
    if symmetric:
        rows, cols = h.shape[-2] // 2, h.shape[-1] // 2
        h = ((h + h[:, :, ::-1] + h[:, ::-1, :] + h[:, ::-1, ::-1]) / 4)[:, :rows, :cols]
    b, rows, cols = h.shape
    if rows % block or cols % block:
        raise SystemExit(f"--height-pixels {block} does not divide the {rows} × {cols} height map")
    return h.reshape(b, rows // block, block, cols // block, block).mean(axis=(2, 4)).reshape(b, -1)


def ridge_model(height_pcs: int = 0, n_height: int = 0):
    """Standardised ridge (one penalty per target by leave-one-out) on the design matrix of
    ``features``; its last ``n_height`` columns (the height map) enter as ``height_pcs`` principal
    components, fitted on the training rows only."""
    ridge = make_pipeline(StandardScaler(), RidgeCV(alphas=np.logspace(-3, 3, 13), alpha_per_target=True))
    if not height_pcs:
        return ridge
    columns = ColumnTransformer([("descriptor", "passthrough", slice(None, -n_height)),
                                 ("height", PCA(height_pcs, random_state=0), slice(-n_height, None))])
    return make_pipeline(columns, ridge)


PIXEL_WEIGHTS = (0.1, 0.3, 1.0)
"""Weights of the standardised height pixels against the descriptor, chosen from by ``pixel_model``."""


def _weighted(z: np.ndarray, weight: float) -> np.ndarray:
    return z * weight


def overall_r2(y: np.ndarray, pred: np.ndarray) -> float:
    """R² of the overall stiffness (mean log k1/ρ over the three directions)."""
    return float(r2_score(y[:, K1_COLUMNS].mean(1), pred[:, K1_COLUMNS].mean(1)))


def pixel_model(n_height: int):
    """Standardised ridge (one penalty per target by leave-one-out) on the design matrix of
    ``features``, whose last ``n_height`` columns are height pixels, each standardised and all
    scaled by the one of ``PIXEL_WEIGHTS`` that scores best (``overall_r2``) over an inner 5-fold
    split of the training rows: the weight is fitted, not chosen on the rows it is scored on."""
    columns = ColumnTransformer([
        ("descriptor", StandardScaler(), slice(None, -n_height)),
        ("height", make_pipeline(StandardScaler(), FunctionTransformer(_weighted, kw_args={"weight": 1.0})),
         slice(-n_height, None))])
    ridge = make_pipeline(columns, RidgeCV(alphas=np.logspace(-3, 4, 15), alpha_per_target=True))
    grid = {"columntransformer__height__functiontransformer__kw_args": [{"weight": w} for w in PIXEL_WEIGHTS]}
    return GridSearchCV(ridge, grid, scoring=make_scorer(overall_r2), cv=KFold(5, shuffle=True, random_state=0))


def scores(y: np.ndarray, pred: np.ndarray) -> dict:
    out = {f"r2_{name}": float(r2_score(y[:, i], pred[:, i])) for i, name in enumerate(est.TARGET_NAMES)}
    out["r2_log_k1_mean_per_density"] = overall_r2(y, pred)
    return out


def by_fifth(y: np.ndarray, pred: np.ndarray) -> dict:
    """RMSE and mean error of the overall stiffness (mean log k1/ρ) in fifths of its true value,
    soft to stiff: where in the prior the error sits."""
    t, p = y[:, K1_COLUMNS].mean(1), pred[:, K1_COLUMNS].mean(1)
    edges = np.quantile(t, np.linspace(0, 1, 6))
    fifth = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, 4)
    return {"log_k1_mean_fifth_edges": edges.tolist(),
            "rmse_log_k1_mean_by_fifth": [float(np.sqrt(np.mean((p - t)[fifth == i] ** 2))) for i in range(5)],
            "bias_log_k1_mean_by_fifth": [float(np.mean((p - t)[fifth == i])) for i in range(5)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", nargs="+", help="one or more dataset directories, pooled")
    ap.add_argument("--invariant", action="store_true", help="rotation-invariant features only")
    ap.add_argument("--stretch", action="store_true", help="add the true stretching inputs (the +S methods)")
    ap.add_argument("--height-pcs", type=int, default=0, metavar="N",
                    help="add N principal components of the height map (0: none)")
    ap.add_argument("--height-pixels", type=int, default=0, metavar="B",
                    help="add the height map's pixels averaged over B x B blocks (0: none)")
    ap.add_argument("--symmetric", action="store_true",
                    help="--height-pcs or --height-pixels of the height map averaged over the material's symmetries")
    ap.add_argument("--val-fraction", type=float, default=0.1, help="as train_inverse.py's data.val_fraction")
    ap.add_argument("--split-seed", type=int, default=0, help="as train_inverse.py's data.seed")
    ap.add_argument("--redrop", type=int, default=0, metavar="M",
                    help="fresh members dropped with three seeds each, for the fold-noise share (0: none)")
    ap.add_argument("--simulate", default=None, metavar="MODULE:FUNCTION",
                    help="simulate of the --redrop drops when dataset.json records none "
                         "(default drapejax.inverse.dataset:quick_simulate)")
    ap.add_argument("--test", default=None, metavar="DATASET2", help="score the ridge trained on DATASET here")
    ap.add_argument("--checkpoint", action="append", default=[], metavar="MODEL.eqx",
                    help="a 3DH checkpoint to score on --test's drapes (repeatable)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    if a.checkpoint and not a.test:
        ap.error("--checkpoint needs --test")
    if a.height_pcs and a.height_pixels:
        ap.error("give --height-pcs or --height-pixels, not both")
    if a.symmetric and not (a.height_pcs or a.height_pixels):
        ap.error("--symmetric needs --height-pcs or --height-pixels")
    data, cfg = pooled(a.dataset)
    recorded = cfg.get("simulate")
    if recorded and a.simulate and a.simulate != recorded:
        ap.error(f"--simulate {a.simulate}: the dataset was made with {recorded} (dataset.json)")
    simulate = recorded or a.simulate or "drapejax.inverse.dataset:quick_simulate"
    design = functools.partial(features, invariant=a.invariant, stretch=a.stretch, height_pcs=a.height_pcs,
                               symmetric=a.symmetric, height_pixels=a.height_pixels)
    x, y = design(data), est.targets_from_params(data["params"])
    n_height = (height_columns(data["height"][:1], a.symmetric, max(a.height_pixels, 1)).shape[1]
                if a.height_pcs or a.height_pixels else 0)
    new_model = (functools.partial(pixel_model, n_height) if a.height_pixels
                 else functools.partial(ridge_model, a.height_pcs, n_height))
    n = len(y)
    val, train = split(n, a.val_fraction, a.split_seed)
    n_val = len(val)
    common = {"dataset": [str(Path(d).resolve()) for d in a.dataset],
              "features": x.shape[1] - (0 if a.height_pixels else n_height - a.height_pcs),
              "invariant": a.invariant, "stretch": a.stretch, "height_pcs": a.height_pcs,
              "height_pixels": a.height_pixels, "symmetric": a.symmetric}
    pred = new_model().fit(x[train], y[train]).predict(x[val])
    emit({**common, "evaluation": "train_inverse split", "n_train": len(train), "n_val": n_val,
          **scores(y[val], pred)}, a.out)
    pred = cross_val_predict(new_model(), x, y, cv=KFold(10, shuffle=True, random_state=a.split_seed))
    emit({**common, "evaluation": "10-fold", "n": n, **scores(y, pred), **by_fifth(y, pred)}, a.out)
    full = new_model().fit(x, y) if a.test or a.redrop else None
    if a.test:
        test = load_dataset(a.test, None, repeats=True)
        yt = est.targets_from_params(test["params"])
        pred = full.predict(design(test))
        emit({**common, "evaluation": "transfer", "test": str(Path(a.test).resolve()), "n_train": n,
              "n_test": len(yt), **scores(yt, pred), **by_fifth(yt, pred)}, a.out)
        drops = drops_per_member(a.test)
        if drops > 1:
            emit({**common, "evaluation": f"transfer, mean of {drops} drops", "test": str(Path(a.test).resolve()),
                  "n_train": n, **drop_means(test["index"] // drops, drops, yt, pred)}, a.out)
        for path in a.checkpoint:
            emit({"checkpoint": str(Path(path).resolve()), "evaluation": "transfer",
                  "test": str(Path(a.test).resolve()), "n_test": len(yt), **checkpoint_scores(path, test, yt)}, a.out)
    if a.redrop:
        emit({**common, "evaluation": "drop-seed noise", **seed_noise(full, design, y, cfg, a.redrop, simulate)}, a.out)


def drop_means(member: np.ndarray, drops: int, y: np.ndarray, pred: np.ndarray) -> dict:
    """Scores of the mean prediction over each member's ``drops`` drops, on the members whose
    drops all came to rest, beside the single drops' scores on the same members, and the
    between-drop variance of the predictions over the targets' variance (the fold pattern's share)."""
    ids, counts = np.unique(member, return_counts=True)
    whole = np.isin(member, ids[counts == drops])
    order = np.argsort(member[whole], kind="stable")
    y_m = y[whole][order].reshape(-1, drops, y.shape[1])
    p_m = pred[whole][order].reshape(-1, drops, y.shape[1])
    mean_k1, true_k1 = p_m[:, :, K1_COLUMNS].mean(2), y_m[:, 0][:, K1_COLUMNS].mean(1)
    return {"members": len(y_m), "drops": drops,
            "single_drop": {**scores(y_m.reshape(-1, y.shape[1]), p_m.reshape(-1, y.shape[1])),
                            "rmse_log_k1_mean_per_density": float(np.sqrt(np.mean((mean_k1 - true_k1[:, None]) ** 2)))},
            **scores(y_m[:, 0], p_m.mean(1)), **by_fifth(y_m[:, 0], p_m.mean(1)),
            "rmse_log_k1_mean_per_density": float(np.sqrt(np.mean((mean_k1.mean(1) - true_k1) ** 2))),
            **drop_variance_shares(p_m, y_m[:, 0], "drop_var_over_var")}


def drop_variance_shares(pred: np.ndarray, y: np.ndarray, prefix: str) -> dict:
    """Variance between the drops of one member of predictions ``pred`` (members, drops, targets),
    averaged over members, / the variance of targets ``y`` (n, targets): per log k1/ρ direction
    and for the overall stiffness, as ``{prefix}_{target}``."""
    out = {f"{prefix}_{est.TARGET_NAMES[i]}": float(pred[:, :, i].var(1, ddof=1).mean() / y[:, i].var())
           for i in K1_COLUMNS}
    out[f"{prefix}_log_k1_mean_per_density"] = float(pred[:, :, K1_COLUMNS].mean(2).var(1, ddof=1).mean()
                                                     / y[:, K1_COLUMNS].mean(1).var())
    return out


def checkpoint_scores(path: str, data: dict, y: np.ndarray) -> dict:
    """Scores of a 3DH checkpoint on a dataset's drapes (material frame), clipped to its training range."""
    model = est.InverseModel.load(path)
    if model.method != "3dh":
        raise SystemExit(f"--checkpoint {path}: method {model.method!r}, expected '3dh'")
    x = harmonic_features(data, model.meta)
    pred, _ = model.clip_to_training_range(model.predict_targets(x))
    return {**scores(y, pred), **by_fifth(y, pred)}


def seed_noise(model, design, y: np.ndarray, cfg: dict, members: int, simulate: str, seeds: int = 3) -> dict:
    """Between-seed variance of ``model``'s predictions (on ``design(observations)``) over fresh
    members dropped by ``simulate`` (``"module:function"``) on the mesh of the dataset whose
    ``dataset.json`` is ``cfg``, / the variance of targets ``y``."""
    import jax
    import jax.numpy as jnp

    from drapejax.inverse.dataset import import_callable, named_observer, params_matrix
    from drapejax.inverse.prior import default_prior
    from drapejax.mesh import cusick_mesh

    jax.config.update("jax_enable_x64", True)
    mesh = cusick_mesh(cfg["mesh_spacing_m"], rim_spacing_m=cfg.get("mesh_rim_spacing_m"))
    faces = np.asarray(mesh.faces)
    params = default_prior().sample_indices(np.arange(5000, 5000 + members), 0)
    batch = jax.tree.map(lambda v: jnp.repeat(jnp.asarray(v), seeds, 0), params)
    res = import_callable(simulate)(mesh, batch, np.arange(members * seeds) + 777)
    x, status = np.asarray(res.x), np.asarray(res.status)
    obs = {name: np.stack([named_observer(name)(v, faces) for v in x]) for name in ("boundary", "height")}
    obs["params"] = params_matrix(batch)
    at_rest = (status.reshape(members, seeds) == 0).all(1)
    pred = model.predict(design(obs)).reshape(members, seeds, -1)[at_rest]
    return {"simulate": simulate, "members": int(at_rest.sum()), "seeds": seeds,
            **drop_variance_shares(pred, y, "seed_var_over_var")}


if __name__ == "__main__":
    main()
