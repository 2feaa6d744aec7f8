"""Dask workers report their versions; generation refuses a cluster that runs another uavsim, MuJoCo or
numpy than the client, and records the workers' versions."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest

from uavsim.data.generate import cluster_versions, generate, versions
from uavsim.data.recipe import parse_recipe
from uavsim.errors import UserError

ROOT = Path(__file__).resolve().parents[1]


def _recipe(tmp_path):
    text = (ROOT / "datasets" / "small.toml").read_text()
    text = text.replace("per_class = 8", "per_class = 2").replace("chunk = 16", "chunk = 4")
    return parse_recipe(text, str(tmp_path / "d.toml"), "d")


def test_cluster_of_other_versions_is_refused_and_writes_nothing(tmp_path):
    distributed = pytest.importorskip("distributed")
    pre = tmp_path / "old_uavsim.py"
    # a worker whose uavsim is another release (set before any task runs, as an install would)
    pre.write_text("import uavsim\nuavsim.__version__ = '0.0.1'\n")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                                  preload=[str(pre)]) as cluster, distributed.Client(cluster) as client:
        theirs = list(client.run(versions).values())[0]
        assert theirs["uavsim"] == "0.0.1" and theirs["numpy"] == versions()["numpy"]
        with pytest.raises(UserError) as info:
            generate(_recipe(tmp_path), tmp_path / "d.h5", progress=False, client=client)
    msg = str(info.value)
    assert "\n" not in msg and "uavsim 0.0.1" in msg and f"uavsim {versions()['uavsim']}" in msg, msg
    assert "mujoco" not in msg  # only what differs is named
    assert not list(tmp_path.glob("d.h5*")) and not list(tmp_path.glob("*.resume"))


def test_matching_cluster_records_the_workers_versions(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        want = cluster_versions(client)
        pid_versions = list(client.run(versions).values())[0]
        out = tmp_path / "d.h5"
        generate(_recipe(tmp_path), out, progress=False, client=client)
    with h5py.File(out) as f:
        recorded = json.loads(f.attrs["versions"])
    assert recorded == want == {**pid_versions, "h5py": h5py.__version__}
