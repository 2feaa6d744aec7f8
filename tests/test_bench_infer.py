"""``uavsim bench infer`` runs its stages on a random-weight network of the altitude grid's shape."""

import math

from uavsim.bench.infer import run_bench


def test_bench_infer_times_every_stage(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no training/runs here: the random-weight network of the same shape
    out = run_bench(None, reps=3, threads=1)
    assert not out["trained_model"]
    for k in ("preprocess", "network", "identification", "identification_table_path", "identification_guarded",
              "identification_two_points", "fitted_optimum"):
        assert math.isfinite(out[k]["median_ms"]) and out[k]["median_ms"] > 0, k
    # the guarded identification is the table path plus the guard's own ISEs
    assert out["identification_guarded"]["median_ms"] > out["preprocess"]["median_ms"]
    # the goal is judged on the table path (the grid's decision), not on the default decision's
    assert out["meets_goal"] == (out["identification_table_path"]["median_ms"] <= out["goal_ms"])
