"""The exported network without torch: ``weights.npz`` (numpy), ``model.onnx`` (onnxruntime),
and identification that never imports torch (same JSON as with torch)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from _learning_fixtures import three_model, trained_like_net  # noqa: F401 (fixture)

from uavsim.errors import UserError
from uavsim.learning.export import ONNX_FILE, WEIGHTS_FILE, Predictor, export_model, write_weights

ROOT = Path(__file__).resolve().parents[1]
META = {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "altitude"}

#: a ``python -c`` prelude under which any ``import torch`` fails, as in an install without torch
BLOCK_TORCH = (
    "import sys\n"
    "class _NoTorch:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name == 'torch' or name.startswith('torch.'):\n"
    "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
    "sys.meta_path.insert(0, _NoTorch())\n"
)


def _run_without_torch(code: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "tests"), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", BLOCK_TORCH + code, *args], capture_output=True, text=True,
                          env=env, timeout=300, cwd=ROOT)


@pytest.mark.parametrize(("period_features", "phase_samples"), [(8, 0), (0, 0), (8, 16), (0, 40)])
def test_weights_and_onnx_equal_torch(tmp_path, period_features, phase_samples):
    import onnxruntime as ort

    net = trained_like_net(period_features=period_features, phase_samples=phase_samples)
    x = torch.randn(16, 2, 40)
    x[:, 1] = torch.sign(x[:, 1])  # the relay channel: +-1, its length feeds the period features
    x[:8, 1, 25:] = 0.0
    with torch.no_grad():
        want = net(x).numpy()
    export_model(net, dict(META, net=net.cfg.as_dict()), tmp_path)  # the trainer's meta.json holds the net's shape
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert {WEIGHTS_FILE, ONNX_FILE, "model.pt"} <= set(meta["files"])
    pred = Predictor(tmp_path)
    assert pred._module is None  # numpy only: the TorchScript file is not even loaded
    np.testing.assert_allclose(pred.activations(x.numpy()), want, rtol=1e-5, atol=1e-5)
    sess = ort.InferenceSession(str(tmp_path / ONNX_FILE), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"x": x.numpy()})[0]
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    one = sess.run(None, {"x": x[:1].numpy()})[0]  # the batch axis is dynamic
    np.testing.assert_allclose(one, want[:1], rtol=1e-5, atol=1e-5)
    with torch.inference_mode():  # and the TorchScript copy agrees
        np.testing.assert_allclose(pred.module(x).numpy(), want, rtol=1e-5, atol=1e-5)
    assert pred.numpy_layers["phase_samples"] == phase_samples
    if phase_samples:  # a folder whose weights.npz is written again from the TorchScript copy reads meta.json's
        (tmp_path / WEIGHTS_FILE).unlink()
        write_weights(tmp_path)
        np.testing.assert_allclose(Predictor(tmp_path).activations(x.numpy()), want, rtol=1e-5, atol=1e-5)


def test_network_exported_before_weights_npz(tmp_path):
    """A TorchScript-only folder still loads with torch, says how to upgrade without it, and upgrades."""
    net = trained_like_net()
    export_model(net, META, tmp_path)
    x = np.random.default_rng(0).standard_normal((3, 2, 40)).astype(np.float32)
    want = Predictor(tmp_path).activations(x)
    (tmp_path / WEIGHTS_FILE).unlink()
    (tmp_path / ONNX_FILE).unlink()
    old = Predictor(tmp_path)
    assert old.numpy_layers is not None  # read out of the TorchScript file, as before
    np.testing.assert_allclose(old.activations(x), want, rtol=1e-6, atol=1e-6)
    res = _run_without_torch("from uavsim.learning.export import Predictor\nimport sys\n"
                             "from uavsim.errors import UserError\n"
                             "try:\n    Predictor(sys.argv[1])\nexcept UserError as e:\n    print(e)\n",
                             str(tmp_path))
    assert res.returncode == 0, res.stderr
    msg = res.stdout.strip()
    assert "\n" not in msg and str(tmp_path) in msg and "python -m uavsim.learning.export" in msg, msg
    write_weights(tmp_path)
    assert (tmp_path / WEIGHTS_FILE).is_file() and (tmp_path / ONNX_FILE).is_file()
    np.testing.assert_allclose(Predictor(tmp_path).activations(x), want, rtol=1e-6, atol=1e-6)


def test_bad_weights_file_is_one_line_error(tmp_path):
    export_model(trained_like_net(), META, tmp_path)
    (tmp_path / WEIGHTS_FILE).write_bytes(b"not a zip")
    with pytest.raises(UserError, match="not a weights file") as info:
        Predictor(tmp_path)
    assert str(tmp_path / WEIGHTS_FILE) in str(info.value) and "\n" not in str(info.value)


def test_identify_without_torch_answers_the_same_json(three_model, tmp_path):  # noqa: F811
    """`uavsim identify --json` in a process where torch cannot be imported gives the torch process's JSON."""
    from test_identify import _mujoco_session

    from uavsim.formats.session import write_session

    tmp, model, grid = three_model
    from _learning_fixtures import CLASSES

    sess = write_session(_mujoco_session(grid, CLASSES[1]), tmp_path / "session")
    code = ("from uavsim.cli.main import main\n"
            "rc = main(['identify', sys.argv[1], '--models', sys.argv[2], '--json'])\n"
            "assert not any(m == 'torch' or m.startswith('torch.') for m in sys.modules), 'torch imported'\n"
            "sys.exit(rc)\n")
    res = _run_without_torch(code, str(sess), str(model))
    assert res.returncode == 0, res.stderr
    no_torch = json.loads(res.stdout)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    # the torch process runs the TorchScript network itself (the path before weights.npz)
    torch_code = ("import sys, torch\nimport uavsim.learning.export as ex\n"
                  "init = ex.Predictor.__init__\n"
                  "def torch_init(self, *a, **k):\n    init(self, *a, **k)\n    self.numpy_layers = None\n"
                  "ex.Predictor.__init__ = torch_init\nfrom uavsim.cli.main import main\n"
                  "sys.exit(main(['identify', sys.argv[1], '--models', sys.argv[2], '--json']))")
    with_torch = subprocess.run([sys.executable, "-c", torch_code, str(sess), str(model)], capture_output=True,
                                text=True, env=env, timeout=300)
    assert with_torch.returncode == 0, with_torch.stderr
    _assert_same_json(no_torch, json.loads(with_torch.stdout))
    assert no_torch["class"] == 1


def test_identify_reads_nothing_but_the_bundle(three_model, tmp_path):  # noqa: F811
    """A model folder copied away identifies in a process where the package grids, tables and recipes
    cannot even be imported (nor torch), the optimum of the fitted model included: the bundle carries
    everything identification needs."""
    import shutil

    from _learning_fixtures import CLASSES
    from test_identify import _mujoco_session

    from uavsim.formats.session import write_session

    tmp, model, grid = three_model
    sess = write_session(_mujoco_session(grid, CLASSES[1]), tmp_path / "session")
    copy = shutil.copytree(model, tmp_path / "elsewhere" / "model")
    block = ("class _NoGrids:\n"
             "    def find_spec(self, name, path=None, target=None):\n"
             "        if name in ('uavsim.tuning.grid', 'uavsim.tuning.table', 'uavsim.data.recipe'):\n"
             "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
             "sys.meta_path.insert(0, _NoGrids())\n")
    code = block + ("from uavsim.ident.session import identify_session\n"
                    "import json\n"
                    "print(json.dumps(identify_session(sys.argv[1], models=sys.argv[2], optimum='always')))\n")
    res = _run_without_torch(code, str(sess), str(copy))
    assert res.returncode == 0, res.stderr
    ans = json.loads(res.stdout)
    assert ans["class"] == 1 and ans["gains_source"] == "optimum" and ans["gains_table"]["kp"] > 0


def _assert_same_json(a, b, path="$"):
    """Equal structure and strings; numbers equal within float32 rounding of the network's outputs
    (a ``latency_ms``, the answer's own clock, only a number in both)."""
    assert type(a) is type(b) or {type(a), type(b)} <= {int, float}, path
    if path.endswith(".latency_ms"):
        assert isinstance(a, float) and isinstance(b, float), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same_json(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same_json(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-5, abs=1e-9), path
    else:
        assert a == b, path


def test_identify_plot_and_training_curves(three_model, tmp_path, capsys):  # noqa: F811
    """`uavsim identify --plot` writes the picture; training left its curves beside the network."""
    from _learning_fixtures import CLASSES
    from test_identify import _mujoco_session

    import uavsim.cli.main as cli_main
    from uavsim.formats.session import write_session

    tmp, model, grid = three_model
    sess = write_session(_mujoco_session(grid, CLASSES[1]), tmp_path / "session")
    png = tmp_path / "id.png"
    assert cli_main.main(["identify", str(sess), "--models", str(model), "--plot", str(png), "--json"]) == 0
    ans = json.loads(capsys.readouterr().out)
    assert ans["plot"] == str(png)
    for p in (png, model / "training.png"):
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000, p
    from uavsim.learning.figures import model_cycle

    # the picture's model cycle is the identified model's own: its period is the measured one (exact lumped
    # MRFT of the fitted model; NP-MRFT's observation window lengthens the measured cycle a little)
    t, y, u = model_cycle(ans["params"], "altitude", grid.beta, 0.5, 200.0)
    assert t[-1] / 3 == pytest.approx(ans["oscillation"]["period"], rel=0.1)
