"""Trainer: recipes, training on a tiny set, checkpoints and exact resume, early stopping, export, CLI."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from _learning_fixtures import tiny_J, write_tiny_dataset

from uavsim.errors import UserError
from uavsim.ident.bundle import load_bundle
from uavsim.learning.decision import decide
from uavsim.learning.export import Predictor
from uavsim.learning.train import class_metrics, load_train_recipe, train, train_from_recipe

ROOT = Path(__file__).resolve().parents[1]


def _recipe(tmp: Path, extra: str = "", net: str = "", **kw) -> Path:
    tmp.joinpath("training").mkdir(parents=True, exist_ok=True)
    if not (tmp / "a.h5").exists():
        write_tiny_dataset(tmp / "a.h5", seed=0)
        write_tiny_dataset(tmp / "b.h5", seed=1)
    text = (f'name = "tiny"\nloop = "altitude"\ndataset = "a.h5"\ntest_dataset = "b.h5"\nout = "runs/tiny"\n'
            f'seed = 3\n{extra}\n[net]\nhidden = [32, 16]\n{net}\n[optim]\nepochs = {kw.get("epochs", 6)}\n'
            f'batch_size = 16\nlr = 0.003\n[early_stopping]\npatience = {kw.get("patience", 10)}\n')
    p = tmp / "training" / "tiny.toml"
    p.write_text(text)
    return p


def test_recipe_paths_and_errors(tmp_path):
    r = load_train_recipe(_recipe(tmp_path))
    assert r.dataset == str(tmp_path / "a.h5") and r.out == str(tmp_path / "runs/tiny")
    assert r.hidden == [32, 16] and r.epochs == 6
    bad = tmp_path / "training" / "bad.toml"
    bad.write_text(_recipe(tmp_path).read_text() + "bogus = 1\n")
    with pytest.raises(UserError, match="bogus"):
        load_train_recipe(bad)
    bad.write_text(_recipe(tmp_path).read_text().replace("lr = 0.003", "lr = -1"))
    with pytest.raises(UserError, match="lr"):
        load_train_recipe(bad)
    with pytest.raises(UserError, match="not found"):
        load_train_recipe(tmp_path / "nope.toml")


def test_shipped_recipes_parse():
    for name in ("small", "altitude", "attitude", "lateral"):
        r = load_train_recipe(ROOT / "training" / f"{name}.toml")
        assert r.loop in ("altitude", "attitude", "lateral")
        assert Path(r.out).is_relative_to(ROOT / "training" / "runs")


def test_class_metrics_against_hand_values():
    J = tiny_J(4)
    m = class_metrics(np.array([0, 1, 3, 2]), np.array([0, 1, 2, 2]), J)
    assert m["top1"] == 0.75
    assert m["mean_J"] == pytest.approx((1 + 1 + J[3, 2] + 1) / 4)


def test_train_export_and_predictor(tmp_path):
    rep = train(load_train_recipe(_recipe(tmp_path)), quiet=True)
    assert rep["val"]["top1"] >= 0.9 and rep["test"]["top1"] >= 0.9
    assert rep["test"]["mean_J"] < 1.2
    out = Path(rep["out"])
    assert (out / "checkpoint.pt").is_file() and json.loads((out / "report.json").read_text())["name"] == "tiny"
    pred = Predictor(out)
    assert pred.meta["loop"] == "altitude" and pred.n_classes == 6 and pred.meta["seed"] == 3
    from uavsim.data.h5 import open_dataset

    ds = open_dataset(tmp_path / "b.h5")
    cls, act = pred.predict(ds.inputs)
    assert act.shape == (ds.n, 6)
    # the metrics are of identification's decision (least expected J over the set's J at the temperature
    # fitted on the validation set), argmax beside them
    b = load_bundle(out)
    assert b.temperature == pytest.approx(rep["val"]["temperature"]) and b.decision == rep["val"]["decision"]
    pred_b = decide(act, ds.J, temperature=b.temperature).cls
    assert class_metrics(pred_b, ds.labels, ds.J)["top1"] == pytest.approx(rep["test"]["top1_bayes"])
    assert class_metrics(cls, ds.labels, ds.J)["top1"] == pytest.approx(rep["test"]["top1_argmax"])
    assert rep["test"]["top1"] == rep["test"][f"top1_{b.decision}"]
    # the best epoch is the one of least mean J of that decision, and the bundle carries its J
    best = [h for h in rep["history"] if h["epoch"] == rep["best_epoch"]][0]
    assert best["val_mean_J"] == pytest.approx(rep["val"]["mean_J"]) and "val_mean_J_argmax" in best
    assert np.array_equal(b.cost, ds.J)


def test_gain_error_from_the_response(tmp_path):
    """The fixture's responses are K G_class(j w) with 1% noise: a classifier that is right gets the gains to ~1%."""
    rep = train(load_train_recipe(_recipe(tmp_path)), quiet=True)
    assert rep["test"]["top1"] >= 0.9
    assert 0.002 < rep["test"]["kp_err_median"] < 0.03 and rep["test"]["kd_err_median"] < 0.03
    # a set written before the response was recorded trains, without gain metrics
    write_tiny_dataset(tmp_path / "old.h5", seed=0, response=False)
    old = train(load_train_recipe(_recipe(tmp_path), {"dataset": str(tmp_path / "old.h5"), "test_dataset": "",
                                                      "out": str(tmp_path / "runs/old")}), quiet=True)
    assert "kp_err_median" not in old["val"]


def test_resume_continues_exactly(tmp_path):
    """1 epoch + resume to 3 gives the same history and weights as 3 epochs straight."""
    full = train(load_train_recipe(_recipe(tmp_path / "full", epochs=3)), quiet=True)
    (tmp_path / "cut").mkdir()
    p = _recipe(tmp_path / "cut", epochs=1)
    train(load_train_recipe(p), quiet=True)
    resumed = train(load_train_recipe(p, {"epochs": 3}), resume=True, quiet=True)
    assert resumed["epochs_run"] == 3
    ck_full = torch.load(Path(full["out"]) / "checkpoint.pt", weights_only=False)
    ck_res = torch.load(Path(resumed["out"]) / "checkpoint.pt", weights_only=False)
    assert [h["loss"] for h in ck_full["history"]] == pytest.approx([h["loss"] for h in ck_res["history"]], rel=1e-5)
    for k, v in ck_full["model"].items():
        torch.testing.assert_close(v, ck_res["model"][k], rtol=1e-4, atol=1e-5)


def test_resume_refuses_other_recipe(tmp_path):
    p = _recipe(tmp_path, epochs=1)
    train(load_train_recipe(p), quiet=True)
    with pytest.raises(UserError, match="different recipe"):
        train(load_train_recipe(p, {"lr": 0.01}), resume=True, quiet=True)


def test_early_stopping(tmp_path):
    # the tiny set is solved at once: mean J stays at 1, so patience 2 stops after 3 epochs
    rep = train(load_train_recipe(_recipe(tmp_path, epochs=30, patience=2)), quiet=True)
    assert rep["stopped"] == "early_stopping" and rep["epochs_run"] == rep["best_epoch"] + 3


def test_cli_train_json(tmp_path):
    p = _recipe(tmp_path, epochs=1)
    res = subprocess.run([sys.executable, "-m", "uavsim.cli.main", "train", str(p), "--json", "--quiet"],
                         capture_output=True, text=True, cwd=ROOT)
    if res.returncode != 0 and "invalid choice: 'train'" in res.stderr:
        pytest.skip("train command not registered in uavsim.cli.main yet")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["reports"][0]["epochs_run"] == 1
    bad = subprocess.run([sys.executable, "-m", "uavsim.cli.main", "train", str(tmp_path / "missing.toml")],
                         capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr


def test_missing_dataset_is_user_error(tmp_path):
    p = _recipe(tmp_path)
    (tmp_path / "a.h5").unlink()
    with pytest.raises(UserError):
        train_from_recipe(p, quiet=True)


def test_export_folds_batchnorm_exactly(tmp_path):
    """The exported network (BatchNorm folded into the next Linear) gives the trained network's outputs."""
    from _learning_fixtures import trained_like_net

    from uavsim.learning.export import export_model
    from uavsim.learning.model import IdentNet, NetConfig

    net = trained_like_net()  # running statistics far from the identity, as after training
    x = torch.randn(16, 2, 40)
    with torch.no_grad():
        want = net.eval()(x).numpy()
    export_model(net, {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "altitude"}, tmp_path)
    pred = Predictor(tmp_path)
    assert pred.numpy_layers is not None  # the numpy matmul chain, not the TorchScript call
    got = pred.activations(x.numpy())
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
    with torch.inference_mode():
        np.testing.assert_allclose(got, pred.module(x).numpy(), rtol=1e-5, atol=1e-5)
    net0 = IdentNet(NetConfig(2, 40, 5, hidden=[16], period_features=0))
    export_model(net0, {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "altitude"}, tmp_path / "p0")
    p0 = Predictor(tmp_path / "p0")
    with torch.no_grad():
        np.testing.assert_allclose(p0.activations(x.numpy()), net0.eval()(x).numpy(), rtol=1e-5, atol=1e-5)
    assert p0.numpy_layers is not None and p0.numpy_layers["rbf"] is None
    assert not any(isinstance(m, torch.nn.BatchNorm1d) for m in net.fold_batchnorm().modules())


def test_numpy_forward_skips_the_zero_padding_exactly(tmp_path):
    """Right-aligned, zero-padded inputs (cycles of any length, an empty one): the numpy chain's first layer
    over the cycle's samples only gives the TorchScript network's outputs."""
    from _learning_fixtures import trained_like_net

    from uavsim.learning.export import export_model

    net = trained_like_net()
    export_model(net, {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "altitude"}, tmp_path)
    pred = Predictor(tmp_path)
    assert pred.numpy_layers is not None and pred.numpy_layers["rbf"] is not None
    rng = np.random.default_rng(0)
    x = np.zeros((4, 2, 40), dtype=np.float32)
    for i, n in enumerate((40, 31, 9, 0)):  # a full input, two padded ones, an all-zero one
        x[i, :, 40 - n:] = rng.standard_normal((2, n))
    with torch.inference_mode():
        want = pred.module(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(pred.activations(x), want, rtol=1e-5, atol=1e-5)
    for i in range(4):  # one input at a time: the skipped columns are that input's own padding
        np.testing.assert_allclose(pred.activations(x[i]), want[i : i + 1], rtol=1e-5, atol=1e-5)


def test_phase_resample_puts_one_phase_per_position():
    """The output's cycle resampled to m points: a ramp over any cycle length stays that ramp, right-aligned
    with zeros before it; the relay channel is untouched; numpy's copy gives the same numbers."""
    from uavsim.learning.export import _phase_resample
    from uavsim.learning.model import phase_resample

    L, m = 40, 16
    x = np.zeros((4, 2, L), dtype=np.float32)
    for i, n in enumerate((40, 23, 7)):  # a full input and two padded ones
        x[i, 0, L - n:] = np.linspace(-1.0, 1.0, n)
        x[i, 1, L - n:] = np.where(np.arange(n) < n // 2, 1.0, -1.0)
    x[3, 0] = 5.0  # no cycle in the relay channel: no phase to read
    got = phase_resample(torch.from_numpy(x), m).numpy()
    for i in range(3):
        np.testing.assert_allclose(got[i, 0, L - m:], np.linspace(-1.0, 1.0, m), atol=1e-6)
    assert not got[:, 0, : L - m].any() and not got[3, 0].any()
    np.testing.assert_array_equal(got[:, 1], x[:, 1])
    np.testing.assert_array_equal(_phase_resample(x, m), got)
    same = phase_resample(torch.from_numpy(x[:1]), L).numpy()  # m = L on a full cycle: the samples themselves
    np.testing.assert_allclose(same, x[:1], atol=1e-6)


def test_phase_samples_train_export_and_refuse_too_many(tmp_path):
    """A net on phase-resampled cycles trains on the tiny set, and its exported folder says so (meta.json and
    weights.npz); more points than the set's input length is a one-line error."""
    rep = train(load_train_recipe(_recipe(tmp_path, net="phase_samples = 16")), quiet=True)
    assert rep["test"]["top1"] >= 0.9
    pred = Predictor(Path(rep["out"]))
    assert pred.meta["net"]["phase_samples"] == 16 and pred.numpy_layers["phase_samples"] == 16
    big = load_train_recipe(_recipe(tmp_path / "big", net="phase_samples = 100000"))
    with pytest.raises(UserError, match="phase_samples = 100000 exceeds"):
        train(big, quiet=True)
    assert not Path(big.out).exists()
