"""``uavsim bench generate`` on a tiny recipe: its figures are the ones its docstring defines."""

import math

from uavsim.bench.generate import RAW_ARRANGEMENTS, bench_generate


def test_bench_generate_reports_the_fastest_raw_arrangement_and_cpu_figures():
    r = bench_generate(n_classes=2, per_class=2, chunk=3, repeats=1)
    assert r["episodes"] == 2 * 2 + 2  # the reference episodes run too
    walls = {a: r[f"raw_{a}_wall_s"] for a in RAW_ARRANGEMENTS}
    cpus = {a: r[f"raw_{a}_cpu_s"] for a in RAW_ARRANGEMENTS}
    assert all(len(v) == 1 and v[0] > 0 for v in (*walls.values(), *cpus.values()))
    # the baseline is the fastest arrangement (wall) and the least CPU of any raw run
    assert r["raw_wall_s"] == min(v[0] for v in walls.values())
    assert r["raw_cpu_s"] == min(v[0] for v in cpus.values())
    assert math.isclose(r["ratio_to_raw"], r["raw_wall_s"] / r["wall_s"])
    assert r["gen_cpu_s"] == min(r["gen_cpu_s_all"]) > 0
    assert math.isclose(r["cpu_ratio_to_raw"], r["raw_cpu_s"] / r["gen_cpu_s"])
