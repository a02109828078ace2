"""10-fold cross-validation of the tag → stretching kNN (seed 001 Table 1) on a SYNTHETIC catalogue.

No real tag catalogue is available to drapejax, so the numbers describe the regression on
invented fabrics from ``synthetic_catalogue``, not its accuracy on real fabrics.

    python -m experiments.stretch_knn [--n 5000] [--k 50] [--folds 10] [--seed 0]
"""

import argparse
import json

import numpy as np

from drapejax.inverse.tags import StretchKNN, synthetic_catalogue


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--k", type=int, default=50)
    ap.add_argument("--folds", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    cat = synthetic_catalogue(a.n, seed=a.seed)
    folds = StretchKNN(k=a.k).cross_validate(cat, folds=a.folds, seed=a.seed)
    mean = {key: float(np.mean([f[key] for f in folds])) for key in ("train_r2", "val_r2", "constant_val_r2")}
    print(json.dumps({"data": cat.source, "n_fabrics": len(cat), "k": a.k, "folds": folds, "mean": mean},
                     indent=1))


if __name__ == "__main__":
    main()
