"""One drape per Hydra run, for sweeps over mesh, material, solver and seed.

Each run drapes one specimen as ``drapejax simulate`` does (``drapejax.cli.simulate_to_folder``:
the nested-mesh drape for a Cusick specimen), writes the measurement folder into the run's output
directory and prints one JSON line (fabric, mesh, status, drape coefficient, fold count, Newton
iterations per level, seconds); ``results=FILE`` appends the line to a JSONL file as well. The
configuration groups are ``configs/mesh`` (default, fine, fit), ``configs/material`` (light, mid,
heavy, table) and ``configs/solver`` (default, quick); see ``configs/drape.yaml``.

    python -m experiments.drape_sweep material=light seed=2
    python -m experiments.drape_sweep --multirun material=light,mid,heavy seed=0,1,2 results=$PWD/sweep.jsonl
    python -m experiments.drape_sweep --multirun mesh=default,fine material=table material.pick=q25,median
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
from omegaconf import DictConfig

from drapejax.material import FabricParams, example_params


def fabric(cfg: DictConfig) -> FabricParams:
    """The run's fabric: an embedded example or a row of the 618-fabric table, then scaled."""
    if cfg.source == "example":
        p = example_params(cfg.name)
    elif cfg.source == "table":
        from .common import TABLE, pick_fabrics

        p = pick_fabrics(TABLE, [cfg.pick])[cfg.pick][1]
    else:
        raise ValueError(f"material.source must be 'example' or 'table', got {cfg.source!r}")
    d = p.to_dict()
    for key in ("bend_k1_warp", "bend_k1_weft", "bend_k1_bias"):
        d[key] = d[key] * cfg.k1_scale
    d["density"] = d["density"] * cfg.density_scale
    return FabricParams.make(**d)


def run(cfg: DictConfig, out_dir: Path) -> dict:
    """Drape the configured specimen into ``out_dir / "measurement"``; the result line."""
    import jax

    from drapejax.cli import simulate_to_folder

    jax.config.update("jax_enable_x64", True)
    params = fabric(cfg.material)
    info = simulate_to_folder(params, test=cfg.mesh.test, spacing_m=cfg.mesh.spacing_mm / 1e3, seed=int(cfg.seed),
                              out=out_dir / "measurement", quick=bool(cfg.solver.quick),
                              warp_angle_deg=float(cfg.mesh.warp_angle_deg),
                              rim_spacing_m=None if cfg.mesh.rim_mm is None else cfg.mesh.rim_mm / 1e3,
                              buckling=bool(cfg.solver.buckling))
    material = cfg.material.name if cfg.material.source == "example" else f"table:{cfg.material.pick}"
    return {"material": material, "k1_scale": float(cfg.material.k1_scale),
            "density_scale": float(cfg.material.density_scale), "test": cfg.mesh.test,
            "spacing_mm": float(cfg.mesh.spacing_mm), "rim_mm": cfg.mesh.rim_mm, "quick": bool(cfg.solver.quick),
            "buckling": bool(cfg.solver.buckling), "seed": int(cfg.seed), **info}


@hydra.main(version_base=None, config_path="../configs", config_name="drape")
def main(cfg: DictConfig) -> None:
    out_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    line = json.dumps(run(cfg, out_dir))
    print(line, flush=True)
    if cfg.results:
        with open(cfg.results, "a") as f:
            f.write(line + "\n")


if __name__ == "__main__":
    main()
