"""Dataset files: round trip, and refusal of corrupt or incomplete files with a clear message."""

import json

import h5py
import numpy as np
import pytest

from uavsim.data.h5 import CLASS_FIELDS, EPISODE_FIELDS, FORMAT, open_dataset, write_dataset
from uavsim.errors import UserError


def _content(N=5, nc=3, L=16):
    rng = np.random.default_rng(0)
    eps = {k: rng.integers(0, 2, N).astype(dt) for k, dt in EPISODE_FIELDS.items()}
    eps["labels"] = np.arange(N) % nc
    eps["inputs"] = rng.standard_normal((N, 2, L)).astype(np.float32)
    classes = {k: rng.random(nc) for k in ("T_prop", "T1", "tau", *CLASS_FIELDS)}
    attrs = {"loop": "altitude", "grid_hash": "abc", "grid_version": 1, "beta": -0.73, "h": 1.0, "tau_obs": 0.03,
             "a_n": 1.0, "rate_hz": 200.0, "input_length": L, "channels": ["y", "u"], "recipe": "seed = 1",
             "seed": 1, "versions": json.dumps({"numpy": np.__version__}), "git_commit": "unknown",
             "n_episodes": N + 1, "n_diverged": 1, "n_rejected": 0, "noise_kinds": ["none", "white"]}
    return eps, classes, rng.random((nc, nc)) + 1, attrs


def test_round_trip(tmp_path):
    eps, classes, J, attrs = _content()
    p = write_dataset(tmp_path / "d.h5", eps, classes, J, attrs, effects={"0_delay/delay": np.ones(5)})
    assert not (tmp_path / "d.h5.partial").exists()
    ds = open_dataset(p)
    assert ds.n == 5 and ds.n_classes == 3 and ds.inputs.dtype == np.float32
    np.testing.assert_array_equal(ds.inputs, eps["inputs"])
    np.testing.assert_array_equal(ds.labels, eps["labels"])
    np.testing.assert_array_equal(ds.J, J)
    assert ds.attrs["format"] == FORMAT and ds.attrs["complete"] is True and ds.attrs["versions"]["numpy"]
    assert ds.attrs["channels"] == ["y", "u"] and ds.noise_kinds == ["none", "white"]
    assert set(ds.class_table) >= {"T_prop", "kp", "period"} and ds.effects["0_delay/delay"].shape == (5,)
    with h5py.File(p) as f:
        assert f["inputs"].compression == "gzip" and f["inputs"].chunks is not None


def _break(path, how):
    with h5py.File(path, "a") as f:
        if how == "incomplete":
            f.attrs["complete"] = False
        elif how == "missing":
            del f["labels"]
        elif how == "shape":
            del f["K"]
            f["K"] = np.zeros(3)
        elif how == "format":
            f.attrs["format"] = "other/1"
        elif how == "nan":
            f["inputs"][0, 0, 0] = np.nan
        elif how == "labels":
            f["labels"][0] = 7
        elif how == "J":
            del f["J"]
            f["J"] = np.zeros((2, 2))
        elif how == "attr":
            del f.attrs["seed"]
        elif how == "class":
            del f["classes/kp"]


@pytest.mark.parametrize("how, needle", [
    ("incomplete", "incomplete"), ("missing", "missing dataset 'labels'"), ("shape", "K has shape"),
    ("format", "format"), ("nan", "NaN"), ("labels", "labels outside"), ("J", "J has shape"),
    ("attr", "missing attributes seed"), ("class", "classes/kp"),
])
def test_refuses_broken_files(tmp_path, how, needle):
    eps, classes, J, attrs = _content()
    p = write_dataset(tmp_path / "d.h5", eps, classes, J, attrs)
    _break(p, how)
    with pytest.raises(UserError, match="d.h5") as exc:
        open_dataset(p)
    assert needle in str(exc.value)


def test_refuses_garbage_and_missing(tmp_path):
    p = tmp_path / "junk.h5"
    p.write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(UserError, match="junk.h5.*not a readable HDF5"):
        open_dataset(p)
    (tmp_path / "x.h5.partial").write_bytes(b"")
    with pytest.raises(UserError, match="unfinished .partial"):
        open_dataset(tmp_path / "x.h5")
    # truncated: the first half of a valid file
    eps, classes, J, attrs = _content(N=300, L=64)
    good = write_dataset(tmp_path / "t.h5", eps, classes, J, attrs)
    data = good.read_bytes()
    good.write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match="t.h5"):
        open_dataset(good)
