"""Sharded dataset generation: resume after a crash, two processes, gap/duplicate detection.

The drape is a cheap deterministic stand-in (``fake_drape``, a droop-and-folds shape driven by
the gravito-bending number) so that these tests exercise the bookkeeping, not the solver; the
observations are the real renderers of ``drapejax.observe``.
"""

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drapejax.inverse.dataset import DatasetError, drop_seeds, generate, load
from drapejax.inverse.prior import default_prior
from drapejax.material import G, PARAM_KEYS

ROOT = Path(__file__).resolve().parents[1]
OBS = ("silhouette", "height", "depth4", "boundary")
SETUP = dict(n_samples=22, shard_size=4, mesh_spacing_m=0.02, seed=3, observations=OBS)


def fake_drape(mesh, params, seeds):
    """Stand-in for ``drape_batch``: hem droops by a Γ-dependent angle with Γ-dependent folds.

    Status is 1 (step budget) for drop seeds ≡ 0 mod 5 and 2 (non-finite, x = NaN) for ≡ 0 mod 7.
    """
    rest = np.asarray(mesh.rest)
    rho = np.asarray(params.density)[:, None]
    k1 = np.mean([np.asarray(getattr(params, f"bend_k1_{d}")) for d in ("warp", "weft", "bias")], 0)[:, None]
    gamma = rho * G * 0.06**3 / k1
    tip = 0.5 * np.pi * (1 - np.exp(-gamma / 20))  # tip angle from horizontal
    folds = np.clip(np.round(3 + gamma / 15), 3, 12)
    seeds = np.asarray(seeds)[:, None]
    phase = 2 * np.pi * (seeds % 1000) / 1000
    r = np.linalg.norm(rest[:, :2], axis=1)[None]
    phi = np.arctan2(rest[:, 1], rest[:, 0])[None]
    s = np.maximum(r - mesh.info.disk_radius_m, 0.0)
    c = tip / 0.06
    rad = mesh.info.disk_radius_m + np.sin(c * s) / c
    rad = rad * (1 + 0.08 * (s / 0.06) * np.cos(folds * phi + phase))
    x = np.stack([rad * np.cos(phi), rad * np.sin(phi), -(1 - np.cos(c * s)) / c], -1)
    x = np.where((r <= mesh.info.disk_radius_m)[..., None], rest[None], x)
    status = np.where(seeds[:, 0] % 5 == 0, 1, 0)
    status = np.where(seeds[:, 0] % 7 == 0, 2, status)
    x = np.where((status == 2)[:, None, None], np.nan, x)
    return SimpleNamespace(x=x, status=status)


class CrashAfter:
    """``fake_drape`` that raises (a crashed run) on call number ``n + 1``."""

    def __init__(self, n):
        self.n, self.calls = n, 0

    def __call__(self, mesh, params, seeds):
        self.calls += 1
        if self.calls > self.n:
            raise RuntimeError("simulated crash")
        return fake_drape(mesh, params, seeds)


def assert_same(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    summary = generate(out, prior=default_prior(), process_index=0, process_count=1, progress=False,
                       simulate=fake_drape, **SETUP)
    assert summary["written"] == list(range(6)) and summary["skipped"] == []
    return out, load(out)


def test_uninterrupted_dataset_content(reference):
    out, data = reference
    n = SETUP["n_samples"]
    np.testing.assert_array_equal(data["index"], np.arange(n))
    expect = default_prior().sample(n, SETUP["seed"])
    np.testing.assert_array_equal(data["params"], np.stack([np.asarray(getattr(expect, k)) for k in PARAM_KEYS], 1))
    np.testing.assert_array_equal(data["drop_seed"], drop_seeds(SETUP["seed"], np.arange(n)))
    failed = data["status"] != 0
    assert 0 < failed.sum() < n
    np.testing.assert_array_equal(data["status"], fake_drape_status(data["drop_seed"]))
    assert data["silhouette"].shape == (n, 256, 256) and data["depth4"].shape == (n, 4, 128, 128)
    assert np.all(data["silhouette"][failed] == 0) and np.all(np.isnan(data["height"][failed]))
    # A draped specimen covers at least the 18 cm support disc and less than its flat 30 cm disc.
    px_area = (0.32 / 256) ** 2
    area = (data["silhouette"][~failed] > 0).sum((1, 2)) * px_area
    assert np.all(area > np.pi * 0.09**2) and np.all(area < np.pi * 0.15**2 * 1.05)
    log = [json.loads(line) for line in (out / "failures.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in log) == np.flatnonzero(failed).tolist()
    assert all(r["status"] == data["status"][r["index"]] for r in log)


def fake_drape_status(drop_seed):
    return np.where(drop_seed % 7 == 0, 2, np.where(drop_seed % 5 == 0, 1, 0))


def test_resume_after_crash_matches_uninterrupted(reference, tmp_path):
    _, ref = reference
    out = tmp_path / "run"
    kw = dict(prior=default_prior(), process_index=0, process_count=1, progress=False, **SETUP)
    with pytest.raises(RuntimeError, match="simulated crash"):
        generate(out, simulate=CrashAfter(2), **kw)
    assert sorted(p.name for p in out.glob("shard_*")) == ["shard_000000.npz", "shard_000001.npz"]
    (out / "shard_000002.npz.tmp.4242").write_bytes(b"half-written shard of a killed run")
    with pytest.raises(DatasetError, match="14 missing"):
        load(out)
    summary = generate(out, simulate=fake_drape, **kw)
    assert summary["skipped"] == [0, 1] and summary["written"] == [2, 3, 4, 5]
    assert not list(out.glob("*.tmp.*"))
    assert_same(load(out), ref)
    # Failures of the crashed attempt were never logged; those of the resumed run once each.
    idx = [json.loads(line)["index"] for line in (out / "failures.jsonl").read_text().splitlines()]
    assert sorted(idx) == np.flatnonzero(ref["status"] != 0).tolist()
    assert generate(out, simulate=CrashAfter(0), **kw)["written"] == []  # complete: nothing to simulate


def test_load_detects_gaps_duplicates_and_config_change(reference, tmp_path):
    src, _ = reference
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    shutil.copy(out / "shard_000001.npz", out / "shard_000099.npz")
    with pytest.raises(DatasetError, match="4 duplicated"):
        load(out)
    (out / "shard_000099.npz").unlink()
    (out / "shard_000003.npz").unlink()
    with pytest.raises(DatasetError, match=r"4 missing \(first \[12, 13, 14, 15\]\)"):
        load(out)
    with pytest.raises(DatasetError, match=r"dataset.json: existing dataset differs in \['seed'\]"):
        generate(out, prior=default_prior(), process_index=0, process_count=1, progress=False,
                 simulate=fake_drape, **dict(SETUP, seed=4))


def test_named_simulate_is_recorded_and_a_resume_with_another_is_refused(reference, tmp_path):
    _, ref = reference
    out = tmp_path / "named"
    kw = dict(prior=default_prior(), process_index=0, process_count=1, progress=False, **SETUP)
    generate(out, simulate=f"{__name__}:fake_drape", **kw)
    assert json.loads((out / "dataset.json").read_text())["simulate"] == f"{__name__}:fake_drape"
    assert_same(load(out), ref)
    for other in (f"{__name__}:fake_drape_status", fake_drape):
        with pytest.raises(DatasetError, match=r"existing dataset differs in \['simulate'\]"):
            generate(out, simulate=other, **kw)


def test_drops_per_member_repeat_each_member_with_its_own_seeds(reference, tmp_path):
    """With D drops per member, samples D·j … D·j + D − 1 carry member j's parameters (those of
    sample j of the one-drop dataset) and distinct drop seeds; the setting is recorded."""
    _, ref = reference
    out = tmp_path / "drops"
    generate(out, prior=default_prior(), process_index=0, process_count=1, progress=False,
             simulate=fake_drape, drops_per_member=3, **SETUP)
    data = load(out)
    assert json.loads((out / "dataset.json").read_text())["drops_per_member"] == 3
    member = data["index"] // 3
    np.testing.assert_array_equal(data["params"], ref["params"][member])
    np.testing.assert_array_equal(data["drop_seed"], drop_seeds(SETUP["seed"], data["index"]))
    assert all(len(set(data["drop_seed"][member == j])) == np.sum(member == j) for j in np.unique(member))
    assert "drops_per_member" not in json.loads((reference[0] / "dataset.json").read_text())
    with pytest.raises(DatasetError, match="drops_per_member"):
        generate(out, prior=default_prior(), process_index=0, process_count=1, progress=False,
                 simulate=fake_drape, **SETUP)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _generate_in(out: Path, index: int, count: int, coord: list[str],
                 entry: tuple[str, ...] = ("-m", "drapejax.inverse.dataset")) -> subprocess.Popen:
    """The dataset command line (``entry``) as process ``index`` of ``count``, on the CPU."""
    env = dict(os.environ, JAX_ENABLE_X64="1", JAX_PLATFORMS="cpu",
               PYTHONPATH=os.pathsep.join([str(ROOT / "tests"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen(
        [sys.executable, *entry, "--out", str(out), "--n", str(SETUP["n_samples"]),
         "--shard-size", str(SETUP["shard_size"]), "--seed", str(SETUP["seed"]),
         "--spacing", str(SETUP["mesh_spacing_m"]), "--observations", ",".join(OBS),
         "--simulate", "test_dataset:fake_drape", "--process-index", str(index), "--process-count", str(count),
         "--no-progress", *coord], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("distributed", [False, True], ids=["independent", "jax.distributed"])
def test_two_processes_produce_the_dataset(tmp_path, distributed):
    """Two processes write the dataset one process writes, byte for byte (that one through
    ``drapejax dataset``). All runs are on the CPU, so that on a GPU machine the renderers' float
    results are compared with like."""
    coord = ["--coordinator", f"localhost:{_free_port()}"] if distributed else []
    procs = [_generate_in(tmp_path / "two", i, 2, coord) for i in range(2)]
    procs.append(_generate_in(tmp_path / "one", 0, 1, [], entry=("-m", "drapejax.cli", "dataset")))
    results = [p.communicate(timeout=240) for p in procs]
    for p, (so, se) in zip(procs, results):
        assert p.returncode == 0, se[-3000:]
    summaries = [json.loads(so.strip().splitlines()[-1]) for so, _ in results]
    assert summaries[0]["written"] == [0, 2, 4] and summaries[1]["written"] == [1, 3, 5]
    assert summaries[2]["written"] == list(range(6))
    assert_same(load(tmp_path / "two"), load(tmp_path / "one"))


def test_transfer_carries_affine_states_exactly_and_a_mesh_onto_itself_unchanged():
    """Barycentric transfer reproduces any affine map of the flat specimen, also at the target's
    boundary vertices outside the source's polygon, and leaves a state on its own mesh as it is."""
    from drapejax.mesh import cusick_mesh
    from drapejax.transfer import transfer

    source, target = cusick_mesh(0.02, rim_spacing_m=0.004), cusick_mesh(0.01)
    a = np.array([[0.9, 0.2, 0.1], [-0.3, 1.1, 0.4], [0.0, 0.0, 1.0]])
    b = np.array([0.01, -0.02, 0.03])
    affine = lambda rest: np.asarray(rest) @ a.T + b
    carried = transfer(affine(source.rest), source, target)
    np.testing.assert_allclose(carried, affine(target.rest), atol=1e-12)
    x = np.random.default_rng(0).normal(size=(source.n_verts, 3))
    np.testing.assert_array_equal(transfer(x, source, source), x)


def test_converged_simulate_drapes_on_the_hierarchy_and_reports_each_members_status():
    """``converged_simulate`` gives each member ``drape_multilevel``'s rest state on the hierarchy
    of the dataset's spacing, carried to the dataset mesh, and a status per member (an invalid
    member does not stop the batch)."""
    import dataclasses

    import jax

    from drapejax.inverse.dataset import converged_simulate
    from drapejax.material import example_params, stack
    from drapejax.mesh import cusick_hierarchy, cusick_mesh
    from drapejax.solve import AT_REST, INVALID_PARAMS, coarsest_spacing_m, drape_multilevel
    from drapejax.transfer import transfer

    jax.config.update("jax_enable_x64", True)
    mesh = cusick_mesh(0.02)
    good = example_params("heavy")
    bad = dataclasses.replace(good, bend_k1_warp=-1.0)
    res = converged_simulate(mesh, stack([good, bad]), np.array([4, 5]))
    assert res.x.shape == (2, mesh.n_verts, 3)
    assert res.status.tolist() == [AT_REST, INVALID_PARAMS]
    meshes, prolongs = cusick_hierarchy(0.02, coarsest_spacing_m=coarsest_spacing_m(good))
    assert meshes[-1] is not mesh  # the finest level is graded at the disc edge, the dataset mesh is not
    direct = jax.jit(lambda p, s: drape_multilevel(meshes, prolongs, p, s))(good, 4)
    np.testing.assert_allclose(res.x[0], transfer(direct.finest.x, meshes[-1], mesh), atol=1e-9)
    assert np.all(np.isfinite(res.x[0])) and np.min(res.x[0][:, 2]) < -0.02  # it drapes
