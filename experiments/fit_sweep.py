"""One estimate per Hydra run, for sweeps over fit settings and captures.

Each run estimates one measurement folder as ``drapejax estimate`` does (``drapejax.refine.estimate``:
the network's start, then the fit through the simulator on the fit mesh) with the run's fit
settings and prints one JSON line (capture, fit, its settings, status, the estimated parameters and
their stds as ``drapejax estimate --json`` reports them, how the fitted drape matches the capture,
warnings, seconds); ``results=FILE`` appends the line to a JSONL file as well. The configuration
group is ``configs/fit`` (default, no_refine, fine); see ``configs/fit_sweep.yaml``.

    python -m experiments.fit_sweep capture=../shared/data/real_cusick/bdp_f02_sample_2_capture_1
    python -m experiments.fit_sweep --multirun fit=default,no_refine capture=A,B results=$PWD/fits.jsonl
    python -m experiments.fit_sweep --multirun fit=default,fine fit.buckling=false,true capture=A
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig


def run(cfg: DictConfig, fit_name: str) -> dict:
    """Estimate the configured capture with the run's fit settings; the result line."""
    import jax

    from drapejax.refine import SOLVERS, estimate

    jax.config.update("jax_enable_x64", True)
    fit = cfg.fit
    capture = hydra.utils.to_absolute_path(cfg.capture)
    out = estimate(capture, refine=bool(fit.refine), spacing_m=fit.spacing_mm / 1e3,
                   rim_spacing_m=None if fit.rim_mm is None else fit.rim_mm / 1e3, seed=int(fit.seed),
                   max_steps=int(fit.max_steps), config=SOLVERS[fit.solver], buckling=bool(fit.buckling))
    return {"capture": capture, "fit": fit_name, "refine": bool(fit.refine), "spacing_mm": float(fit.spacing_mm),
            "rim_mm": fit.rim_mm, "solver": fit.solver, "buckling": bool(fit.buckling), "seed": int(fit.seed),
            "max_steps": int(fit.max_steps), "status": out["status"], "init": out["init"],
            "density_normalized": out["density_normalized"], "params": out["params"], "std": out["std"],
            "bending_length_mm": out["bending_length_mm"], **out["fit"],
            "within_floor": out["fit_quality"]["within_floor"], "warnings": out["warnings"],
            "seconds": out["seconds"]}


@hydra.main(version_base=None, config_path="../configs", config_name="fit_sweep")
def main(cfg: DictConfig) -> None:
    from .common import emit

    fit_name = hydra.core.hydra_config.HydraConfig.get().runtime.choices["fit"]
    emit(run(cfg, fit_name), Path(cfg.results) if cfg.results else None)


if __name__ == "__main__":
    main()
