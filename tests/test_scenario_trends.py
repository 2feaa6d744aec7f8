"""The paper's camera trends over seeds: the trend logic on known rows, and the CLI on real runs."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from uavsim.scenario.trends import SIMILAR_KP_RATIO, check_trends, summarize

ROOT = Path(__file__).resolve().parents[1]


def _row(**kw):
    base = {"T_prop": 0.1, "T1": 0.5, "tau": 0.01, "kp": 1.0, "kd": 0.2, "Q_sim": 0.2, "Q_mj": 0.2, "T0": 0.6,
            "identifier": "dnn", "retries": 0}
    return {**base, **kw}


def test_trends_on_known_rows():
    runs = {
        ("normal", "kf"): [_row(kp=1.0, tau=0.01), _row(kp=1.1, tau=0.02), _row(kp=1.2, tau=0.01)],
        ("normal", "camera"): [_row(kp=0.4, tau=0.06, Q_mj=0.3), _row(kp=0.5, tau=0.01, Q_mj=0.3),
                               _row(kp=1.5, tau=0.05, Q_mj=0.3)],
        ("event", "kf"): [_row(kp=1.2), _row(kp=1.3), _row(kp=1.4)],
        ("event", "camera"): [_row(kp=0.9, Q_mj=0.1), _row(kp=0.8, Q_mj=0.4), _row(kp=0.7, Q_mj=0.2)],
        ("thermal", "kf"): [_row(kp=3.0), _row(kp=1.2), _row(kp=1.3)],
        ("thermal", "camera"): [_row(kp=0.3, tau=None), _row(kp=0.3), _row(kp=0.3)],
    }
    t = check_trends(runs)["trends"]
    assert t["gains_lower_without_kf"]["normal"] == {"median": True, "seeds": pytest.approx(2 / 3)}
    # tau: medians 0.05 >= 0.01; per seed 0.06 >= 0.01, 0.01 < 0.02, 0.05 >= 0.01
    assert t["delay_larger_without_kf"]["normal"] == {"median": True, "seeds": pytest.approx(2 / 3)}
    # a missing value leaves that seed out
    assert t["delay_larger_without_kf"]["thermal"]["seeds"] == pytest.approx(1.0)
    assert t["event_beats_normal_without_kf"] == {"median": True, "seeds": pytest.approx(2 / 3)}
    # with KF medians 1.1, 1.3, 1.3; seed 0 has 3.0 / 1.0 > SIMILAR_KP_RATIO
    s = t["similar_gains_with_kf"]
    assert s["median"] and s["kp_ratio"] == pytest.approx(1.3 / 1.1) and s["seeds"] == pytest.approx(2 / 3)
    assert 3.0 / 1.0 > SIMILAR_KP_RATIO
    summ = summarize(runs[("thermal", "camera")])
    assert summ["tau"]["n"] == 2 and summ["kp"] == {"median": 0.3, "min": 0.3, "max": 0.3, "n": 3}


def test_cli_runs_the_seeds_of_scenario_run(tmp_path):
    """Each per-seed row is the altitude loop that ``scenario run --seed`` identifies."""
    files = [str(ROOT / "scenarios" / f) for f in ("normal-camera-kf.toml", "normal-camera-no-kf.toml")]
    p = subprocess.run([sys.executable, "-m", "uavsim.cli.main", "scenario", "trends", *files, "--seeds", "1", "--json"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    res = json.loads(p.stdout)
    assert set(res["runs"]) == {"normal/kf", "normal/camera"} and res["n_seeds"] == 1
    assert set(res["trends"]) == {"delay_larger_without_kf", "gains_lower_without_kf"}
    row = res["runs"]["normal/camera"][0]
    q = subprocess.run([sys.executable, "-m", "uavsim.cli.main", "scenario", "run", files[1], "--seed", str(row["seed"]),
                        "--json", "--save", str(tmp_path / "run.rrd")], capture_output=True, text=True, timeout=600)
    assert q.returncode == 0, q.stderr
    one = json.loads(q.stdout)["loops"]["altitude"]
    for k in ("kp", "kd", "tau", "Q_mj"):
        assert row[k] == one[k]


def test_cli_rejects_zero_seeds():
    p = subprocess.run([sys.executable, "-m", "uavsim.cli.main", "scenario", "trends", "--seeds", "0"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "--seeds must be >= 1" in p.stderr and "Traceback" not in p.stderr
