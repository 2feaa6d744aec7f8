"""The package surface: the Python API at the top level, --version, python -m uavsim, a light --help."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import uavsim
import uavsim.cli.main as cli_main

ROOT = Path(__file__).resolve().parents[1]


def test_api_functions_are_documented_at_the_top_level():
    import pkgutil

    # a subpackage imported later would shadow a function of its name
    subpackages = {m.name for m in pkgutil.iter_modules(uavsim.__path__)}
    assert not subpackages & set(uavsim._API)
    for name in uavsim._API:
        f = getattr(uavsim, name)
        assert callable(f) and f.__doc__ and len(f.__doc__.strip()) > 40, name
    assert "identify_session" in dir(uavsim)
    with pytest.raises(AttributeError):
        uavsim.no_such_thing  # noqa: B018


def test_tune_matches_the_cli(capsys):
    got = uavsim.tune("altitude", T_prop=0.3, T1=0.2, tau=0.0128)
    assert cli_main.main(["tune", "--loop", "altitude", "--T-prop", "0.3", "--T1", "0.2", "--tau", "0.0128",
                          "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    for k in ("kp", "kd", "derivative_filter_hz", "omega"):
        assert got[k] == pytest.approx(want[k], rel=1e-12), k
    # the gains scale as 1/K
    assert uavsim.tune("altitude", T_prop=0.3, T1=0.2, tau=0.0128, K=4.0)["kp"] == pytest.approx(got["kp"] / 4)


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)


def test_import_and_help_load_nothing_heavy():
    """``import uavsim`` and ``uavsim --help`` import neither numpy, scipy, MuJoCo nor torch (the ~2 s
    that --help took); only the command being run is imported."""
    heavy = ("numpy", "scipy", "mujoco", "torch", "pydantic", "matplotlib")
    code = ("import sys, io, contextlib\nimport uavsim\nfrom uavsim.cli.main import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(['--help'])\n    except SystemExit:\n        pass\n"
            f"print([m for m in {heavy!r} if m in sys.modules])")
    res = _python(code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_version_and_python_m():
    res = subprocess.run([sys.executable, "-m", "uavsim", "--version"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.strip() == f"uavsim {uavsim.__version__}"
    res = subprocess.run([sys.executable, "-m", "uavsim", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0
    for cmd in ("identify", "export-gains", "schema", "session", "train", "generate"):
        assert cmd in res.stdout, cmd
    res = subprocess.run([sys.executable, "-m", "uavsim", "identify", "--help"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0 and "--plot" in res.stdout
