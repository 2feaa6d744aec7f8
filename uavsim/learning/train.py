"""Training of the DNN-NP-MRFT classifiers from a TOML recipe.

A recipe (``training/*.toml``) names the dataset written by ``uavsim generate``
(``uavsim-dataset/1`` HDF5, see ``uavsim.data.h5``), the network shape and the
optimizer. Training follows the authors' code (NOTES.md section 2): Adam, lr
multiplied by ``lr_decay`` every ``lr_step_epochs``, a J-weighted loss
(``uavsim.learning.loss``). A seeded ``val_fraction`` of the set is held out for
early stopping on the validation **mean log J** (the closed-loop cost of the
answered class for the true one, in the loss's units), not on accuracy: two
wrong classes are not equally wrong. The answered class is the one
identification answers: least expected log J under the network's softmax
(``uavsim.learning.decision``, Bayes), unless the most likely class (argmax) has
the lower mean log J on the validation set (a belief too poor to weigh costs
with); both are reported (``*_bayes``, ``*_argmax``). The belief's temperature
is chosen on the validation set each epoch; the exported ``weights.npz`` carries the set's ``J`` and the best epoch's
temperature, ``meta.json`` its decision.

Every epoch writes ``OUT/checkpoint.pt`` (model, optimizer, schedule, RNG
states, history; atomically), so ``--resume`` continues exactly where an
interrupted run stopped. The best epoch is exported to ``OUT/model.pt`` +
``OUT/meta.json`` (``uavsim.learning.export``) and summarized in
``OUT/report.json``. Lateral recipes carry ``{att}`` in ``dataset`` and ``out``
and train one network per attitude class.

    uavsim train training/altitude.toml            # -> training/runs/altitude/
    uavsim train training/altitude.toml --resume

    from uavsim.learning.train import load_train_recipe, train
    report = train(load_train_recipe("training/small.toml"))
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import tempfile
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from uavsim.cpus import available_cpus
from uavsim.errors import UserError
from uavsim.learning.decision import clip_cost, decide, fit_temperature
from uavsim.learning.export import export_model
from uavsim.learning.loss import LOSS_KINDS, JWeightedLoss
from uavsim.learning.model import IdentNet, NetConfig

__all__ = [
    "TRAIN_FORMAT",
    "TrainRecipe",
    "TrainData",
    "load_train_recipe",
    "load_training_data",
    "class_metrics",
    "gain_metrics",
    "train",
    "train_from_recipe",
]

TRAIN_FORMAT = "uavsim-train/1"
CHECKPOINT = "checkpoint.pt"
REPORT = "report.json"
#: what the cross-entropy takes as a sample's class (``TrainRecipe.loss_target``)
LOSS_TARGETS = ("label", "best")
#: training curves (loss, validation mean J per epoch) beside the exported network
CURVES = "training.png"


@dataclass
class TrainRecipe:
    """A training recipe (one TOML file).

    Attributes
    ----------
    name : str
        Run name (reports).
    loop : str
        ``altitude``, ``attitude`` or ``lateral``.
    dataset : str
        Training set path (``{att}`` for lateral recipes); relative paths are
        relative to the recipe's folder's parent (the repository root for ``training/``).
    out : str
        Output folder for checkpoints and the exported model (``{att}`` for lateral).
    test_dataset : str
        Optional held-out set generated with other seeds ("" for none).
    attitude_classes : list of int or None
        Lateral only: which attitude classes to train (None: every one whose dataset exists).
    seed : int
        Seed of the split, initialization, shuffling and dropout.
    device : str
        ``auto`` (CUDA when present), ``cpu`` or ``cuda``.
    threads : int
        Torch CPU threads (0: all cores).
    hidden : list of int
        Hidden widths (paper: 3000, 1000).
    dropout : float
    period_features : int
        Radial-basis features of the cycle length appended to the input (``NetConfig``; 0: the paper's net).
    phase_samples : int
        Points the output channel's cycle is resampled to, one per phase (``NetConfig``; 0: the
        preprocessed samples as they are, the paper's input).
    lr : float
        Adam learning rate.
    lr_decay : float
        Factor applied every ``lr_step_epochs``.
    lr_step_epochs : int
    batch_size : int
    epochs : int
        Maximum epochs.
    weight_decay : float
    val_fraction : float
        Fraction of the set held out for early stopping (stratified by class).
    patience : int
        Epochs without a validation mean-log-J improvement before stopping.
    min_delta : float
        Improvement (in mean log J) that counts.
    max_minutes : float
        Wall-clock budget (0: none); training stops after the epoch that crosses it.
    loss_kind : str
        ``[loss] kind``: ``expected`` (cross-entropy plus the expected log J) or
        ``paper`` (the paper's J-weighted softmax); ``uavsim.learning.loss``.
    loss_weight : float
        ``[loss] weight``: the expected log J's weight.
    loss_target : str
        ``[loss] target``: the class the cross-entropy (and the stratified split, top-1) takes as
        each sample's: ``label`` (the set's) or ``best`` (the sample's least-cost class, from its
        own cost vector: sets with off-centre episodes, whose label is the nearest class, not
        always a good answer).
    source : str
        Path of the TOML file, for messages.
    """

    name: str
    loop: str
    dataset: str
    out: str
    test_dataset: str = ""
    attitude_classes: list[int] | None = None
    seed: int = 0
    device: str = "auto"
    threads: int = 0
    hidden: list[int] = field(default_factory=lambda: [3000, 1000])
    dropout: float = 0.4
    period_features: int = 0
    phase_samples: int = 0
    lr: float = 0.01
    lr_decay: float = 0.7
    lr_step_epochs: int = 20
    batch_size: int = 100
    epochs: int = 100
    weight_decay: float = 0.0
    val_fraction: float = 0.15
    patience: int = 10
    min_delta: float = 0.0
    max_minutes: float = 0.0
    loss_kind: str = "expected"
    loss_weight: float = 5.0
    loss_target: str = "label"
    source: str = ""

    def fingerprint(self) -> str:
        """Hash of everything that changes the result (resume refuses a different recipe)."""
        d = asdict(self)
        for k in ("source", "max_minutes", "threads", "device", "epochs", "patience"):
            d.pop(k)
        if d["loss_target"] == "label":  # the default: recipes written before it keep their fingerprint
            d.pop("loss_target")
        if not d["phase_samples"]:  # likewise
            d.pop("phase_samples")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


_SECTIONS = {
    "": ("format", "name", "loop", "dataset", "out", "test_dataset", "attitude_classes", "seed", "device", "threads"),
    "net": ("hidden", "dropout", "period_features", "phase_samples"),
    "optim": ("lr", "lr_decay", "lr_step_epochs", "batch_size", "epochs", "weight_decay"),
    "early_stopping": ("val_fraction", "patience", "min_delta", "max_minutes"),
    "loss": ("kind", "weight", "target"),
}
#: keys whose field carries their section's name (``[loss] kind`` is ``loss_kind``)
_PREFIXED = ("loss",)


def load_train_recipe(path: str | os.PathLike, overrides: dict[str, Any] | None = None) -> TrainRecipe:
    """Read and validate a training recipe; relative paths become absolute.

    ``overrides`` replaces fields after reading (tests, CLI).
    """
    p = Path(path)
    if not p.is_file():
        raise UserError(f"training recipe {p} not found")
    from uavsim.schema import load_toml

    doc = load_toml(p, "training")  # keys, types and ranges (uavsim.schema.training)
    flat: dict[str, Any] = {}
    for key, value in doc.items():
        if isinstance(value, dict):
            if key not in _SECTIONS or key == "":
                raise UserError(f"{p}: unknown section [{key}] (known: {', '.join(s for s in _SECTIONS if s)})")
            for k, v in value.items():
                if k not in _SECTIONS[key]:
                    raise UserError(f"{p}: unknown key {k!r} in [{key}] (known: {', '.join(_SECTIONS[key])})")
                flat[f"{key}_{k}" if key in _PREFIXED else k] = v
        elif key in _SECTIONS[""]:
            flat[key] = value
        else:
            raise UserError(f"{p}: unknown key {key!r}")
    fmt = flat.pop("format", TRAIN_FORMAT)
    if fmt != TRAIN_FORMAT:
        raise UserError(f"{p}: format {fmt!r}, expected {TRAIN_FORMAT!r}")
    for k in ("name", "loop", "dataset", "out"):
        if k not in flat:
            raise UserError(f"{p}: missing key {k!r}")
    flat.update(overrides or {})
    try:
        r = TrainRecipe(source=str(p), **flat)
    except TypeError as exc:
        raise UserError(f"{p}: {exc}") from None
    # Paths in training/*.toml are written relative to the repository root.
    root = p.resolve().parent.parent
    for k in ("dataset", "out", "test_dataset"):
        v = getattr(r, k)
        if v and not Path(v).is_absolute():
            setattr(r, k, str(root / v))
    _check_recipe(r)
    return r


def _check_recipe(r: TrainRecipe) -> None:
    where = r.source or "recipe"
    if r.loop not in ("altitude", "attitude", "lateral"):
        raise UserError(f"{where}: loop must be altitude, attitude or lateral, got {r.loop!r}")
    if r.device not in ("auto", "cpu", "cuda"):
        raise UserError(f"{where}: device must be auto, cpu or cuda, got {r.device!r}")
    checks = [
        ("lr", r.lr > 0), ("lr_decay", 0 < r.lr_decay <= 1), ("lr_step_epochs", r.lr_step_epochs >= 1),
        ("batch_size", r.batch_size >= 2), ("epochs", r.epochs >= 1), ("dropout", 0 <= r.dropout < 1),
        ("val_fraction", 0 < r.val_fraction < 1), ("patience", r.patience >= 1), ("max_minutes", r.max_minutes >= 0),
        ("hidden", isinstance(r.hidden, list) and all(isinstance(h, int) and h > 0 for h in r.hidden)),
        ("threads", r.threads >= 0), ("weight_decay", r.weight_decay >= 0),
        ("period_features", r.period_features >= 0), ("phase_samples", r.phase_samples >= 0),
        ("loss_kind", r.loss_kind in LOSS_KINDS),
        ("loss_weight", r.loss_weight >= 0), ("loss_target", r.loss_target in LOSS_TARGETS),
    ]
    for name, ok in checks:
        if not ok:
            raise UserError(f"{where}: invalid {name} = {getattr(r, name)!r}")
    if r.loop == "lateral" and "{att" not in r.dataset:
        raise UserError(f"{where}: a lateral recipe needs '{{att}}' in dataset (one network per attitude class)")


# ---------------------------------------------------------------- data ------------


@dataclass
class TrainData:
    """A dataset in memory.

    Attributes
    ----------
    X : (N, C, L) float32 preprocessed cycles
    labels : (N,) int64 classes
    J : (n, n) float64 relative sensitivity (rows predicted, columns true)
    attrs : dict of the file's attributes (loop, grid_hash, beta, rate_hz, ...)
    classes : dict name -> (n,) array (class table: time parameters, gains, amplitude, ...)
    K : (N,) true gains or None
    response : (N,) complex fundamental response (``uavsim.data.preprocess``) or None
    response_period : (N,) s or None
    cost : (N, n) each sample's own cost of every answer (sets with off-centre episodes,
        ``uavsim.data.costs``) or None: then the cost of answer ``i`` for a sample of class ``l`` is ``J[i, l]``
    """

    X: np.ndarray
    labels: np.ndarray
    J: np.ndarray
    attrs: dict[str, Any]
    classes: dict[str, np.ndarray]
    K: np.ndarray | None = None
    response: np.ndarray | None = None
    response_period: np.ndarray | None = None
    cost: np.ndarray | None = None

    @property
    def n_classes(self) -> int:
        return int(self.J.shape[0])

    def costs(self, idx: np.ndarray) -> np.ndarray:
        """(m, n) cost of every answer for samples ``idx``: their own cost vectors, else ``J``'s columns."""
        if self.cost is not None:
            return self.cost[idx]
        return self.J[:, self.labels[idx]].T


def _attr(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def load_training_data(path: str | os.PathLike) -> TrainData:
    """Read a ``uavsim-dataset/1`` file through ``uavsim.data.h5.open_dataset`` (validated)."""
    from uavsim.data.h5 import open_dataset

    p = Path(path)
    if not p.is_file():
        raise UserError(f"dataset {p} not found (run `uavsim generate` / `make generate-data` first)")
    ds = open_dataset(p)
    attrs = {k: _attr(v) for k, v in dict(ds.attrs).items()}
    classes = {k: np.asarray(v) for k, v in dict(ds.class_table).items()}
    X = np.asarray(ds.inputs, dtype=np.float32)
    labels = np.asarray(ds.labels).astype(np.int64)
    J = np.asarray(ds.J, dtype=np.float64)
    response = response_period = None
    if "response_re" in ds.fields:  # sets written before the response was recorded lack it
        response = ds.response_re + 1j * ds.response_im
        response_period = np.asarray(ds.response_period, dtype=np.float64)
    n = J.shape[0]
    if X.ndim != 3 or labels.shape != (X.shape[0],) or J.shape != (n, n):
        raise UserError(f"{p}: inconsistent shapes inputs {X.shape}, labels {labels.shape}, J {J.shape}")
    cost = None if ds.cost is None else np.asarray(ds.cost, dtype=np.float64)
    return TrainData(X, labels, J, attrs, classes, np.asarray(ds.K, dtype=np.float64), response, response_period,
                     cost)


def best_classes(data: TrainData, where: str = "dataset") -> np.ndarray:
    """Each sample's least-cost class, (N,) int64 (ties: the lowest index); the set must have costs."""
    if data.cost is None:
        raise UserError(f"{where}: [loss] target = \"best\" needs a set with per-sample costs "
                        "(a recipe with randomize.offgrid)")
    C = np.where(np.isfinite(data.cost), data.cost, np.inf)
    best = C.argmin(axis=1).astype(np.int64)
    none = ~np.isfinite(C).any(axis=1)  # no finite cost: keep the set's label
    best[none] = data.labels[none]
    return best


def class_metrics(pred: np.ndarray, true: np.ndarray, J: np.ndarray, costs: np.ndarray | None = None
                  ) -> dict[str, float]:
    """Top-1 accuracy and mean / p95 of ``J[pred, true]`` (clipped to [1, 1e3]).

    Parameters
    ----------
    pred, true : (N,) int class indices
    J : (n, n) rows predicted, columns true
    costs : (N, n), optional: each sample's own costs, ``costs[k, pred[k]]`` in place of ``J[pred, true]``
    """
    pred = np.asarray(pred, dtype=np.int64)
    true = np.asarray(true, dtype=np.int64)
    if pred.size == 0:
        return {"n": 0, "top1": float("nan"), "mean_J": float("nan"), "p95_J": float("nan"), "max_J": float("nan")}
    j = J[pred, true] if costs is None else np.asarray(costs)[np.arange(pred.size), pred]
    j = clip_cost(j)
    return {
        "n": int(pred.size),
        "top1": float(np.mean(pred == true)),
        "mean_J": float(j.mean()),
        "p95_J": float(np.percentile(j, 95)),
        "max_J": float(j.max()),
    }


def gain_metrics(pred: np.ndarray, data: TrainData, idx: np.ndarray) -> dict[str, float]:
    """Error of the gains identification answers, ``|kp / kp_true - 1|`` and the same for kd (median, p95).

    For samples ``idx`` predicted as ``pred``: the table's robust PD of the predicted class over
    the gain fitted to the sample's measured response with that class's lags (``uavsim.ident``),
    against the true class's over the true ``K``. Empty when the set has no response or no table
    (older files) or is lateral.
    """
    from uavsim.ident.response import fit_response

    loop = data.attrs.get("loop")
    c = data.classes
    if (len(pred) == 0 or data.response is None or data.K is None or loop not in ("altitude", "attitude")
            or "table_robust_kp" not in c):
        return {}
    K_hat = fit_response(data.response[idx], data.response_period[idx], T_prop=c["T_prop"][pred], T1=c["T1"][pred],
                         tau_class=c["tau"][pred])["K"]
    out = {}
    for k in ("kp", "kd"):
        col = np.asarray(c[f"table_robust_{k}"], dtype=np.float64)
        e = np.abs((col[pred] / K_hat) / (col[data.labels[idx]] / data.K[idx]) - 1.0)
        out.update({f"{k}_err_median": float(np.median(e)), f"{k}_err_p95": float(np.percentile(e, 95))})
    return out


def _split(labels: np.ndarray, frac: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Stratified split: about ``frac`` of each class to validation (at least 1 if the class has 2+)."""
    rng = np.random.default_rng(seed)
    tr, va = [], []
    for c in np.unique(labels):
        idx = rng.permutation(np.flatnonzero(labels == c))
        k = int(round(frac * idx.size))
        if idx.size >= 2:
            k = min(max(k, 1), idx.size - 1)
        else:
            k = 0
        va.append(idx[:k])
        tr.append(idx[k:])
    return np.sort(np.concatenate(tr)), np.sort(np.concatenate(va))


# ---------------------------------------------------------------- training --------


def _device(name: str) -> torch.device:
    if name == "cuda" and not torch.cuda.is_available():
        raise UserError("recipe asks for device = 'cuda' but no CUDA device is available")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name)


def _atomic_save(obj: Any, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _activations(net: IdentNet, X: torch.Tensor, device: torch.device, batch: int = 2048) -> np.ndarray:
    """The network's activations (N, n_classes) float32."""
    net.eval()
    act = []
    with torch.inference_mode():
        for i in range(0, X.shape[0], batch):
            act.append(net(X[i : i + batch].to(device)).float().cpu())
    return torch.cat(act).numpy()


def _progress(iterable, **kw):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return iterable
    return tqdm(iterable, file=sys.stderr, leave=False, dynamic_ncols=True, disable=kw.pop("quiet", False), **kw)


def _grid_pm(attrs: dict[str, Any]) -> float | None:
    """Phase margin (deg) of the rule of the dataset's grid, when that grid is the installed one."""
    from uavsim.tuning.grid import load_grid

    if attrs.get("loop") not in ("altitude", "attitude"):
        return None
    try:
        g = load_grid(attrs["loop"])
    except UserError:
        return None
    return float(g.pm_deg) if g.hash == attrs.get("grid_hash") else None


def _class_meta(data: TrainData, recipe: TrainRecipe, cfg: NetConfig) -> dict[str, Any]:
    """What identification needs, stored beside the exported network."""
    a = data.attrs
    cycles, bias_trim = 1, "off"
    try:  # cycles per input and the relay's bias trim, from the dataset recipe (identification must match)
        doc = tomllib.loads(str(a.get("recipe", "")))
        cycles = int(doc.get("preprocess", {}).get("cycles", 1))
        bias_trim = str(doc.get("test", {}).get("bias_trim", "off"))
    except (tomllib.TOMLDecodeError, TypeError, ValueError):
        pass
    from uavsim.learning.bundle import bundle_section

    cyc = int(a.get("cycles_per_input", cycles))
    ident = bundle_section(loop=a.get("loop", recipe.loop), grid_hash=str(a.get("grid_hash", "")),
                           rate_hz=float(a.get("rate_hz") or 200.0), beta=a.get("beta"),
                           input_length=cfg.input_length, cycles=cyc,
                           att_class=int(a["att_class"]) if a.get("att_class") is not None else None,
                           bias_trim=bias_trim)
    return {
        "identification": ident,
        "cycles": cyc,
        "name": recipe.name,
        "loop": a.get("loop", recipe.loop),
        "grid_hash": a.get("grid_hash", ""),
        "att_class": int(a["att_class"]) if a.get("att_class") is not None else None,  # lateral: its sub-grid
        "beta": a.get("beta"),
        "pm_deg": _grid_pm(a),
        "h": a.get("h", 1.0),
        "rate_hz": a.get("rate_hz"),
        "channels": cfg.channels,
        "input_length": cfg.input_length,
        "n_classes": cfg.n_classes,
        "net": cfg.as_dict(),
        "classes": {k: np.asarray(v).tolist() for k, v in data.classes.items()},
        "dataset": {"path": recipe.dataset, "seed": a.get("seed"), "recipe": a.get("recipe")},
        "seed": recipe.seed,
        "recipe_fingerprint": recipe.fingerprint(),
    }


#: belief temperatures tried beside the NLL-fitted one (``_val_metrics``)
TEMPERATURES = (0.5, 1.0, 2.0)


def _val_metrics(net: IdentNet, X: torch.Tensor, idx: np.ndarray, data: TrainData, device: torch.device, *,
                 temperature: float | None = None, decision: str | None = None) -> dict[str, Any]:
    """Metrics of identification's class decision, and of both decisions beside them (``*_bayes``, ``*_argmax``).

    ``temperature``: the belief's (``uavsim.learning.decision``); None tries the NLL-fitted one
    and ``TEMPERATURES`` and keeps the one whose Bayes answers have the least mean log J.
    ``decision``: ``bayes`` or ``argmax``; None takes Bayes unless argmax has the lower mean
    log J on this set (validation: what the best epoch exports; the test set gets the exported
    ones). Mean log J, the loss's cost, rather than mean J: with unstable answers at 1e3 the mean
    J of a set of a thousand is decided by one or two inputs.
    """
    true = data.labels[idx]
    if X.shape[0] == 0:
        return class_metrics(np.zeros(0, np.int64), true, data.J)
    act = _activations(net, X, device)
    C = data.costs(idx)  # (m, n): the samples' own costs, or J's columns
    logC = np.log(clip_cost(C))  # the decision's cost per sample (``log_cost``'s, row by row)
    rows = np.arange(len(idx))

    def cost(cls: np.ndarray) -> float:
        return float(logC[rows, cls].mean())

    temps = (fit_temperature(act, true), *TEMPERATURES) if temperature is None else (float(temperature),)
    bayes = {t: decide(act, data.J, temperature=t).cls for t in temps}
    T = min(temps, key=lambda t: cost(bayes[t]))
    pred = {"bayes": bayes[T], "argmax": act.argmax(axis=1).astype(np.int64)}
    m = {d: class_metrics(c, true, data.J, None if data.cost is None else C) for d, c in pred.items()}
    if decision is None:
        decision = "bayes" if cost(pred["bayes"]) <= cost(pred["argmax"]) else "argmax"
    return {**m[decision], **gain_metrics(pred[decision], data, idx),
            **{f"{k}_{d}": m[d][k] for d in pred for k in ("top1", "mean_J", "p95_J")},
            **{f"mean_log_J_{d}": cost(c) for d, c in pred.items()}, "mean_log_J": cost(pred[decision]),
            "temperature": T, "decision": decision}


def train(recipe: TrainRecipe, resume: bool = False, quiet: bool = False) -> dict[str, Any]:
    """Train one network (non-lateral recipe, or a lateral one with ``{att}`` filled in).

    Returns
    -------
    dict
        The report written to ``OUT/report.json``: epochs, wall time (s), best
        epoch, validation and test metrics (``class_metrics``), paths.
    """
    if "{att" in recipe.dataset:
        raise UserError("lateral recipes train one network per attitude class: use train_from_recipe")
    data = load_training_data(recipe.dataset)
    if recipe.loss_target == "best":
        data.labels = best_classes(data, recipe.dataset)
    N, C, L = data.X.shape
    if N < 2 * data.n_classes and N < 10:
        raise UserError(f"{recipe.dataset}: only {N} samples for {data.n_classes} classes")
    if recipe.phase_samples > L:
        raise UserError(f"{recipe.source or 'recipe'}: phase_samples = {recipe.phase_samples} exceeds the set's "
                        f"input length {L}")
    # made once the recipe and its set are known to fit: a refused run leaves no empty folder
    out = Path(recipe.out)
    out.mkdir(parents=True, exist_ok=True)
    seed = int(recipe.seed)
    torch.manual_seed(seed)
    # 0: the CPUs this process may use (torch's own default counts the host's)
    torch.set_num_threads(recipe.threads or available_cpus())
    device = _device(recipe.device)
    tr_idx, va_idx = _split(data.labels, recipe.val_fraction, seed)
    Xtr = torch.from_numpy(data.X[tr_idx])
    ytr = torch.from_numpy(data.labels[tr_idx])
    # the samples' own cost vectors where the set has them (off-centre episodes), else the loss's J
    ctr = None if data.cost is None else torch.from_numpy(data.cost[tr_idx].astype(np.float32))
    Xva = torch.from_numpy(data.X[va_idx])
    if device.type == "cuda":
        Xtr, ytr = Xtr.to(device), ytr.to(device)

    cfg = NetConfig(C, L, data.n_classes, list(recipe.hidden), recipe.dropout,
                    period_features=recipe.period_features, phase_samples=recipe.phase_samples)
    net = IdentNet(cfg).to(device)
    loss_fn = JWeightedLoss(data.J, kind=recipe.loss_kind, weight=recipe.loss_weight).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=recipe.lr_step_epochs, gamma=recipe.lr_decay)
    gen = torch.Generator().manual_seed(seed)

    history: list[dict[str, float]] = []
    start_epoch, elapsed = 0, 0.0
    best = {"mean_log_J": math.inf, "epoch": -1}
    best_state: dict[str, torch.Tensor] | None = None
    ck_path = out / CHECKPOINT
    if resume and ck_path.is_file():
        ck = torch.load(ck_path, map_location=device, weights_only=False)
        if ck.get("fingerprint") != recipe.fingerprint():
            raise UserError(f"{ck_path} was written by a different recipe; remove it or train without --resume")
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optim"])
        sched.load_state_dict(ck["sched"])
        gen.set_state(ck["gen"])
        torch.set_rng_state(ck["torch_rng"])
        history, best, elapsed = ck["history"], ck["best"], ck["elapsed"]
        best_state = ck["best_state"]
        start_epoch = ck["epoch"] + 1
        if not quiet:
            print(f"resuming {recipe.name} at epoch {start_epoch} (best mean log J {best.get('mean_log_J', math.nan):.4f})", file=sys.stderr)
    elif resume and not quiet:
        print(f"no checkpoint at {ck_path}: starting from scratch", file=sys.stderr)

    stale = len(history) - 1 - best["epoch"] if best["epoch"] >= 0 else 0
    stopped = "epochs"
    t0 = time.perf_counter() - elapsed
    for epoch in range(start_epoch, recipe.epochs):
        if stale >= recipe.patience:
            stopped = "early_stopping"
            break
        if recipe.max_minutes and (time.perf_counter() - t0) > 60 * recipe.max_minutes:
            stopped = "max_minutes"
            break
        net.train()
        perm = torch.randperm(Xtr.shape[0], generator=gen)
        nb = max(1, Xtr.shape[0] // recipe.batch_size)  # drop the ragged last batch (BatchNorm needs > 1)
        total = 0.0
        bar = _progress(range(nb), desc=f"{recipe.name} epoch {epoch + 1}/{recipe.epochs}", quiet=quiet)
        for b in bar:
            idx = perm[b * recipe.batch_size : (b + 1) * recipe.batch_size]
            xb, yb = Xtr[idx].to(device, non_blocking=True), ytr[idx].to(device, non_blocking=True)
            opt.zero_grad(set_to_none=True)
            cb = None if ctr is None else ctr[idx].to(device, non_blocking=True)
            loss = loss_fn(net(xb), yb, cb)
            loss.backward()
            opt.step()
            total += float(loss.detach())
        sched.step()
        vm = _val_metrics(net, Xva, va_idx, data, device)
        rec = {"epoch": epoch, "loss": total / nb, "lr": opt.param_groups[0]["lr"], **{f"val_{k}": v for k, v in vm.items()},
               "elapsed_s": time.perf_counter() - t0}
        history.append(rec)
        # the best epoch by mean log J (the loss's cost): mean J is decided by the one or two
        # inputs of a thousand whose answer is unstable (J clipped to 1e3)
        if vm["mean_log_J"] < best.get("mean_log_J", math.inf) - recipe.min_delta:
            best = {"mean_log_J": vm["mean_log_J"], "epoch": epoch, **{f"val_{k}": v for k, v in vm.items()}}
            best_state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
            stale = 0
        else:
            stale += 1
        if not quiet:
            print(f"{recipe.name} epoch {epoch + 1}: loss {rec['loss']:.4f}  val top1 {vm['top1']:.3f}  "
                  f"mean J {vm['mean_J']:.4f} ({vm.get('decision', '-')}; argmax {vm.get('mean_J_argmax', math.nan):.4f})  p95 J {vm['p95_J']:.3f}  kp err median {vm.get('kp_err_median', math.nan):.3f}  "
                  f"({rec['elapsed_s']:.0f} s)", file=sys.stderr)
        _atomic_save({
            "fingerprint": recipe.fingerprint(), "epoch": epoch, "model": net.state_dict(), "optim": opt.state_dict(),
            "sched": sched.state_dict(), "gen": gen.get_state(), "torch_rng": torch.get_rng_state(),
            "history": history, "best": best, "best_state": best_state, "elapsed": time.perf_counter() - t0,
            "net": cfg.as_dict(),
        }, ck_path)
    train_s = time.perf_counter() - t0
    if best_state is None:
        raise UserError(f"{recipe.name}: no epoch finished")
    net.load_state_dict(best_state)
    net.cpu()
    meta = _class_meta(data, recipe, cfg)
    meta.update({"best_epoch": best["epoch"], "val": {k[4:]: v for k, v in best.items() if k.startswith("val_")}})
    if "decision" not in meta["val"]:  # a best epoch from a checkpoint written before the decision existed
        meta["val"] = _val_metrics(net, Xva, va_idx, data, torch.device("cpu"))
    T_best, decision = float(meta["val"]["temperature"]), str(meta["val"]["decision"])
    meta["identification"]["class_decision"]["decision"] = decision
    export_model(net, meta, out, arrays={"J": data.J, "temperature": np.float64(T_best)})
    from uavsim.learning.figures import training_curves_png

    training_curves_png(history, out / CURVES, title=f"{recipe.name}: {cfg.n_classes} {meta['loop']} classes, "
                        f"{int(tr_idx.size)} training inputs", best_epoch=best["epoch"])

    report: dict[str, Any] = {
        "name": recipe.name, "loop": meta["loop"], "n_classes": cfg.n_classes, "n_train": int(tr_idx.size),
        "n_val": int(va_idx.size), "input": [C, L], "epochs_run": len(history), "stopped": stopped,
        "best_epoch": best["epoch"], "train_time_s": train_s, "device": device.type,
        "threads": torch.get_num_threads(), "seed": seed, "val": meta["val"], "out": str(out),
        "dataset": recipe.dataset, "curves": str(out / CURVES),
        "history": [{k: h[k] for k in ("epoch", "loss", "val_mean_J", "val_top1", "val_decision", "val_mean_J_bayes",
                                             "val_mean_J_argmax") if k in h}
                    for h in history],
    }
    if recipe.test_dataset and not Path(recipe.test_dataset).is_file():
        # a missing held-out set must not throw away a finished training run
        print(f"warning: held-out set {recipe.test_dataset} not found; no test metrics", file=sys.stderr)
    elif recipe.test_dataset:
        test = load_training_data(recipe.test_dataset)
        if test.attrs.get("grid_hash") != data.attrs.get("grid_hash"):
            raise UserError(f"{recipe.test_dataset}: grid differs from the training set's")
        gi, gt = data.classes.get("grid_index"), test.classes.get("grid_index")
        if gi is not None and gt is not None and not np.array_equal(gi, gt):
            raise UserError(f"{recipe.test_dataset}: class subset differs from the training set's")
        report["test"] = _val_metrics(net, torch.from_numpy(test.X), np.arange(len(test.labels)), test,
                                      torch.device("cpu"), temperature=T_best, decision=decision)
        report["test_dataset"] = recipe.test_dataset
    Path(out / REPORT).write_text(json.dumps(report, indent=1))
    return report


def train_from_recipe(path: str | os.PathLike, resume: bool = False, quiet: bool = False,
                      overrides: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """Train every network of a recipe (one, or one per attitude class for lateral); return the reports."""
    r = load_train_recipe(path, overrides)
    if "{att" not in r.dataset:
        return [train(r, resume=resume, quiet=quiet)]
    from uavsim.tuning.grid import load_grid

    n_att = load_grid("attitude").n
    classes = r.attitude_classes if r.attitude_classes is not None else list(range(n_att))
    reports = []
    for a in classes:
        ds = r.dataset.format(att=a)
        if r.attitude_classes is None and not Path(ds).is_file():
            continue
        sub = TrainRecipe(**{**asdict(r), "name": f"{r.name}-att{a:02d}", "dataset": ds, "out": r.out.format(att=a),
                             "test_dataset": r.test_dataset.format(att=a) if r.test_dataset else ""})
        reports.append(train(sub, resume=resume, quiet=quiet))
    if not reports:
        raise UserError(f"{r.source}: no lateral dataset matches {r.dataset} (lateral grids and data come first)")
    return reports
