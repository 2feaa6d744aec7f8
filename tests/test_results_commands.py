"""The commands behind docs/results figures that had none: ``uavsim.results.optimal_gains`` and
``uavsim.results.training_sets`` run on the packaged tables and a small generated set, and refuse bad
input with one line, exit 2 (with ``uavsim.results.lateral_grid``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _one_line_error(capsys, needle: str) -> None:
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


# --- uavsim.results -------------------------------------------------------------------------

def test_optimal_gains_kick_and_margins_on_the_packaged_tables(capsys):
    from uavsim.lumped.sampled import lift, sampled_ise
    from uavsim.results.optimal_gains import gain_margin, kick_figures
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.table import load_table

    k = kick_figures("attitude")
    # with the kick the optimum is another controller: a fraction of the rule's kp, a large first sample
    assert k["stable_optimum"] == 48 and k["kick_kp_over_rule_kp"]["max"] < 0.5
    assert k["kick_first_derivative_over_proportional"]["median"] > 10
    assert k["no_kick_table_kp_over_rule_kp"]["median"] > 0.5
    # the margin is where the loop turns unstable: stable just below it, unstable just above
    g, t, c = load_grid("altitude"), load_table("altitude"), np.array([0, 100, 207])
    proc = lift("altitude", 200.0, K=1.0, **{a: np.asarray(g.params[a])[c] for a in ("T_prop", "T1", "tau")})
    kp, kd, N = t.kp[c], t.kd[c], t.N[c]
    m = gain_margin(proc, kp, kd, N)
    assert np.all(m > 1) and np.all(m < 10)
    assert np.all(sampled_ise(proc, 0.999 * m * kp, 0.999 * m * kd, N, return_stable=True)[1])
    assert not np.any(sampled_ise(proc, 1.001 * m * kp, 1.001 * m * kd, N, return_stable=True)[1])


def test_optimal_gains_free_filter_opens_the_filter():
    from uavsim.results.optimal_gains import N_CAP, free_filter_figures

    f = free_filter_figures(n_classes=1, maxfev=600)
    assert len(f["rows"]) == 2  # one class of each inner grid
    for r in f["rows"]:
        assert r["ise_free"] < r["ise_fixed"] and r["N_free"] > 1e3 * r["N_fixed"] and r["N_free"] <= N_CAP


@pytest.mark.parametrize("module, argv, needle", [
    ("optimal_gains", [], "nothing to do"),
    ("optimal_gains", ["--kick", "--classes", "0"], "must be >= 1"),
    ("lateral_grid", ["--per-class", "0"], "--per-class"),
    ("lateral_grid", ["--render", "/no/new.json", "/no/old.json"], "cannot read"),
    ("lateral_grid", ["--grid", "/no/lateral.json"], "/no/lateral.json"),
    ("training_sets", ["/no/such.h5"], "no such file"),
])
def test_results_modules_user_errors(module, argv, needle, capsys):
    import importlib

    mod = importlib.import_module(f"uavsim.results.{module}")
    assert mod.main(argv) == 2
    _one_line_error(capsys, needle)


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    from uavsim.data.generate import generate
    from uavsim.data.recipe import load_recipe

    out = tmp_path_factory.mktemp("small") / "small.h5"
    generate(load_recipe(ROOT / "datasets" / "small.toml"), out, progress=False)
    return out


def test_training_set_figures(small_set, capsys):
    from uavsim.data.h5 import open_dataset
    from uavsim.results.training_sets import figures, main

    ds = open_dataset(small_set)
    f = figures(small_set)
    r = f["refused"]
    # every planned episode is kept or counted as refused or diverged by the file itself
    assert r["planned"] == ds.attrs["n_episodes"] and r["missing"] == r["n_rejected"] + r["n_diverged"]
    assert sum(x["planned"] for x in r["by_level"]) == sum(x["planned"] for x in r["by_kind"]) == r["planned"]
    assert sum(x["episodes"] for x in f["lengthening"]) == ds.n
    none = next(x for x in f["lengthening"] if x["kind"] == "none")
    assert 0.9 < none["period_over_period_sim_median"] < 1.1
    rc = f["reference_cycle"]  # the sampled relay lengthens the cycle, most for the fastest classes
    assert rc["period"]["max"] > 0 and rc["period"]["grid_class_of_max"] == 207
    assert main([str(small_set)]) == 0
    assert "| noise kind | planned | missing |" in capsys.readouterr().out


def test_training_set_figures_refuse_a_changed_grid(small_set, tmp_path, capsys):
    import h5py

    copy = tmp_path / "copy.h5"
    copy.write_bytes(small_set.read_bytes())
    with h5py.File(copy, "a") as f:
        f.attrs["grid_hash"] = "0" * 64
    from uavsim.results.training_sets import main

    assert main([str(copy)]) == 2
    _one_line_error(capsys, "grid changed since the file was made")


def test_onnx_latency_on_an_exported_network(tmp_path):
    pytest.importorskip("torch")
    from _learning_fixtures import trained_like_net

    from uavsim.learning.export import export_model
    from uavsim.results.onnx_latency import onnx_latency

    export_model(trained_like_net(), {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "altitude"}, tmp_path)
    r = onnx_latency(tmp_path, n=5)
    assert r["onnxruntime_ms"] > 0 and r["numpy_ms"] > 0 and r["max_diff"] < 1e-4


def test_onnx_latency_refuses_a_folder_without_a_network(tmp_path, capsys):
    from uavsim.results.onnx_latency import main

    assert main([str(tmp_path)]) == 2
    _one_line_error(capsys, "no model.onnx")
