"""The ``drapejax`` command line: parses arguments and calls the library, nothing more."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path


def _x64():
    """float64 (the solver needs it) and JAX's persistent compilation cache, so that a second run
    of a command loads the programs the first compiled (``DRAPEJAX_CACHE_DIR``, default
    ``~/.cache/drapejax/jax``; set it to an empty string to turn the cache off)."""
    import jax

    from .compile_cache import enable

    jax.config.update("jax_enable_x64", True)
    enable()


_ASCII = {"µ": "u", "²": "^2", "³": "^3", "·": "*", "±": "+-", "ρ": "rho", "α": "alpha", "β": "beta",
          "Γ": "Gamma", "Δ": "d", "°": " deg"}


def _echo(text: str) -> None:
    """Print ``text`` on stdout; where stdout cannot encode its unit signs, spelled in ASCII."""
    try:
        print(text)
    except UnicodeEncodeError:
        print("".join(_ASCII.get(c, c) if ord(c) > 127 else c for c in text).encode("ascii", "replace").decode())


def _print(obj, as_json: bool, command: str | None = None):
    """One JSON object (``--json``), else ``drapejax.summary``'s short text for ``command``."""
    if as_json:
        print(json.dumps(obj, indent=2, default=float))
    else:
        from .summary import summarize

        _echo(summarize(command or "", obj))


@contextlib.contextmanager
def _stage(what: str):
    """``[drapejax] what...`` on stderr before a long step, and its elapsed seconds after it."""
    print(f"[drapejax] {what}...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        print(f"[drapejax] {what}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def simulate_to_folder(params, *, test: str, spacing_m: float, seed: int, out: Path, quick: bool = False,
                       warp_angle_deg: float = 0.0, n_px: int = 256, extent_m: float = 0.16,
                       rim_spacing_m: float | None = None, buckling: bool = False) -> dict:
    """Drape one specimen and write it as a measurement folder with truth.json.

    A Cusick drape runs on nested meshes (``mesh.cusick_hierarchy``: the dynamic drop on the
    coarsest, rim-graded level, a static solve on each finer one, ``solve.drape_multilevel``);
    ``spacing_m`` and ``rim_spacing_m`` name the finest level, and the coarsest is as coarse as
    the fabric's folds allow (``solve.coarsest_spacing_m``). A square specimen drops directly
    on its mesh. ``buckling`` caps the membrane's compression at the element scale
    (``energy.Membrane``)."""
    import jax
    import numpy as np

    from .energy import default_energies
    from .io import write_measurement
    from .mesh import cusick_hierarchy, hierarchy_rim_spacing, specimen_mesh
    from .observe import drape_coefficient, fold_count, height_map, rim_profile, silhouette
    from .solve import STATUS_NAMES, SolverConfig, coarsest_spacing_m, drape, drape_multilevel, quick_config

    config = quick_config() if quick else SolverConfig()
    terms = default_energies(test, buckling=buckling)
    t0 = time.perf_counter()
    if test == "cusick":
        meshes, prolongs = cusick_hierarchy(spacing_m, rim_spacing_m, warp_angle_deg=warp_angle_deg,
                                            coarsest_spacing_m=coarsest_spacing_m(params))
        multi = jax.jit(lambda p, s: drape_multilevel(meshes, prolongs, p, s, terms=terms,
                                                      coarse_config=config))(params, seed)
        res, mesh = multi.finest, meshes[-1]
        levels = multi.level_records(meshes)
        rim_spacing_m = hierarchy_rim_spacing(spacing_m, rim_spacing_m)
    else:
        mesh = specimen_mesh(test, spacing_m, warp_angle_deg=warp_angle_deg, rim_spacing_m=rim_spacing_m)
        res = jax.jit(lambda p, s: drape(mesh, p, s, terms=terms, config=config))(params, seed)
        levels = [{"spacing_m": spacing_m, "verts": int(mesh.n_verts), "newton_iters": int(res.newton_iters),
                   "status": STATUS_NAMES[int(res.status)]}]
    x = np.asarray(res.x)
    seconds = time.perf_counter() - t0
    faces = np.asarray(mesh.faces)
    sil = silhouette(x, faces, n=n_px, extent_m=extent_m)
    hgt = height_map(x, faces, n=n_px, extent_m=extent_m)
    hgt = np.where(sil > 0, hgt, np.nan).astype(np.float32)
    status = STATUS_NAMES[int(res.status)]
    truth = {"params": params.to_dict(), "effects": {},
             "mesh": {"test": test, "spacing_m": spacing_m, "rim_spacing_m": rim_spacing_m, "buckling": buckling,
                      "seed": seed, "verts": int(mesh.n_verts), "levels": levels,
                      "status": status, "steps": int(res.steps), "seconds": seconds}}
    write_measurement(out, test=test, specimen_radius_m=mesh.info.specimen_radius_m,
                      disk_radius_m=mesh.info.disk_radius_m, areal_density_kg_m2=float(params.density),
                      warp_angle_deg=warp_angle_deg, silhouette=sil, extent_m=extent_m, height=hgt,
                      scan=(x, faces), truth=truth, overwrite=True)
    dc = drape_coefficient(sil, extent_m, specimen_radius_m=mesh.info.specimen_radius_m,
                           disk_radius_m=mesh.info.disk_radius_m) if test == "cusick" else None
    folds = int(fold_count(rim_profile(sil, extent_m))) if test == "cusick" else None
    return {"out": str(out), "status": status, "steps": int(res.steps), "spacing_mm": round(spacing_m * 1e3, 2),
            "verts": int(mesh.n_verts),
            "dc": None if dc is None else round(float(dc), 4), "folds": folds, "levels": len(levels),
            "newton_iters": [lv["newton_iters"] for lv in levels],
            "seconds": round(seconds, 3)}


def _cmd_simulate(a):
    _x64()
    from .material import example_params, load_params

    from .solve import DEFAULT_FINEST_SPACING_M, finest_spacing_m

    params = load_params(a.params) if a.params else example_params(a.fabric)
    if a.spacing_mm is not None:
        spacing_m = a.spacing_mm / 1000.0
    else:  # a Cusick drape's finest level as fine as the fabric's folds need, a square's 5 mm
        spacing_m = finest_spacing_m(params) if a.test == "cusick" else DEFAULT_FINEST_SPACING_M
    info = simulate_to_folder(params, test=a.test, spacing_m=spacing_m, seed=a.seed, out=Path(a.out),
                              quick=a.quick, warp_angle_deg=a.warp_angle_deg,
                              rim_spacing_m=None if a.rim_mm is None else a.rim_mm / 1000.0, buckling=a.buckling)
    _print(info, a.json, "simulate")
    return 0 if info["status"] == "at_rest" else 1


def _floats(text: str, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None
    if not values:
        raise ValueError(f"{name} is empty")
    return values


def _cmd_validate(a):
    _x64()
    from .validate import validate_cantilever

    spacings = _floats(a.spacings_mm, "--spacings-mm")
    gammas = _floats(a.gammas, "--gammas")
    if min(spacings) <= 0 or min(gammas) <= 0:
        raise ValueError(f"--spacings-mm and --gammas must be positive, got {spacings} and {gammas}")
    angles = _floats(a.angles, "--angles")
    with _stage(f"validating {len(gammas) * len(angles) * len(spacings)} cantilever cases"):
        res = validate_cantilever(gammas, angles, tuple(s / 1000.0 for s in spacings), progress=True)
    _print(res, a.json, "validate")
    return 0 if res["passed"] else 1


def _cmd_bench(a):
    _x64()
    from .bench import parse_strategies, run_bench

    with _stage(f"benchmarking a Cusick drape on a {a.spacing_mm:g} mm mesh"):
        res = run_bench(spacing_m=a.spacing_mm / 1000.0, repeats=a.repeats, batch=a.batch,
                        newton=not a.no_newton, strategies=parse_strategies(a.strategies), process=not a.no_process)
    _print(res, a.json, "bench")
    return 0


def _cmd_inspect(a):
    from .observe import inspect

    _print(inspect(a.dir), a.json, "inspect")
    return 0


def _density(text: str) -> float | None:
    """``--density``: kg/m², or ``unknown`` (also ``none``, ``null``) for a fabric that was not weighed."""
    if text.strip().lower() in ("unknown", "none", "null"):
        return None
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--density {text}: expected the areal density in kg/m² (200 g/m² is 0.2) or "
                         f"'unknown'") from None


def _count(text: str) -> int:
    """A whole number ≥ 0 (argparse reports the option's name with the error)."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return n


def _cmd_measure(a):
    from .io import build_measurement

    center = None if a.marker_center_m is None else _floats(a.marker_center_m, "--marker-center-m")
    if center is not None and len(center) != 3:
        raise ValueError(f"--marker-center-m {a.marker_center_m}: expected x,y,z in m")
    with _stage("building the measurement folder"):
        res = build_measurement(a.out, areal_density_kg_m2=_density(a.density), test=a.test, photo=a.photo,
                                marker_side_m=a.marker_side_m, marker_id=a.marker_id,
                                marker_dictionary=a.marker_dictionary, marker_center_m=center, scan=a.scan,
                                scan_unit=a.scan_unit, silhouette=a.silhouette, height=a.height,
                                extent_m=a.extent_m, warp_angle_deg=a.warp_angle_deg,
                                specimen_radius_m=a.specimen_radius_m, disk_radius_m=a.disk_radius_m,
                                bench=a.bench, overwrite=a.overwrite)
    _print(res, a.json, "measure")
    return 0


EXPORT_TARGETS = ["clo", "style3d", "browzwear", "marvelous", "kes", "fast"]
"""``drapejax.export.TARGETS`` (listed here so that building the parser imports nothing heavy)."""

JSON_HELP = "print the whole result as one JSON object on stdout instead of the short summary"
SPACING_HELP = "fit mesh spacing, mm (the fitted k1 depend on it: the coarse default is fast, not mesh-converged)"
RIM_HELP = "fit mesh spacing on the disc edge, graded up to --spacing-mm (equal to it: a uniform mesh)"
BUCKLING_HELP = ("cap the membrane's compression at the Euler load of the element-scale fold (drapejax.energy."
                 "Membrane), so that soft fabrics fold on coarse meshes instead of locking")
SOLVER_HELP = ("the fit's solver (drapejax.refine.SOLVERS): exact Newton (every rest state at equilibrium, 4-7x "
               "faster; the virtual lab's) or the projected-Newton continuation (refine.fit's default)")


def _cmd_estimate(a):
    _x64()
    if a.to is not None:
        from .io import load_measurement

        for d in a.dir:  # before the (minutes-long) estimate: an export needs absolute values
            if load_measurement(d).areal_density_kg_m2 is None:
                print(f"drapejax estimate: error: {d}: no areal_density_kg_m2, so the estimate is density-normalised "
                      f"(k/rho) and --to {a.to} needs absolute values; estimate without --to, then run "
                      f"'drapejax export ESTIMATE.json --to {a.to} --density-gsm G'", file=sys.stderr)
                return 2
    if a.no_refine:
        from .inverse.estimate import InverseModel
        from .io import load_measurement

        ms = [load_measurement(d) for d in a.dir]
        checkpoints = [InverseModel.amortised_checkpoint_for(m) for m in ms]
        for d, c in zip(a.dir[1:], checkpoints[1:]):
            if c != checkpoints[0]:
                print(f"drapejax estimate: error: {d}: read by {c.name}, but {a.dir[0]} by {checkpoints[0].name} "
                      f"(a scan mesh or a recorded warp angle in one and not the other); estimate them apart",
                      file=sys.stderr)
                return 2
        model = InverseModel.load(checkpoints[0])
        out = (model.estimate_no_refine(ms[0], mesh_bias=not a.no_mesh_bias) if len(ms) == 1
               else model.estimate_specimens(ms, mesh_bias=not a.no_mesh_bias))
    elif len(a.dir) > 1:
        print("drapejax estimate: error: several folders (specimens of one fabric) need --no-refine; "
              "the refinement fits one measurement", file=sys.stderr)
        return 2
    else:
        from .refine import SOLVERS, estimate

        with _stage("estimating the fabric: network start, then the fit through the simulator (minutes)"):
            out = estimate(a.dir[0], spacing_m=a.spacing_mm / 1000.0, rim_spacing_m=a.rim_mm / 1000.0, seed=a.seed,
                           config=SOLVERS[a.solver], buckling=a.buckling,
                           converged_spacing_m=None if a.converged_mm is None else a.converged_mm / 1000.0,
                           mesh_bias=not a.no_mesh_bias)
    if a.to is not None:
        from .export import export_params

        out["export"] = export_params(out["params"], a.to)
    _print(out, a.json, "estimate")  # the summary ends with the export table when there is one
    return 0


def _cmd_export(a):
    _x64()
    from .export import export_params, format_export, parse_params_file
    from .files import write_text_atomic

    density = None if a.density_gsm is None else a.density_gsm / 1000.0
    result = export_params(parse_params_file(a.params, density_kg_m2=density), a.to)
    if a.out:
        write_text_atomic(a.out, json.dumps(result, indent=2) + "\n")
    if a.json:
        _print(result, True)
    else:
        _echo(format_export(result))
        if a.out:
            print(f"wrote {a.out}")
    return 0


def _package_version() -> str:
    try:
        return version("drapejax")
    except PackageNotFoundError:  # a source tree that was never installed
        from . import __version__

        return __version__


def _cmd_diagnose(a):
    _x64()
    from .diagnose import MembraneScan, Rescale, Screen, diagnose
    from .refine import SOLVERS

    with _stage(f"diagnosing {len(a.dirs)} capture(s): fit, residuals, effect search, refit (minutes)"):
        out = diagnose([Path(d) for d in a.dirs], report=Path(a.report) if a.report else None,
                       spacing_m=a.spacing_mm / 1000.0, rim_spacing_m=a.rim_mm / 1000.0, seed=a.seed,
                       screen=None if a.no_screen else Screen() if a.k_widen is None else Screen(k_widen=a.k_widen),
                       rescale=None if a.no_rescale else Rescale(),
                       membrane=MembraneScan() if a.membrane_scan else None, config=SOLVERS[a.solver],
                       buckling=a.buckling)
    _print(out, a.json, "diagnose")
    return 0


def _cmd_demo(a):
    _x64()
    from .diagnose import demo

    minutes = "12-20 minutes" if a.full else "about 3 minutes"
    with _stage(f"demo: virtual-lab captures with a hidden effect -> estimate -> diagnose -> report ({minutes})"):
        out = demo(Path(a.out), full=a.full)
    _print(out, a.json, "demo")
    return 0


DATASET_JSON_HELP = ("  --json                accepted as by the other commands: stdout is always the\n"
                     "                        generator's one-line JSON summary (scripts read it);\n"
                     "                        a short summary goes to stderr")


def _dataset(argv) -> int:
    """``drapejax dataset ...``: the dataset generator's own command line (options passed through).

    Its stdout is the generator's one-line JSON summary with or without ``--json`` (scripts and the
    multi-process tests read its last line); stage lines and a readable summary go to stderr."""
    from .inverse.dataset import DatasetError
    from .inverse.dataset import main as dataset_main

    argv = [x for x in argv if x != "--json"]
    if "-h" in argv or "--help" in argv:
        try:
            dataset_main(argv, prog="drapejax dataset")
        finally:
            print(DATASET_JSON_HELP)
        return 0
    buf = io.StringIO()
    try:
        with _stage("generating the dataset's shards"), contextlib.redirect_stdout(buf):
            dataset_main(argv, prog="drapejax dataset")
    except DatasetError as e:
        sys.stdout.write(buf.getvalue())
        print(f"drapejax dataset: error: {e}", file=sys.stderr)
        return 2
    except BaseException:
        sys.stdout.write(buf.getvalue())
        raise
    text = buf.getvalue()
    sys.stdout.write(text)
    sys.stdout.flush()
    try:
        from .summary import dataset as dataset_summary

        print(dataset_summary(json.loads(text.strip().splitlines()[-1])), file=sys.stderr)
    except (ValueError, IndexError, TypeError):
        pass
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="drapejax", description=__doc__)
    ap.add_argument("--version", action="version", version=f"%(prog)s {_package_version()}",
                    help="print the installed drapejax version and exit")
    sub = ap.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("simulate", help="drape a specimen and write a measurement folder (+ truth.json)")
    s.add_argument("--params", help="parameter JSON (flat SI schema); default: an embedded example fabric")
    s.add_argument("--fabric", default="mid", choices=["light", "mid", "heavy"], help="embedded example fabric")
    s.add_argument("--test", default="cusick", choices=["cusick", "square"],
                   help="drape test: the Cusick drape (circular specimen on a disc) or a square specimen")
    s.add_argument("--spacing-mm", type=float, default=None, help="mesh edge length of the finest level, mm "
                   "(default 5; Cusick: finer for a light, soft fabric whose folds a 5 mm mesh would lock, down to "
                   "3.4 mm across the 618-fabric table. The drape drops on a coarser nested level, up to 20 mm or "
                   "0.75 bending lengths, and is solved again on each finer one)")
    s.add_argument("--rim-mm", type=float, default=None, help="Cusick: the finest level's spacing on the disc "
                   "edge, graded up to --spacing-mm (default: a fifth of --spacing-mm)")
    s.add_argument("--seed", type=int, default=0, help="drop seed (the fold pattern depends on it)")
    s.add_argument("--warp-angle-deg", type=float, default=0.0,
                   help="angle of the warp direction to the image x axis, degrees")
    s.add_argument("--quick", action="store_true", help="short drop then static solve (faster)")
    s.add_argument("--buckling", action="store_true", help=BUCKLING_HELP)
    s.add_argument("--out", required=True, help="measurement folder to write (replaced if it exists)")
    s.add_argument("--json", action="store_true", help=JSON_HELP)
    s.set_defaults(fn=_cmd_simulate)

    v = sub.add_parser("validate", help="physics validation against reference curves (exit status 1 when a "
                       "case misses the 4 %% tolerance or does not converge)")
    v.add_argument("what", choices=["cantilever"],
                   help="the check: cantilever strips against the heavy-elastica master curve")
    v.add_argument("--gammas", default="0.1,1,10,100", help="gravito-bending numbers Γ, comma-separated")
    v.add_argument("--angles", default="0,30,45,90", help="cut angles to the warp, degrees, comma-separated")
    v.add_argument("--spacings-mm", default="3.5,2.5,1.75", help="mesh spacings, mm, comma-separated")
    v.add_argument("--json", action="store_true", help=JSON_HELP)
    v.set_defaults(fn=_cmd_validate)

    b = sub.add_parser("bench", help="speed/memory benchmark of a Cusick drape (JSON)")
    b.add_argument("--spacing-mm", type=float, default=5.0, help="mesh edge length, mm")
    b.add_argument("--repeats", type=int, default=3, help="timed runs per measurement (the median is reported)")
    b.add_argument("--batch", type=int, default=16, help="members of the batched runs (vmap, map, loop peer)")
    b.add_argument("--strategies", default="vmap,map",
                   help="comma-separated batch strategies to time besides the device's default")
    b.add_argument("--no-newton", action="store_true", help="skip the Newton peer (its fields are then null)")
    b.add_argument("--no-process", action="store_true",
                   help="skip timing two whole `drapejax simulate` processes (simulate_process_s is then null)")
    b.add_argument("--json", action="store_true", help=JSON_HELP)
    b.set_defaults(fn=_cmd_bench)

    i = sub.add_parser("inspect", help="load a measurement folder and print its drape descriptors")
    i.add_argument("dir", help="measurement folder (measurement.json with a silhouette, height map, scan or photo)")
    i.add_argument("--json", action="store_true", help=JSON_HELP)
    i.set_defaults(fn=_cmd_inspect)

    ms = sub.add_parser("measure", help="build a measurement folder from your files (photo, scan, silhouette, "
                        "height map; density, warp angle), check that it loads and print its drape descriptors")
    ms.add_argument("--out", required=True, metavar="DIR", help="measurement folder to create (staged beside "
                    "it and moved into place once it loads: a failure leaves nothing)")
    ms.add_argument("--test", default="cusick", choices=["cusick", "square"],
                    help="drape test: the Cusick drape (circular specimen on a disc) or a square specimen")
    ms.add_argument("--density", required=True, metavar="KG_M2", help="areal density, kg/m^2 (200 g/m^2 is 0.2), "
                    "or 'unknown' when not weighed (estimates are then density-normalised, k/rho)")
    ms.add_argument("--warp-angle-deg", type=float, default=None, metavar="DEG", help="angle from the "
                    "image/scan +x axis to the warp, counter-clockwise, degrees (default: not recorded, an unknown "
                    "of the estimate)")
    ms.add_argument("--specimen-radius-m", type=float, default=None, metavar="M",
                    help="specimen radius (square test: half side), m (default 0.15: the 30 cm specimen)")
    ms.add_argument("--disk-radius-m", type=float, default=None, metavar="M",
                    help="support disc radius, m (default 0.09: the 18 cm disc)")
    ms.add_argument("--photo", metavar="IMG", help="top-view photo of the drape on a green or red background with "
                    "an ArUco marker flat on the top clamp, edges along warp and weft (needs --marker-side-m)")
    ms.add_argument("--marker-side-m", type=float, default=None, metavar="M",
                    help="side of the marker's black square, m (a 4 cm marker is 0.04); sets the photo's scale")
    ms.add_argument("--marker-id", type=int, default=None, metavar="N",
                    help="the marker's id in its dictionary (default 0)")
    ms.add_argument("--marker-dictionary", default=None, metavar="NAME",
                    help="the marker's cv2.aruco dictionary (default DICT_4X4_50)")
    ms.add_argument("--marker-center-m", default=None, metavar="X,Y,Z", help="marker centre in the world frame, m: "
                    "origin at the disc centre, z up from the disc top (default 0,0,0.002)")
    ms.add_argument("--scan", metavar="MESH", help="scan of the draped specimen in the world frame (metres, z up, "
                    "origin at the disc top's centre): a mesh or point cloud, .ply .obj .stl .off or .xyz; its "
                    "silhouette and height map are rendered unless --silhouette or --height is given")
    ms.add_argument("--scan-unit", default="m", choices=["m", "cm", "mm"],
                    help="length unit of the scan file (default m)")
    ms.add_argument("--silhouette", metavar="PNG", help="top-view silhouette image on the format's grid: square, "
                    "fabric 255 else 0, image up +y (needs --extent-m)")
    ms.add_argument("--height", metavar="NPY", help="float .npy height map, m, on the silhouette's grid, NaN off "
                    "the fabric (needs --extent-m)")
    ms.add_argument("--extent-m", type=float, default=None, metavar="E", help="half width of the "
                    "silhouette/height grid, m: it covers x, y in [-E, E] (default for views rendered from --scan: "
                    "0.16)")
    ms.add_argument("--bench", metavar="JSON", help="bench readings on strips of the same fabric (cantilever tip "
                    "drops, KES pure bending moments, tensile forces): a JSON list, as under 'bench' in "
                    "docs/measurement-format.md")
    ms.add_argument("--overwrite", action="store_true", help="replace --out if it exists and is a measurement folder "
                    "(holds measurement.json; any other folder is refused)")
    ms.add_argument("--json", action="store_true", help=JSON_HELP)
    ms.set_defaults(fn=_cmd_measure)

    e = sub.add_parser("estimate", help="estimate fabric parameters from a measurement folder")
    e.add_argument("dir", nargs="+", help="a measurement folder; with --no-refine also several, specimens of "
                   "one fabric, read as one estimate (the mean of theirs, which averages out the fold pattern)")
    e.add_argument("--no-refine", action="store_true",
                   help="amortised estimate only (for a scan mesh the packaged 3DH model trained on capped-membrane "
                   "drapes, the closest to converged drapes; else the 2DS network)")
    e.add_argument("--spacing-mm", type=float, default=20.0, help=SPACING_HELP)
    e.add_argument("--rim-mm", type=float, default=3.0, help=RIM_HELP)
    e.add_argument("--seed", type=int, default=0, help="drop seed of the fit's simulated drapes")
    e.add_argument("--converged-mm", type=float, default=None, metavar="MM",
                   help="after the fit on the fit mesh, go on fitting on nested Cusick meshes down to MM (5: the "
                   "default resolution of 'drapejax simulate', whose drape is converged; a few minutes more)")
    e.add_argument("--no-mesh-bias", action="store_true",
                   help="report the fit mesh's (or, with --no-refine, the network's) own k1, not divided by its "
                   "stiffness bias against converged drapes (drapejax/data/mesh_bias.json): values to redraw on "
                   "that mesh rather than to type into a converged simulator")
    e.add_argument("--solver", choices=["exact", "continuation"], default="exact", help=SOLVER_HELP)
    e.add_argument("--buckling", action="store_true",
                   help=BUCKLING_HELP + "; the fit starts from the 3DH models trained with the cap (which "
                   "--no-refine always reads a scan with)")
    e.add_argument("--to", choices=EXPORT_TARGETS, default=None,
                   help="also give the estimate in this tool's fields and units (JSON key 'export'; see "
                   "'drapejax export'); needs the measurement's areal density")
    e.add_argument("--json", action="store_true", help=JSON_HELP)
    e.set_defaults(fn=_cmd_estimate)

    x = sub.add_parser("export", help="parameters in the field names and units of CLO3D, Style3D, Browzwear, "
                       "Marvelous Designer, KES-F or FAST")
    x.add_argument("params", help="parameter JSON: the flat SI schema, or the output of 'drapejax estimate --json' "
                   "(parameters under 'params')")
    x.add_argument("--to", required=True, choices=EXPORT_TARGETS,
                   help="target tool: clo (CLO3D), style3d (Newton's SolverStyle3D), browzwear (VStitcher), "
                   "marvelous (Marvelous Designer), kes (KES-F), fast (SiroFAST)")
    x.add_argument("--density-gsm", type=float, default=None,
                   help="areal density, g/m^2, for a density-normalised estimate (k/rho keys, from a measurement "
                   "without a density); the tools need absolute values")
    x.add_argument("--out", help="also write the export as JSON to this file (atomically: never half-written)")
    x.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    x.set_defaults(fn=_cmd_export)

    d = sub.add_parser("diagnose", help="fit, analyse residuals, search missing effects, refit, report")
    d.add_argument("dirs", nargs="+", help="measurement folders, captures of one specimen: the first is fitted, "
                   "the others are held-out evidence and give the capture-to-capture noise floor")
    d.add_argument("--report", help="output folder or .html path for the report")
    d.add_argument("--spacing-mm", type=float, default=20.0, help=SPACING_HELP)
    d.add_argument("--rim-mm", type=float, default=3.0, help=RIM_HELP)
    d.add_argument("--seed", type=int, default=0, help="drop seed of the fit's simulated drapes")
    d.add_argument("--no-screen", action="store_true",
                   help="refit candidates only by continuation from the baseline (no fresh-drop screen; faster)")
    d.add_argument("--no-rescale", action="store_true",
                   help="keep the baseline fit as it is (no scan of its overall k1 scale over fresh drops)")
    d.add_argument("--k-widen", type=_count, default=None, metavar="N",
                   help="let the screen try each candidate (and the current model) up to N k1 factors beyond its grid "
                   "(0.71-2x the baseline) while its best drop is at the grid's edge: a baseline that took an offset "
                   "specimen for a fabric several times too stiff needs it (default 3; 0 keeps the grid)")
    d.add_argument("--membrane-scan", action="store_true",
                   help="when the baseline misses the noise floor, scan the overall scale of the membrane stiffness "
                   "it holds from the tag or the network over fresh drops (it can also stand in for a heavier hem)")
    d.add_argument("--solver", choices=["exact", "continuation"], default="exact", help=SOLVER_HELP)
    d.add_argument("--buckling", action="store_true", help=BUCKLING_HELP)
    d.add_argument("--json", action="store_true", help=JSON_HELP)
    d.set_defaults(fn=_cmd_diagnose)

    m = sub.add_parser("demo", help="virtual-lab measurement with a hidden effect -> estimate -> diagnose -> report")
    m.add_argument("--out", default="drapejax-demo", help="folder for the captures and report.html")
    m.add_argument("--full", action="store_true", help="search every candidate effect after the baseline's "
                   "rescale scan (12-20 minutes) instead of the hidden effect against its closest look-alike")
    m.add_argument("--json", action="store_true", help="print the whole result as one JSON object instead of "
                   "the summary")
    m.set_defaults(fn=_cmd_demo)
    # Listed for --help only: ``main`` hands ``drapejax dataset ...`` to the generator's own parser.
    sub.add_parser("dataset", add_help=False,
                   help="generate (or resume) a sharded synthetic drape dataset; 'drapejax dataset --help'")
    return ap


def main(argv=None) -> int:
    from .io import MeasurementError
    from .material import ParameterError

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["dataset"]:  # argparse cannot pass options through a subcommand untouched
        return _dataset(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        return args.fn(args)
    except (MeasurementError, ParameterError, FileNotFoundError, ValueError) as e:
        print(f"drapejax {args.cmd}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
