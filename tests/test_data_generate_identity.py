"""Generated training sets do not change with speed work: same recipe and seed, same arrays.

The digest covers every dataset and attribute of the file (its bytes, dtype and
shape), except the two that name the code that wrote it (``git_commit``,
``versions``). The reference digests were first recorded with the code before
the generation path was sped up (commit af50481), and recorded again when the
NP-MRFT settings rule changed (``SETTINGS_RULE`` 2: the floor on a refined
``a_n``), which changes the samples on purpose, and when the sets gained the
``trim_rule`` attribute (the same arrays and other attributes: the digests without
it were the previous ones), and when the tests pinned OpenBLAS's Haswell
kernels (the same code; under SkylakeX kernels the previous digests, 30c6ec7b...
and 29002b4f..., still come out); on the platform named in
``tests/_platform.py``: numpy's, MuJoCo's and the BLAS kernels' floating point
may differ by an ulp on another CPU or version, so elsewhere the check is
skipped with the reason.
"""

import hashlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from _platform import platform_differs

from uavsim.bench.generate import BENCH_RECIPE
from uavsim.data.generate import generate
from uavsim.data.recipe import load_recipe, parse_recipe
from uavsim.tuning.grid import load_grid

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "datasets" / "small.toml"
#: the code's identity, not the data's
SKIP_ATTRS = frozenset({"git_commit", "versions"})
SMALL_DIGEST = "e38c82667f33db20dd4ab65c204344da6826e38b935745a7267bd94e84014c94"
BENCH8_DIGEST = "1cde0c04fea8e84fcbb38c9bd1b72405bd3c68f12195a24d5b1c61416fedf4bb"


def _attr_bytes(v) -> bytes:
    a = np.asarray(v)
    if a.dtype.kind in "OUS":
        return repr(v).encode()
    return a.dtype.str.encode() + repr(a.shape).encode() + a.tobytes()


def h5_digest(path: Path) -> str:
    """SHA-256 of every dataset and attribute of an HDF5 file but ``SKIP_ATTRS``, in name order."""
    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        items = {"/": f}
        f.visititems(lambda name, obj: items.__setitem__(name, obj))
        for name in sorted(items):
            obj = items[name]
            h.update(name.encode())
            for k in sorted(obj.attrs):
                if k not in SKIP_ATTRS:
                    h.update(k.encode() + _attr_bytes(obj.attrs[k]))
            if isinstance(obj, h5py.Dataset):
                a = obj[()]
                h.update(a.dtype.str.encode() + repr(a.shape).encode() + np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def bench_recipe(n_classes: int = 8):
    g = load_grid("altitude")
    step = max(1, g.n // n_classes)
    classes = list(range(0, g.n, step))[:n_classes]
    return parse_recipe(BENCH_RECIPE.format(classes=classes, per_class=16, chunk=104), "bench.toml", "bench")


def test_digest_sees_every_array(tmp_path):
    # a control: the digest changes with one value of one dataset, and not with the commit
    p = tmp_path / "a.h5"
    with h5py.File(p, "w") as f:
        f.attrs["seed"], f.attrs["git_commit"] = 3, "abc"
        f.create_dataset("g/x", data=np.arange(4.0))
    d0 = h5_digest(p)
    with h5py.File(p, "a") as f:
        f.attrs["git_commit"] = "def"
    assert h5_digest(p) == d0
    with h5py.File(p, "a") as f:
        f["g/x"][2] = np.nextafter(2.0, 3.0)
    assert h5_digest(p) != d0


def test_small_set_unchanged(tmp_path):
    why = platform_differs()
    if why:
        pytest.skip(why)
    out = tmp_path / "small.h5"
    generate(load_recipe(SMALL), out, progress=False)
    assert h5_digest(out) == SMALL_DIGEST


@pytest.mark.slow
def test_bench_set_unchanged(tmp_path):
    why = platform_differs()
    if why:
        pytest.skip(why)
    out = tmp_path / "bench.h5"
    generate(bench_recipe(8), out, progress=False)
    assert h5_digest(out) == BENCH8_DIGEST


def test_noise_trace_block_is_the_per_sample_call():
    # the hover's one-call path: bit for bit the per-sample effect, quantized groups and samples past the trace
    from uavsim.data.noise_trace import NoiseTrace
    from uavsim.noise.models import make_noise

    n, T = 6, 50
    groups = [(np.array([0, 1]), make_noise("coloured", 1.0, np.array([0.1, 0.2]))),
              (np.array([2, 3]), make_noise("quantization", 1.0, np.array([0.05, 0.3]))),
              (np.array([4]), make_noise("outliers", 1.0, np.array([0.4])))]
    x = np.random.default_rng(1).normal(size=(T + 5, n))
    a, b = NoiseTrace(groups=groups, samples=T), NoiseTrace(groups=groups, samples=T)
    a.reset(n, 200.0, np.random.default_rng(2))
    b.reset(n, 200.0, np.random.default_rng(2))
    ref = np.stack([a(x[k], k) for k in range(T + 5)])
    assert np.array_equal(b.block(x), ref)
