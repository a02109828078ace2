"""Fabric parameters in the field names and units of garment-simulation tools and fabric testers.

``export_params(params, "clo")`` turns drapejax's SI parameters (``drapejax.material``) into the
values a user types into a tool's fabric editor, or compares with a fabric-testing report. Every
number is a unit conversion from ``drapejax.units`` (or, for Style3D, the mapping of
``drapejax.bench.newton_peer``); a tool field with no documented counterpart is listed in
``not_exported`` with the reason, never filled with a guess.

Targets, their fields and where the units come from:

``clo`` — CLO3D (CLO Virtual Fashion) fabric Physical Property editor.
    Field names are the editor's (Stretch-Weft, Stretch-Warp, Shear (Right)/(Left),
    Bending-Weft, Bending-Warp, Bending-Bias (Right)/(Left), Density). Units: stretch and shear
    in g/s² (1e-3 N/m), bending in g·mm²/s² (1e-9 N·m), as CLO writes them to its USD export
    (``primvars:clo:stretchWarp``, ``bendingWarp``, ...) and as Epic Games' Unreal Engine 5
    Chaos Cloth USD importer (``ChaosClothAssetUSDImportNode``, 2024) reads them; the spec table
    of units-and-ranges.md gives the same factors. Density in g/m² (the editor's range is
    30–2100 g/m²). Bending-* ← the strip rigidities ``bend_k1_*``; Stretch-* ← the
    zero-strain stiffness ``stretch_alpha_*``. Shear ← ``stretch_alpha_bias``: Epic's importer
    puts CLO's shear in the bias slot of the anisotropic stretch stiffness, which is what
    ``stretch_alpha_bias`` is in drapejax (each bias direction's stiffness; the shear modulus
    is half of it). drapejax has one bias value, so Right and Left are equal.

``style3d`` — Style3D's cloth solver as published in NVIDIA Newton (``SolverStyle3D``).
    The mapping of ``drapejax.bench.newton_peer`` (benchmarks/README.md, "Material mapping"):
    ``density`` kg/m²; ``tri_aniso_ke = (alpha_warp, alpha_weft, alpha_bias / 2)`` N/m (the
    membrane energy ``ku/2 (|F_u|-1)² + kv/2 (|F_v|-1)² + ks/2 (F_u·F_v)²``, ks the shear
    modulus); ``edge_aniso_ke`` the uncalibrated pass-through
    ``(k1_warp, k1_weft, k1_bias - (k1_warp + k1_weft)/64)`` N·m. Style3D's discrete hinge
    energy makes that pass-through about 3.4 times stiffer than the strip rigidities on the
    benchmark meshes; the exact coefficients depend on the mesh (``bending_calibration``) and
    are not a property of the fabric alone, so they are not exported.

``browzwear`` — Browzwear VStitcher fabric Physics dialog (Browzwear, "Physics Reference",
    VStitcher 2022.1 and newer). Mass in g/m²; Stretch in N/m along Length (the grain line,
    warp) and Width (weft), defined as the force per width that would double a linear fabric's
    length, i.e. ``stretch_alpha``; Bend along Length and Width, which the reference labels
    "dynes per centimeter": the CGS bending rigidity per centimetre of width, dyn·cm²/cm
    = 1e-7 N·m. The reference's guidance (5 very low, 1000 high, leather in the 1000s) is
    0.5–100 µN·m in this reading, the 5%–95% range of the 618 measured fabrics
    (units-and-ranges.md). No unit for Shear was found in the reference, so it is not exported.

``marvelous`` — Marvelous Designer (CLO Virtual Fashion) fabric Physical Property editor.
    Density in g/m² is exported. Its stretch, shear and bending fields are sliders whose
    mapping to physical units is not published, so none of them is exported.

``kes`` — Kawabata Evaluation System for Fabrics (KES-F; Kawabata 1980, "The Standardization
    and Analysis of Hand Evaluation"). W in mg/cm² (1e-2 kg/m²); B-1 (warp), B-2 (weft) and
    their mean B in gf·cm²/cm (1 gf = 1e-3 kg × 9.80665 m/s²); G, the shear stiffness, in
    gf/(cm·degree) ← the drapejax shear modulus ``stretch_alpha_bias / 2`` (N/m per radian of
    shear angle) × π/180. KES-F's B is the slope of the moment–curvature loop between 0.5 and
    1.5 cm⁻¹; ``bend_k1`` is the slope at zero curvature, which it equals when ``bend_k2`` is 0.

``fast`` — SiroFAST (CSIRO; De Boos and Tester 1994, "SiroFAST — Fabric Assurance by Simple
    Testing"). W in g/m²; B-1 (warp), B-2 (weft) in µN·m, FAST-2's cantilever bending rigidity
    B = W c³ with c half the 41.5° overhang, which equals the heavy-elastica rigidity k1 to
    0.05% (units-and-ranges.md: Γ = 8.004); G in N/m = 123 / EB5, FAST-3's trellis shear
    rigidity, the bias tension 5 gf/cm over four times the bias strain, i.e. the shear modulus
    ``stretch_alpha_bias / 2``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .material import DEFAULTS, PARAM_KEYS, PER_DENSITY_SUFFIX, FabricParams, check, from_per_density
from .units import from_si

TARGETS: dict[str, str] = {
    "clo": "CLO3D",
    "style3d": "Style3D (NVIDIA Newton SolverStyle3D)",
    "browzwear": "Browzwear VStitcher",
    "marvelous": "Marvelous Designer",
    "kes": "Kawabata KES-F",
    "fast": "SiroFAST",
}
"""Export target -> the tool's name."""

_DIRS = ("warp", "weft", "bias")

_ESTIMATE_NOTE = ("in a `drapejax estimate` result the stretching parameters (stretch_alpha, stretch_beta) are "
                  "prior or tag values, not fitted to the drape")


def _field(name: str, value_si: float, unit: str, source: str) -> dict:
    return {"name": name, "value": float(from_si(value_si, unit)), "unit": unit, "from": source}


def _skip(parameter: str | None, reason: str, field: str | None = None) -> dict:
    entry = {"parameter": parameter, "reason": reason}
    if field is not None:
        entry["field"] = field
    return entry


def _zero_remark(p: dict, group: str) -> str:
    """" (all zero here: nothing is lost)" when every direction of ``group`` is 0."""
    return " (all zero here: nothing is lost)" if all(p[f"{group}_{d}"] == 0.0 for d in _DIRS) else ""


def _k2_skip(p: dict, tool: str, detail: str) -> dict:
    return _skip("bend_k2_warp, bend_k2_weft, bend_k2_bias",
                 f"{tool} has no field for the quadratic bending coefficient (moment k1 κ + k2 κ|κ|); "
                 f"{detail}" + _zero_remark(p, "bend_k2"))


def _beta_skip(p: dict, tool: str) -> dict:
    return _skip("stretch_beta_warp, stretch_beta_weft, stretch_beta_bias",
                 f"{tool}'s stretch stiffness is one linear value per direction; the exponential "
                 f"stiffening exponent has no counterpart" + _zero_remark(p, "stretch_beta"))


def _clo(p: dict) -> tuple[list, list, list]:
    fields = [
        _field("Stretch-Weft", p["stretch_alpha_weft"], "g/s^2", "stretch_alpha_weft"),
        _field("Stretch-Warp", p["stretch_alpha_warp"], "g/s^2", "stretch_alpha_warp"),
        _field("Shear (Right)", p["stretch_alpha_bias"], "g/s^2", "stretch_alpha_bias"),
        _field("Shear (Left)", p["stretch_alpha_bias"], "g/s^2", "stretch_alpha_bias"),
        _field("Bending-Weft", p["bend_k1_weft"], "g*mm^2/s^2", "bend_k1_weft"),
        _field("Bending-Warp", p["bend_k1_warp"], "g*mm^2/s^2", "bend_k1_warp"),
        _field("Bending-Bias (Right)", p["bend_k1_bias"], "g*mm^2/s^2", "bend_k1_bias"),
        _field("Bending-Bias (Left)", p["bend_k1_bias"], "g*mm^2/s^2", "bend_k1_bias"),
        _field("Density", p["density"], "g/m^2", "density"),
    ]
    skipped = [
        _k2_skip(p, "CLO3D", "its nonlinear bending (Buckling Ratio, Buckling Stiffness) switches to a "
                 "lower stiffness past a fold angle, and no published relation ties it to k2"),
        _beta_skip(p, "CLO3D"),
        _skip(None, "no drapejax counterpart (drapejax models no thickness, friction or damping)",
              "Thickness, Friction, Internal Damping, Buckling Ratio-*, Buckling Stiffness-*"),
    ]
    notes = [
        "units: stretch/shear g/s^2 = 1e-3 N/m, bending g*mm^2/s^2 = 1e-9 N*m (CLO's USD export, read by "
        "Epic Games' Unreal Engine 5 Chaos Cloth USD importer; units-and-ranges.md)",
        "Shear (Right/Left) = stretch_alpha_bias, the stiffness of each bias direction (Epic's importer puts "
        "CLO's shear in the bias slot of the stretch stiffness); the shear modulus is half of it",
        "drapejax has one bias value: Right and Left are equal",
    ]
    return fields, skipped, notes


def _style3d(p: dict) -> tuple[list, list, list]:
    fields = [
        _field("density", p["density"], "kg/m^2", "density"),
        _field("tri_aniso_ke[0]", p["stretch_alpha_warp"], "N/m", "stretch_alpha_warp"),
        _field("tri_aniso_ke[1]", p["stretch_alpha_weft"], "N/m", "stretch_alpha_weft"),
        _field("tri_aniso_ke[2]", 0.5 * p["stretch_alpha_bias"], "N/m", "stretch_alpha_bias / 2"),
        _field("edge_aniso_ke[0]", p["bend_k1_warp"], "N*m", "bend_k1_warp"),
        _field("edge_aniso_ke[1]", p["bend_k1_weft"], "N*m", "bend_k1_weft"),
    ]
    skipped = []
    k_bias = p["bend_k1_bias"] - (p["bend_k1_warp"] + p["bend_k1_weft"]) / 64.0
    if k_bias >= 0.0:
        fields.append(_field("edge_aniso_ke[2]", k_bias, "N*m", "bend_k1_bias - (bend_k1_warp + bend_k1_weft) / 64"))
    else:
        skipped.append(_skip("bend_k1_bias", f"the pass-through bias hinge coefficient k1_bias - (k1_warp + "
                             f"k1_weft)/64 = {k_bias:.4g} N*m is negative; Style3D's directional law cannot "
                             f"represent this fabric's bias rigidity", "edge_aniso_ke[2]"))
    skipped += [_k2_skip(p, "Style3D", "its hinge energy is quadratic in the bend angle"),
                _beta_skip(p, "Style3D")]
    notes = [
        "mapping of drapejax.bench.newton_peer (benchmarks/README.md, 'Material mapping'): Newton's SolverStyle3D "
        "add_cloth_mesh(density=, tri_aniso_ke=, edge_aniso_ke=), SI units",
        "edge_aniso_ke is the uncalibrated pass-through: on the benchmark meshes Style3D's hinge energy makes it "
        "about 3.4x stiffer than bend_k1; exact coefficients depend on the mesh (newton_peer.bending_calibration)",
    ]
    return fields, skipped, notes


def _browzwear(p: dict) -> tuple[list, list, list]:
    fields = [
        _field("Mass", p["density"], "g/m^2", "density"),
        _field("Bend (Length)", p["bend_k1_warp"], "dyn*cm^2/cm", "bend_k1_warp"),
        _field("Bend (Width)", p["bend_k1_weft"], "dyn*cm^2/cm", "bend_k1_weft"),
        _field("Stretch (Length)", p["stretch_alpha_warp"], "N/m", "stretch_alpha_warp"),
        _field("Stretch (Width)", p["stretch_alpha_weft"], "N/m", "stretch_alpha_weft"),
    ]
    skipped = [
        _skip("bend_k1_bias", "VStitcher's Bend has Length and Width values only"),
        _skip("stretch_alpha_bias", "no unit or definition of Shear was found in Browzwear's Physics Reference",
              "Shear"),
        _k2_skip(p, "VStitcher", "Bend is one linear rigidity per direction"),
        _beta_skip(p, "VStitcher"),
        _skip(None, "no drapejax counterpart", "Thickness, Friction"),
    ]
    notes = [
        "Length is the grain line (warp), Width the weft (Browzwear, Physics Reference, VStitcher 2022.1+)",
        "Bend: the reference's 'dynes per centimeter' is read as dyn*cm^2/cm (bending rigidity per cm of width) "
        "= 1e-7 N*m; its guidance 5 (very low) to 1000 (high) is then 0.5-100 uN*m, the 5%-95% range of the "
        "618 measured fabrics",
        "Stretch in N/m: force per width to double the length of a linear fabric, i.e. stretch_alpha",
    ]
    return fields, skipped, notes


def _marvelous(p: dict) -> tuple[list, list, list]:
    fields = [_field("Density", p["density"], "g/m^2", "density")]
    slider = "its editor value is a slider whose mapping to physical units Marvelous Designer does not publish"
    skipped = [
        _skip("stretch_alpha_warp, stretch_alpha_weft", slider, "Stretch-Warp, Stretch-Weft"),
        _skip("stretch_alpha_bias", slider, "Shear"),
        _skip("bend_k1_warp, bend_k1_weft, bend_k1_bias", slider, "Bending-Warp, Bending-Weft"),
        _k2_skip(p, "Marvelous Designer", "its Buckling Ratio/Stiffness are sliders as well"),
        _beta_skip(p, "Marvelous Designer"),
    ]
    notes = ["only the density has a documented physical unit (g/m^2) in Marvelous Designer's fabric editor"]
    return fields, skipped, notes


def _kes(p: dict) -> tuple[list, list, list]:
    fields = [
        _field("W", p["density"], "mg/cm^2", "density"),
        _field("B-1", p["bend_k1_warp"], "gf*cm^2/cm", "bend_k1_warp"),
        _field("B-2", p["bend_k1_weft"], "gf*cm^2/cm", "bend_k1_weft"),
        _field("B", 0.5 * (p["bend_k1_warp"] + p["bend_k1_weft"]), "gf*cm^2/cm",
               "(bend_k1_warp + bend_k1_weft) / 2"),
        _field("G", 0.5 * p["stretch_alpha_bias"], "gf/cm/deg", "stretch_alpha_bias / 2"),
    ]
    skipped = [
        _skip("bend_k1_bias", "KES-FB2 bends warp and weft specimens only"),
        _k2_skip(p, "KES-F", "B is one slope over curvatures 0.5-1.5 1/cm, beyond the 0.5 1/cm (50 1/m) "
                 "range where drapejax's k2 applies (material.KAPPA_RANGE)"),
        _skip("stretch_alpha_warp, stretch_alpha_weft, stretch_beta_warp, stretch_beta_weft, stretch_beta_bias",
              "KES-FB1 tensile values describe a load-unload cycle to 500 gf/cm with hysteresis; "
              "drapejax's elastic law near zero strain gives no such cycle", "LT, WT, RT, EMT"),
        _skip(None, "hysteresis: drapejax's bending and shear are elastic", "2HB, 2HG, 2HG5"),
    ]
    notes = [
        "1 gf = 9.80665e-3 N: B 1 gf*cm^2/cm = 9.80665e-5 N*m; G 1 gf/(cm*deg) = 0.980665 N/m per degree "
        "of shear angle; W 1 mg/cm^2 = 10 g/m^2 (Kawabata 1980)",
        "G = shear modulus stretch_alpha_bias / 2 (N/m per radian) x pi/180",
        "KES-F B is the slope between curvatures 0.5 and 1.5 1/cm; bend_k1 is the slope at zero curvature",
    ]
    return fields, skipped, notes


def _fast(p: dict) -> tuple[list, list, list]:
    fields = [
        _field("W", p["density"], "g/m^2", "density"),
        _field("B-1", p["bend_k1_warp"], "uN*m", "bend_k1_warp"),
        _field("B-2", p["bend_k1_weft"], "uN*m", "bend_k1_weft"),
        _field("G", 0.5 * p["stretch_alpha_bias"], "N/m", "stretch_alpha_bias / 2"),
    ]
    skipped = [
        _skip("bend_k1_bias", "FAST-2 bends warp and weft specimens only"),
        _k2_skip(p, "FAST", "FAST-2 gives one cantilever rigidity per direction"),
        _skip("stretch_alpha_warp, stretch_alpha_weft, stretch_beta_warp, stretch_beta_weft, stretch_beta_bias",
              "FAST-3 reports strains at fixed loads (5, 20, 100 gf/cm); getting them from stretch_alpha and "
              "stretch_beta means solving drapejax's tension law, a model prediction, not a unit conversion",
              "E5, E20, E100, EB5"),
        _skip(None, "needs E20 - E5 or thickness, which drapejax has no counterpart for", "F-1, F-2, T2, T100, ST"),
    ]
    notes = [
        "B = W c^3 (FAST-2, 41.5 deg cantilever) equals the heavy-elastica k1 to 0.05% (units-and-ranges.md)",
        "G = 123 / EB5 is the trellis shear modulus (bias tension over 4 x bias strain), i.e. stretch_alpha_bias / 2 "
        "(CSIRO SiroFAST, De Boos and Tester 1994)",
    ]
    return fields, skipped, notes


_EXPORTERS = {"clo": _clo, "style3d": _style3d, "browzwear": _browzwear, "marvelous": _marvelous, "kes": _kes,
              "fast": _fast}


def _per_density_keys(d: dict) -> list[str]:
    return sorted(k for k in d if isinstance(k, str) and k.endswith(PER_DENSITY_SUFFIX))


def _checked_dict(d: dict, source: str) -> dict:
    """The flat SI dict ``d`` with ``DEFAULTS`` filled in, checked by ``FabricParams.from_dict``.

    The values are ``d``'s own floats rather than a FabricParams' arrays, which would be rounded
    to float32 unless JAX runs in 64-bit mode."""
    FabricParams.from_dict(d, source=source)
    return {k: float(d[k]) if k in d else float(DEFAULTS[k]) for k in PARAM_KEYS}


def _as_dict(params: FabricParams | dict) -> dict:
    """The SI parameter dict of one fabric, checked by ``material.check``; ValueError otherwise."""
    if isinstance(params, FabricParams):
        if np.ndim(params.density) != 0:
            raise ValueError(f"export needs one fabric, got a batch of shape {np.shape(params.density)}")
        check(params, source="export")
        return params.to_dict()
    if isinstance(params, dict):
        if _per_density_keys(params):
            raise ValueError(f"density-normalised parameters ({', '.join(_per_density_keys(params)[:2])}, ...): "
                             f"the areal density is unknown, and every tool needs absolute values; give it "
                             f"(parse_params_file(..., density_kg_m2=...), drapejax export --density-gsm)")
        return _checked_dict(params, "export")
    raise ValueError(f"export needs a FabricParams or a parameter dict, got {type(params).__name__}")


def export_params(params: FabricParams | dict, target: str) -> dict:
    """Parameters of one fabric in the field names and units of ``target`` (one of ``TARGETS``).

    Args:
        params: a ``FabricParams`` (one fabric) or its flat SI dict (``FabricParams.to_dict``).
        target: ``clo``, ``style3d``, ``browzwear``, ``marvelous``, ``kes`` or ``fast``.

    Returns:
        ``{"target", "tool", "fields": [{"name", "value", "unit", "from"}], "not_exported":
        [{"parameter", "reason"[, "field"]}], "notes": [...]}``: ``fields`` in the tool's order and
        units (``unit`` is a ``drapejax.units`` name, so ``units.to_si(value, unit)`` gives the SI
        value back); ``not_exported`` names each drapejax parameter (or tool field, with
        ``parameter`` None) without a documented counterpart and why.

    Raises:
        ValueError: an unknown target, or parameters that are invalid or density-normalised.
    """
    if target not in TARGETS:
        raise ValueError(f"unknown export target {target!r}; choose from {sorted(TARGETS)}")
    p = _as_dict(params)
    fields, skipped, notes = _EXPORTERS[target](p)
    if any(f["from"].startswith("stretch") for f in fields):
        notes = notes + [_ESTIMATE_NOTE]
    return {"target": target, "tool": TARGETS[target], "fields": fields, "not_exported": skipped, "notes": notes}


def parse_params_file(path: str | os.PathLike, *, density_kg_m2: float | None = None) -> dict:
    """Read a parameter JSON: a flat FabricParams dict, or an object holding one under ``params``
    (what ``drapejax estimate --json`` prints, and ``truth.json``).

    Returns the flat SI dict of every ``PARAM_KEYS`` entry (``DEFAULTS`` filled in), checked as
    ``FabricParams.from_dict`` checks it; ``FabricParams.from_dict`` of it gives the pytree.

    A density-normalised estimate (``*_per_density`` keys, k/ρ, from a measurement without an
    areal density) becomes absolute with ``density_kg_m2``; without it, it is an error.

    Raises:
        ValueError: one message naming the file and the missing or invalid field.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: parameter file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: cannot read the parameter file ({e})") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON ({e.msg} at line {e.lineno})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected a JSON object of parameters, got {type(d).__name__}")
    if "params" in d:
        d = d["params"]
        if not isinstance(d, dict):
            raise ValueError(f"{path}: 'params' must be a JSON object of parameters, got {type(d).__name__}")
    per_density = _per_density_keys(d)
    if per_density:
        if density_kg_m2 is None:
            raise ValueError(f"{path}: density-normalised parameters ('{per_density[0]}', ...: the measurement had "
                             f"no areal density); give the areal density (drapejax export --density-gsm G) to "
                             f"export absolute values")
        rho = float(density_kg_m2)
        if not (np.isfinite(rho) and rho > 0.0):
            raise ValueError(f"{path}: the areal density must be positive, got {density_kg_m2!r} kg/m^2")
        d = from_per_density(d, rho, source=str(path))
    elif density_kg_m2 is not None:
        raise ValueError(f"{path}: holds absolute parameters ('density' included); an areal density is only "
                         f"given for a density-normalised estimate")
    missing = [k for k in ("density", "bend_k1_warp", "bend_k1_weft", "bend_k1_bias") if k not in d]
    if missing and not set(d) & set(PARAM_KEYS):
        raise ValueError(f"{path}: no drapejax parameters found (expected keys such as {list(PARAM_KEYS[:4])}, "
                         f"at the top level or under 'params')")
    return _checked_dict(d, str(path))


def format_export(result: dict) -> str:
    """``export_params``'s result as a short table (field, value, unit, from), then what was not exported
    and the notes."""
    rows = [(f["name"], f"{f['value']:.6g}", f["unit"], f["from"]) for f in result["fields"]]
    head = ("field", "value", "unit", "from")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(4)]
    lines = [f"{result['tool']} (--to {result['target']})"]
    for r in [head] + rows:
        lines.append("  " + "  ".join([r[0].ljust(widths[0]), r[1].rjust(widths[1]), r[2].ljust(widths[2]), r[3]]))
    if result["not_exported"]:
        lines.append("not exported:")
        for s in result["not_exported"]:
            what = s["parameter"] or s["field"]
            if s["parameter"] and s.get("field"):
                what += f" ({s['field']})"
            lines.append(f"  - {what}: {s['reason']}")
    if result["notes"]:
        lines.append("notes:")
        lines.extend(f"  - {n}" for n in result["notes"])
    return "\n".join(lines)


__all__ = ["TARGETS", "PER_DENSITY_SUFFIX", "export_params", "parse_params_file", "format_export"]
