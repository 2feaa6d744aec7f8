"""Training-set files, format ``uavsim-dataset/1`` (HDF5), written and validated.

One file holds the network inputs of every kept episode of a recipe, their
labels and everything needed to interpret or regenerate them
(``docs/formats/dataset.md`` is the normative description):

* datasets, one row per kept episode (N rows): ``inputs`` (N, C, L) float32
  (chunked, gzip), ``labels`` (N,) int32, ``K`` (N,) true gain, ``bias`` (N,)
  command units, ``noise_kind`` (N,) int8 indexing attr ``noise_kinds``,
  ``noise_level`` (N,) float32 (noise amplitude / a0), ``period`` (N,) s and
  ``amplitude`` (N,) output units as measured by the preprocessing, and the rest
  of each episode's draws: ``y0``, ``tau_obs``, ``a_n``, ``episode`` (index in
  the recipe's plan), ``sim_seed`` (seed of the batch that simulated it),
  ``response_re``, ``response_im`` (N,) the fundamental response ``Y1 / (h U1)``
  and ``response_period`` (N,) s its cycle (``uavsim.data.preprocess``), and
  ``effects/<i>_<name>/<param>`` for randomized effect parameters; sets with
  episodes off the class centres (recipe ``randomize.offgrid``) add each
  episode's process ``process_T_prop``, ``process_T1``, ``process_tau`` (N,) s,
  ``offgrid`` (N,) bool and ``cost`` (N, n_classes): each class's table answer's
  cost on the episode's own process (``uavsim.data.costs``, attr ``cost_source``);
* group ``classes``: the class table, ``T_prop, T1, tau`` (``T2, tau`` for
  lateral), ``kp, kd, derivative_filter_hz, omega, amplitude, period``
  (n_classes,) from the grid (continuous-time cycle, K = 1, h = 1),
  ``grid_index``, and ``period_sim, amplitude_sim``: the cycle of a reference
  episode per class simulated at the data's control rate (K = 1, per unit h, no
  bias or noise; NaN if it failed), the scale to use for gain recovery; and
  dataset ``J`` (n_classes, n_classes), rows predicted;
* optional group ``raw``: ``y``, ``u`` (N, T) float32, NaN-padded, ``length`` (N,);
* attributes: ``format, loop, grid_hash, grid_version, beta, h, tau_obs, a_n,
  rate_hz, input_length, channels, recipe, seed, versions, git_commit,
  n_episodes, n_diverged, n_rejected`` and ``complete``, written last. Lateral
  sets are one file per attitude class, with attr ``att_class``.

Writers produce ``PATH.partial`` and rename it when complete, so a file at
``PATH`` is whole; ``open_dataset`` still checks everything and refuses a
corrupt or incomplete file with a ``UserError`` naming it and the problem.

    from uavsim.data.h5 import open_dataset
    ds = open_dataset("datasets/altitude.h5")
    ds.inputs.shape, ds.labels[:5], ds.n_classes, ds.J.shape, ds.attrs["seed"]
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from uavsim.errors import UserError

FORMAT = "uavsim-dataset/1"
#: per-episode datasets: name -> dtype (inputs checked separately)
EPISODE_FIELDS = {
    "labels": np.int32, "K": np.float64, "bias": np.float64, "noise_kind": np.int8, "noise_level": np.float32,
    "period": np.float64, "amplitude": np.float64, "y0": np.float64, "tau_obs": np.float64, "a_n": np.float64,
    "episode": np.int64, "sim_seed": np.uint32,
}
#: per-episode datasets that older files may lack (read when present)
OPTIONAL_EPISODE_FIELDS = {"response_re": np.float64, "response_im": np.float64, "response_period": np.float64,
                           "process_T_prop": np.float64, "process_T1": np.float64, "process_tau": np.float64,
                           "offgrid": np.bool_}
CLASS_FIELDS = ("kp", "kd", "derivative_filter_hz", "omega", "amplitude", "period")
CLASS_PARAMS = {"altitude": ("T_prop", "T1", "tau"), "attitude": ("T_prop", "T1", "tau"), "lateral": ("T2", "tau")}
REQUIRED_ATTRS = ("format", "loop", "grid_hash", "grid_version", "beta", "h", "tau_obs", "a_n", "rate_hz",
                  "input_length", "channels", "recipe", "seed", "versions", "git_commit", "n_episodes",
                  "n_diverged", "n_rejected", "noise_kinds")


def _attr(v: Any) -> Any:
    if isinstance(v, list | tuple):
        return np.array([str(x) for x in v], dtype=h5py.string_dtype())
    return v


def write_dataset(path: str | Path, episodes: dict[str, np.ndarray], classes: dict[str, np.ndarray],
                  J: np.ndarray, attrs: dict[str, Any], *, effects: dict[str, np.ndarray] | None = None,
                  raw: dict[str, np.ndarray] | None = None, cost: np.ndarray | None = None) -> Path:
    """Write a complete dataset at ``path`` (via ``path.partial``, renamed at the end).

    Parameters
    ----------
    path : output file
    episodes : ``inputs`` (N, C, L) float32 and every ``EPISODE_FIELDS`` entry, (N,)
    classes : the class table: ``CLASS_PARAMS[loop]`` and ``CLASS_FIELDS``, each (n_classes,)
    J : (n_classes, n_classes)
    attrs : every ``REQUIRED_ATTRS`` entry but ``format`` (``complete`` is added last)
    effects : optional ``"<i>_<name>/<param>" -> (N,)`` randomized effect parameters
    raw : optional ``y``, ``u`` (N, T) float32 and ``length`` (N,)
    cost : optional (N, n_classes) per-sample cost vectors (``uavsim.data.costs``)

    The bytes depend only on the arguments (no timestamps), so that the same
    recipe and seed give the same file.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    path.parent.mkdir(parents=True, exist_ok=True)
    X = np.ascontiguousarray(episodes["inputs"], dtype=np.float32)
    N = X.shape[0]
    kw = {"track_times": False}
    with h5py.File(tmp, "w", track_order=True) as f:
        f.attrs["format"] = FORMAT
        chunks = (max(1, min(N, 256)), X.shape[1], X.shape[2]) if N else None
        f.create_dataset("inputs", data=X, chunks=chunks, compression="gzip" if N else None,
                         compression_opts=4 if N else None, shuffle=bool(N), **kw)
        for name, dt in EPISODE_FIELDS.items():
            a = np.asarray(episodes[name], dtype=dt)
            if a.shape != (N,):
                raise ValueError(f"episode field {name} has shape {a.shape}, expected ({N},)")
            f.create_dataset(name, data=a, **kw)
        for name, dt in OPTIONAL_EPISODE_FIELDS.items():
            if name in episodes:
                a = np.asarray(episodes[name], dtype=dt)
                if a.shape != (N,):
                    raise ValueError(f"episode field {name} has shape {a.shape}, expected ({N},)")
                f.create_dataset(name, data=a, **kw)
        g = f.create_group("classes", track_order=True)
        for k, v in classes.items():
            g.create_dataset(k, data=np.asarray(v, dtype=np.float64), **kw)
        f.create_dataset("J", data=np.asarray(J, dtype=np.float64), **kw)
        if cost is not None:
            c = np.asarray(cost, dtype=np.float64)
            if c.shape != (N, np.shape(J)[0]):
                raise ValueError(f"cost has shape {c.shape}, expected ({N}, {np.shape(J)[0]})")
            f.create_dataset("cost", data=c, **kw)
        if effects:
            ge = f.create_group("effects", track_order=True)
            for k, v in effects.items():
                ge.create_dataset(k, data=np.asarray(v, dtype=np.float64), **kw)
        if raw is not None:
            gr = f.create_group("raw", track_order=True)
            for k in ("y", "u"):
                gr.create_dataset(k, data=np.asarray(raw[k], dtype=np.float32), compression="gzip",
                                  compression_opts=4, shuffle=True, **kw)
            gr.create_dataset("length", data=np.asarray(raw["length"], dtype=np.int64), **kw)
        for k, v in attrs.items():
            f.attrs[k] = _attr(v)
        f.attrs["complete"] = True
    tmp.replace(path)
    return path


@dataclass
class Dataset:
    """A validated ``uavsim-dataset/1`` file, loaded in memory.

    Attributes
    ----------
    path : the file
    inputs : (N, C, L) float32
    labels, K, bias, noise_kind, noise_level, period, amplitude, y0, tau_obs, a_n, episode, sim_seed : (N,)
    class_table : dict name -> (n_classes,) (grid parameters, gains, oscillation)
    J : (n_classes, n_classes), rows predicted, columns true
    attrs : dict of the file attributes (``versions`` parsed from JSON)
    effects : dict name -> (N,) randomized effect parameters
    raw : dict ``y``, ``u`` (N, T), ``length`` (N,), or None
    cost : (N, n_classes) per-sample cost vectors (sets with off-centre episodes), or None
    """

    path: Path
    inputs: np.ndarray
    fields: dict[str, np.ndarray]
    class_table: dict[str, np.ndarray]
    J: np.ndarray
    attrs: dict[str, Any]
    effects: dict[str, np.ndarray] = field(default_factory=dict)
    raw: dict[str, np.ndarray] | None = None
    cost: np.ndarray | None = None

    def __getattr__(self, name: str) -> np.ndarray:
        fields = self.__dict__.get("fields", {})
        if name in fields:
            return fields[name]
        raise AttributeError(name)

    @property
    def n(self) -> int:
        return self.inputs.shape[0]

    @property
    def n_classes(self) -> int:
        return self.J.shape[0]

    @property
    def noise_kinds(self) -> list[str]:
        return list(self.attrs["noise_kinds"])


def _bad(path: Path, msg: str) -> UserError:
    return UserError(f"dataset {path}: {msg}")


def _decode(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.ndarray) and v.dtype.kind in "OSU":
        return [x.decode() if isinstance(x, bytes) else str(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def open_dataset(path: str | Path) -> Dataset:
    """Read and validate a dataset file; UserError naming the file and the problem otherwise."""
    path = Path(path)
    if not path.exists():
        partial = path.with_name(path.name + ".partial")
        hint = " (an unfinished .partial exists: run the generation again to finish it)" if partial.exists() else ""
        raise _bad(path, f"no such file{hint}")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise _bad(path, f"not a readable HDF5 file ({exc})") from None
    try:
        with f:
            attrs = {k: _decode(v) for k, v in f.attrs.items()}
            if attrs.get("format") != FORMAT:
                raise _bad(path, f"format is {attrs.get('format')!r}, expected {FORMAT!r}")
            if attrs.get("complete") is not True:
                raise _bad(path, "incomplete (attribute complete is not true): the writer did not finish")
            missing = [a for a in REQUIRED_ATTRS if a not in attrs]
            if missing:
                raise _bad(path, f"missing attributes {', '.join(missing)}")
            loop = attrs["loop"]
            if loop not in CLASS_PARAMS:
                raise _bad(path, f"unknown loop {loop!r}")
            try:
                attrs["versions"] = json.loads(attrs["versions"])
            except (TypeError, ValueError):
                raise _bad(path, "attribute versions is not JSON") from None
            for name in ("inputs", "J", "classes", *EPISODE_FIELDS):
                if name not in f:
                    raise _bad(path, f"missing dataset {name!r}")
            X = f["inputs"]
            if X.ndim != 3 or X.dtype != np.float32:
                raise _bad(path, f"inputs must be (N, C, L) float32, got {X.shape} {X.dtype}")
            N, C, L = X.shape
            if L != attrs["input_length"] or C != len(attrs["channels"]):
                raise _bad(path, f"inputs shape {X.shape} disagrees with input_length {attrs['input_length']} "
                                 f"and channels {attrs['channels']}")
            fields = {}
            for name, dt in EPISODE_FIELDS.items():
                d = f[name]
                if d.shape != (N,):
                    raise _bad(path, f"dataset {name} has shape {d.shape}, expected ({N},)")
                fields[name] = d[()].astype(dt, copy=False)
            for name, dt in OPTIONAL_EPISODE_FIELDS.items():
                if name in f:
                    if f[name].shape != (N,):
                        raise _bad(path, f"dataset {name} has shape {f[name].shape}, expected ({N},)")
                    fields[name] = f[name][()].astype(dt, copy=False)
            g = f["classes"]
            table = {}
            for k in (*CLASS_PARAMS[loop], *CLASS_FIELDS):
                if k not in g:
                    raise _bad(path, f"missing class table column classes/{k}")
                table[k] = g[k][()]
            for k in g:  # optional columns (grid_index, period_sim, amplitude_sim)
                if k not in table and isinstance(g[k], h5py.Dataset):
                    table[k] = g[k][()]
            nc = len(table["kp"])
            if any(v.shape != (nc,) for v in table.values()):
                raise _bad(path, "class table columns have different lengths")
            J = f["J"][()]
            if J.shape != (nc, nc):
                raise _bad(path, f"J has shape {J.shape}, expected ({nc}, {nc})")
            labels = fields["labels"]
            if N and (labels.min() < 0 or labels.max() >= nc):
                raise _bad(path, f"labels outside 0..{nc - 1}")
            n_kinds = len(attrs["noise_kinds"])
            if N and (fields["noise_kind"].min() < 0 or fields["noise_kind"].max() >= n_kinds):
                raise _bad(path, "noise_kind outside the noise_kinds table")
            inputs = X[()]
            if not np.all(np.isfinite(inputs)):
                raise _bad(path, "inputs contain NaN or inf")
            effects = {}
            if "effects" in f:
                f["effects"].visititems(
                    lambda k, obj: effects.__setitem__(k, obj[()]) if isinstance(obj, h5py.Dataset) else None)
                for k, v in effects.items():
                    if v.shape != (N,):
                        raise _bad(path, f"effects/{k} has shape {v.shape}, expected ({N},)")
            cost = None
            if "cost" in f:
                cost = f["cost"][()]
                if cost.shape != (N, nc):
                    raise _bad(path, f"cost has shape {cost.shape}, expected ({N}, {nc})")
            raw = None
            if "raw" in f:
                raw = {k: f["raw"][k][()] for k in ("y", "u", "length") if k in f["raw"]}
                if len(raw) != 3 or raw["y"].shape[0] != N or raw["u"].shape != raw["y"].shape:
                    raise _bad(path, "raw group must hold y, u (N, T) and length (N,)")
    except UserError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise _bad(path, f"corrupt ({type(exc).__name__}: {exc})") from None
    return Dataset(path=path, inputs=inputs, fields=fields, class_table=table, J=J, attrs=attrs, effects=effects,
                   raw=raw, cost=cost)
