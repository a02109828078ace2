"""`drapejax export`: parameters in the field names and units of CLO3D, Style3D, Browzwear,
Marvelous Designer, KES-F and FAST; hand-computed values, round trips, the command line."""

import json
import math
import sys
from pathlib import Path

import pytest

from drapejax import units
from drapejax.cli import main
from drapejax.export import TARGETS, export_params, format_export, parse_params_file
from drapejax.material import DEFAULTS, PARAM_KEYS, FabricParams

# A fabric with round numbers, so the expected values below can be worked out by hand.
FABRIC = {"density": 0.2, "bend_k1_warp": 5e-6, "bend_k1_weft": 4e-6, "bend_k1_bias": 4.5e-6,
          "bend_k2_warp": -1e-8, "stretch_alpha_warp": 600.0, "stretch_alpha_weft": 400.0,
          "stretch_alpha_bias": 80.0}
SI = {**DEFAULTS, **FABRIC}
GF_N = 9.80665e-3  # one gram-force in newtons (standard gravity)


def fields(target, params=FABRIC):
    return {f["name"]: f for f in export_params(params, target)["fields"]}


def skipped_parameters(target):
    return " | ".join(s["parameter"] or "" for s in export_params(FABRIC, target)["not_exported"])


def skipped_fields(target):
    return " | ".join(s.get("field", "") for s in export_params(FABRIC, target)["not_exported"])


def test_clo_values_by_hand():
    f = fields("clo")
    # 1 g*mm^2/s^2 = 1e-3 kg * 1e-6 m^2 / s^2 = 1e-9 N*m, so 5e-6 N*m is 5000 g*mm^2/s^2.
    assert f["Bending-Warp"]["value"] == pytest.approx(5000.0, rel=1e-12)
    assert f["Bending-Weft"]["value"] == pytest.approx(4000.0, rel=1e-12)
    assert f["Bending-Bias (Right)"]["value"] == f["Bending-Bias (Left)"]["value"] == pytest.approx(4500.0)
    # 1 g/s^2 = 1e-3 N/m.
    assert f["Stretch-Warp"]["value"] == pytest.approx(6e5) and f["Stretch-Weft"]["value"] == pytest.approx(4e5)
    assert f["Shear (Right)"]["value"] == f["Shear (Left)"]["value"] == pytest.approx(8e4)
    assert f["Density"]["value"] == pytest.approx(200.0) and f["Density"]["unit"] == "g/m^2"
    assert f["Bending-Warp"]["unit"] == "g*mm^2/s^2" and f["Shear (Left)"]["unit"] == "g/s^2"


def test_style3d_is_the_newton_peer_mapping():
    f = fields("style3d")
    assert f["density"]["value"] == pytest.approx(0.2) and f["density"]["unit"] == "kg/m^2"
    assert [f[f"tri_aniso_ke[{i}]"]["value"] for i in range(3)] == pytest.approx([600.0, 400.0, 40.0])
    assert [f[f"edge_aniso_ke[{i}]"]["value"] for i in range(3)] == pytest.approx(
        [5e-6, 4e-6, 4.5e-6 - 9e-6 / 64.0], rel=1e-12)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from newton_peer import style3d_material
    finally:
        sys.path.pop(0)
    peer = style3d_material(FabricParams.make(**FABRIC), None)
    assert [f[f"tri_aniso_ke[{i}]"]["value"] for i in range(3)] == pytest.approx(list(peer.tri_aniso_ke))
    assert [f[f"edge_aniso_ke[{i}]"]["value"] for i in range(3)] == pytest.approx(list(peer.edge_aniso_ke))


def test_style3d_negative_bias_hinge_is_not_exported():
    stiff_warp = {**FABRIC, "bend_k1_warp": 1e-4, "bend_k1_weft": 4e-6, "bend_k1_bias": 1.2e-6}
    out = export_params(stiff_warp, "style3d")
    assert "edge_aniso_ke[2]" not in {f["name"] for f in out["fields"]}
    assert any(s.get("field") == "edge_aniso_ke[2]" for s in out["not_exported"])


def test_browzwear_values_by_hand():
    f = fields("browzwear")
    # 1 dyn*cm^2/cm = 1e-5 N * 1e-4 m^2 / 1e-2 m = 1e-7 N*m.
    assert f["Bend (Length)"]["value"] == pytest.approx(50.0) and f["Bend (Width)"]["value"] == pytest.approx(40.0)
    assert f["Stretch (Length)"]["value"] == 600.0 and f["Stretch (Width)"]["value"] == 400.0
    assert f["Mass"]["value"] == pytest.approx(200.0)
    assert "bend_k1_bias" in skipped_parameters("browzwear") and "Shear" in skipped_fields("browzwear")


def test_marvelous_exports_only_the_density():
    f = fields("marvelous")
    assert list(f) == ["Density"] and f["Density"]["value"] == pytest.approx(200.0)
    skipped = skipped_parameters("marvelous")
    for key in ("bend_k1_warp", "stretch_alpha_warp", "stretch_alpha_bias", "bend_k2_warp", "stretch_beta_warp"):
        assert key in skipped


def test_kes_values_by_hand():
    f = fields("kes")
    # 1 gf*cm^2/cm = 9.80665e-3 N * 1e-4 m^2 / 1e-2 m = 9.80665e-5 N*m.
    assert f["B-1"]["value"] == pytest.approx(5e-6 / 9.80665e-5, rel=1e-12)
    assert f["B-2"]["value"] == pytest.approx(4e-6 / 9.80665e-5, rel=1e-12)
    assert f["B"]["value"] == pytest.approx(4.5e-6 / 9.80665e-5, rel=1e-12)
    assert f["B-1"]["value"] == pytest.approx(0.050986, rel=1e-4)
    # W: 0.2 kg/m^2 = 200 g/m^2 = 20 mg/cm^2.
    assert f["W"]["value"] == pytest.approx(20.0) and f["W"]["unit"] == "mg/cm^2"
    # G: shear modulus alpha_bias / 2 = 40 N/m per radian -> per degree, in gf/cm (0.980665 N/m).
    assert f["G"]["value"] == pytest.approx(40.0 * math.pi / 180.0 / (GF_N / 1e-2), rel=1e-12)
    assert f["G"]["value"] == pytest.approx(0.71190, rel=1e-4)
    assert "bend_k1_bias" in skipped_parameters("kes") and "2HB" in skipped_fields("kes")


def test_fast_values_by_hand():
    f = fields("fast")
    assert f["B-1"]["value"] == pytest.approx(5.0) and f["B-2"]["value"] == pytest.approx(4.0)
    assert f["B-1"]["unit"] == "uN*m"
    assert f["W"]["value"] == pytest.approx(200.0) and f["G"]["value"] == pytest.approx(40.0)
    assert f["G"]["unit"] == "N/m"
    assert "bend_k1_bias" in skipped_parameters("fast") and "E100" in skipped_fields("fast")


def _si_of(source: str) -> float:
    """SI value of a field's ``from`` expression (a key, or one of the documented combinations)."""
    derived = {
        "stretch_alpha_bias / 2": SI["stretch_alpha_bias"] / 2,
        "(bend_k1_warp + bend_k1_weft) / 2": (SI["bend_k1_warp"] + SI["bend_k1_weft"]) / 2,
        "bend_k1_bias - (bend_k1_warp + bend_k1_weft) / 64":
            SI["bend_k1_bias"] - (SI["bend_k1_warp"] + SI["bend_k1_weft"]) / 64,
    }
    return derived[source] if source in derived else SI[source]


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_every_field_converts_back_to_its_si_value(target):
    out = export_params(FABRIC, target)
    assert out["target"] == target and out["tool"] == TARGETS[target]
    assert out["fields"]
    for f in out["fields"]:
        assert isinstance(f["value"], float) and math.isfinite(f["value"])
        assert units.get_unit(f["unit"]).si in ("N*m", "N/m", "kg/m^2")
        assert units.to_si(f["value"], f["unit"]) == pytest.approx(_si_of(f["from"]), rel=1e-12), f


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_what_has_no_counterpart_is_listed(target):
    out = export_params(FABRIC, target)
    skipped = skipped_parameters(target)
    assert "bend_k2_warp" in skipped and "stretch_beta_warp" in skipped
    assert all(s["reason"] for s in out["not_exported"])
    exported = {f["from"] for f in out["fields"]}
    assert not any(src.startswith(("bend_k2", "stretch_beta")) for src in exported)
    # Every exported number is in the table, every omission in its list.
    text = format_export(out)
    for f in out["fields"]:
        assert f["name"] in text and f"{f['value']:.6g}" in text
    assert "not exported:" in text and "bend_k2_warp" in text


def test_zero_stiffening_is_said_to_lose_nothing():
    beta = next(s for s in export_params(FABRIC, "clo")["not_exported"] if "stretch_beta_warp" in s["parameter"])
    k2 = next(s for s in export_params(FABRIC, "clo")["not_exported"] if "bend_k2_warp" in (s["parameter"] or ""))
    assert "nothing is lost" in beta["reason"] and "nothing is lost" not in k2["reason"]


def test_fabric_params_and_dict_give_the_same_export():
    assert export_params(FabricParams.make(**FABRIC), "kes") == export_params(FABRIC, "kes")


def test_bad_inputs_raise_value_errors():
    with pytest.raises(ValueError, match="unknown export target 'optitex'"):
        export_params(FABRIC, "optitex")
    with pytest.raises(ValueError, match="bend_k1_warp"):
        export_params({**FABRIC, "bend_k1_warp": 13.8}, "clo")  # µN·m given as N·m
    with pytest.raises(ValueError, match="density-normalised"):
        export_params({"bend_k1_warp_per_density": 2.5e-5}, "clo")


def test_parse_params_file_reads_both_forms(tmp_path):
    flat = tmp_path / "p.json"
    flat.write_text(json.dumps(FABRIC))
    wrapped = tmp_path / "estimate.json"
    wrapped.write_text(json.dumps({"params": FABRIC, "density_normalized": False, "seconds": 1.0}))
    for path in (flat, wrapped):
        d = parse_params_file(path)
        assert set(d) == set(PARAM_KEYS) and d == SI


def test_parse_params_file_density_normalised(tmp_path):
    path = tmp_path / "est.json"
    # The k/ρ keys `drapejax estimate` reports without a density (stretch_beta is dimensionless).
    per = {f"{k}_per_density": v / FABRIC["density"] for k, v in FABRIC.items() if k != "density"}
    per["stretch_beta_warp"] = 0.0
    path.write_text(json.dumps({"params": per, "density_normalized": True}))
    with pytest.raises(ValueError, match=r"est\.json: density-normalised .*--density-gsm"):
        parse_params_file(path)
    d = parse_params_file(path, density_kg_m2=0.2)
    for k, v in FABRIC.items():
        assert d[k] == pytest.approx(v, rel=1e-12)
    flat = tmp_path / "p.json"
    flat.write_text(json.dumps(FABRIC))
    with pytest.raises(ValueError, match="only given for a density-normalised"):
        parse_params_file(flat, density_kg_m2=0.2)


@pytest.mark.parametrize("content, message", [
    ("{not json", "invalid JSON"),
    ("[1, 2]", "expected a JSON object"),
    (json.dumps({"params": [1]}), "'params' must be a JSON object"),
    (json.dumps({k: v for k, v in FABRIC.items() if k != "bend_k1_bias"}), "bend_k1_bias"),
    (json.dumps({**FABRIC, "density": "heavy"}), "'density' must be a number"),
    (json.dumps({**FABRIC, "thickness": 0.4}), "thickness"),
    (json.dumps({"dc": 0.5}), "no drapejax parameters"),
])
def test_parse_params_file_errors_name_the_file_and_field(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as e:
        parse_params_file(path)
    assert str(path) in str(e.value)
    with pytest.raises(ValueError, match="not found"):
        parse_params_file(tmp_path / "missing.json")


def test_cli_export_table_and_json(tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(FABRIC))
    assert main(["export", str(path), "--to", "clo"]) == 0
    text = capsys.readouterr().out
    assert "Bending-Warp" in text and "5000" in text and "g*mm^2/s^2" in text and "not exported:" in text
    assert main(["export", str(path), "--to", "kes", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == export_params(FABRIC, "kes")


def test_cli_export_out_writes_complete_json(tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(FABRIC))
    dest = tmp_path / "exports" / "fast.json"
    dest.parent.mkdir()
    dest.write_text("old")
    assert main(["export", str(path), "--to", "fast", "--out", str(dest)]) == 0
    assert "B-1" in capsys.readouterr().out
    assert json.loads(dest.read_text()) == export_params(FABRIC, "fast")
    assert sorted(p.name for p in dest.parent.iterdir()) == ["fast.json"]  # no temporary file left


def test_cli_bad_file_is_one_clear_error(tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({**FABRIC, "bend_k1_warp": 13.8}))
    dest = tmp_path / "out.json"
    assert main(["export", str(path), "--to", "clo", "--out", str(dest)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("drapejax export: error:")
    assert str(path) in err[0] and "bend_k1_warp" in err[0] and "Traceback" not in err[0]
    assert not dest.exists()
    assert main(["export", str(tmp_path / "missing.json"), "--to", "clo"]) == 2
    assert "not found" in capsys.readouterr().err


def test_cli_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"drapejax {version('drapejax')}"


def test_estimate_to_is_off_by_default():
    from drapejax.cli import build_parser

    assert build_parser().parse_args(["estimate", "d"]).to is None


def test_estimate_to_adds_the_export(shared_data, capsys):
    """`estimate --no-refine --to fast` on a real capture with a known density (fabric 2, 0.192 kg/m²)."""
    folder = shared_data / "real_cusick" / "bdp_f02_sample_2_capture_1"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    assert main(["estimate", str(folder), "--no-refine", "--to", "fast", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["export"] == export_params(out["params"], "fast")
    b1 = next(f for f in out["export"]["fields"] if f["name"] == "B-1")
    assert b1["value"] == pytest.approx(out["params"]["bend_k1_warp"] * 1e6)


def test_estimate_to_needs_a_density(shared_data, capsys):
    """Without an areal density the estimate is k/ρ: `--to` stops before estimating, naming the folder."""
    from drapejax.io import load_measurement

    folders = [d for d in sorted((shared_data / "real_cusick").iterdir())
               if load_measurement(d).areal_density_kg_m2 is None]
    if not folders:
        pytest.skip("no capture without an areal density")
    assert main(["estimate", str(folders[0]), "--no-refine", "--to", "clo"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and str(folders[0]) in captured.err and "--density-gsm" in captured.err
