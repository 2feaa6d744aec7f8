"""Export a trained network for embedded use, and the inference path that reads it.

An exported model is a folder with two files:

* ``model.pt``: the network in eval mode as TorchScript (BatchNorm's running
  statistics folded into the next Linear layer, Dropout gone), loadable with
  ``torch.jit.load`` alone;
* ``meta.json``: what identification needs without the training code: loop,
  grid hash, preprocessing (rate, input length, channels, beta), and the class
  table (time parameters, rule gains for K = 1, exact MRFT amplitude for K = 1, h = 1).

``Predictor`` needs only numpy, json and torch (no ``uavsim.learning.model``); it
reads the folded weights out of the TorchScript file and runs the network as a
numpy matmul chain (twice as fast as the TorchScript call on one input row), or
calls the TorchScript module for a structure it does not know:

    from uavsim.learning.export import Predictor
    pred = Predictor("training/runs/altitude")
    cls, act = pred.predict(x)            # x (B, C, L) float32 -> (B,) int64, (B, n) float32
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

__all__ = ["MODEL_FILE", "META_FILE", "META_FORMAT", "export_model", "Predictor"]

MODEL_FILE = "model.pt"
META_FILE = "meta.json"
META_FORMAT = "uavsim-model/1"


def _atomic_write_bytes(path: Path, writer) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def export_model(net: torch.nn.Module, meta: dict[str, Any], out_dir: str | os.PathLike) -> Path:
    """Write ``model.pt`` (TorchScript, eval mode, CPU) and ``meta.json`` into ``out_dir``.

    Parameters
    ----------
    net : nn.Module
        Network taking (B, C, L) float32 and returning (B, n_classes).
    meta : dict
        JSON-serializable description; must hold ``channels`` and ``input_length``.
    out_dir : path-like
        Target folder (created).

    Returns
    -------
    Path
        The folder.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    was_training = net.training
    net = net.eval()
    fold = getattr(net, "fold_batchnorm", None)  # uavsim's IdentNet: same outputs, fewer passes
    exported = fold() if fold is not None else net
    try:
        example = torch.zeros(2, int(meta["channels"]), int(meta["input_length"]))
        # TorchScript is deprecated upstream in favour of torch.export but is still the
        # artefact that loads with torch alone on embedded targets (and in C++ via libtorch)
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            scripted = torch.jit.trace(exported.cpu(), example)
            _atomic_write_bytes(out / MODEL_FILE, lambda p: torch.jit.save(scripted, p))
    finally:
        net.train(was_training)
    meta = dict(meta, format=META_FORMAT)
    _atomic_write_bytes(out / META_FILE, lambda p: Path(p).write_text(json.dumps(meta, indent=1)))
    return out


class Predictor:
    """Exported network + its metadata; numpy in, numpy out.

    Parameters
    ----------
    model_dir : path-like
        Folder written by ``export_model``.
    threads : int or None
        Torch intra-op threads (None: leave torch's setting). One thread is the
        embedded case and is what ``uavsim bench infer`` measures.
    """

    def __init__(self, model_dir: str | os.PathLike, threads: int | None = None):
        from uavsim.errors import UserError

        d = Path(model_dir)
        if not (d / MODEL_FILE).is_file() or not (d / META_FILE).is_file():
            raise UserError(f"no exported model in {d} (expected {MODEL_FILE} and {META_FILE}; run `uavsim train`)")
        try:
            self.meta: dict[str, Any] = json.loads((d / META_FILE).read_text())
        except ValueError as exc:
            raise UserError(f"{d / META_FILE}: not valid JSON ({exc})") from None
        if self.meta.get("format") != META_FORMAT:
            raise UserError(f"{d / META_FILE}: format {self.meta.get('format')!r}, expected {META_FORMAT!r}")
        if threads is not None:
            torch.set_num_threads(int(threads))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            self.module = torch.jit.load(str(d / MODEL_FILE), map_location="cpu").eval()
        self.dir = d
        self.channels = int(self.meta["channels"])
        self.input_length = int(self.meta["input_length"])
        self.numpy_layers = _numpy_layers(self.module, self.meta)

    @property
    def n_classes(self) -> int:
        return int(self.meta["n_classes"])

    def activations(self, x: np.ndarray) -> np.ndarray:
        """Network outputs (B, n_classes) float32 for inputs ``x`` (B, C, L) or (C, L)."""
        x = np.asarray(x, dtype=np.float32)
        if x.ndim == 2:
            x = x[None]
        if x.shape[1:] != (self.channels, self.input_length):
            raise ValueError(f"input shape {x.shape[1:]} != ({self.channels}, {self.input_length})")
        if self.numpy_layers is not None:
            return _forward_numpy(self.numpy_layers, x)
        with torch.inference_mode():
            return self.module(torch.from_numpy(np.ascontiguousarray(x))).numpy()

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted classes (B,) int64 (argmax of the class activations) and those activations (B, n)."""
        a = self.activations(x)
        return a.argmax(axis=1).astype(np.int64), a


def _numpy_layers(module, meta: dict[str, Any]) -> dict[str, Any] | None:
    """The folded network's weights as numpy, for ``_forward_numpy``; None for another structure.

    A single identification is one input row: there a matmul chain in numpy is
    about twice as fast as the TorchScript call (``uavsim bench infer``), with
    the same weights and the same float32 arithmetic.
    """
    layers = getattr(module, "layers", None)
    if layers is None:
        return None
    kinds = [c.original_name for c in layers.children()]
    if not kinds or kinds[-1] != "InputMajorLinear" or any(
            k != ("InputMajorLinear" if i % 2 == 0 else "ReLU") for i, k in enumerate(kinds)):
        return None
    Ws = [(np.ascontiguousarray(c.weight_t.detach().numpy(), dtype=np.float32),
           np.ascontiguousarray(c.bias.detach().numpy(), dtype=np.float32))
          for c in layers.children() if c.original_name == "InputMajorLinear"]
    # the first layer's width tells whether the period RBFs are there (IdentNet keeps a
    # one-entry ``centres`` buffer without them)
    k = Ws[0][0].shape[0] - int(meta["channels"]) * int(meta["input_length"])
    centres = dict(module.named_buffers()).get("centres")
    if k == 0:
        rbf = None
    elif k >= 2 and centres is not None and centres.numel() == k:
        # they sit on a linspace: their width is its step
        c = centres.detach().numpy().astype(np.float32)
        rbf = (c, np.float32(c[1] - c[0]))
    else:
        return None
    return {"layers": Ws, "rbf": rbf}


def _forward_numpy(net: dict[str, Any], x: np.ndarray) -> np.ndarray:
    """``IdentNet.forward`` of the folded network in numpy: x (B, C, L) float32 -> (B, n_classes) float32."""
    flat = x.reshape(x.shape[0], -1)
    if net["rbf"] is not None:
        c, w = net["rbf"]
        n = np.log(np.maximum(np.abs(x[:, -1, :]).sum(axis=1), np.float32(1.0)))
        flat = np.concatenate([flat, np.exp(np.float32(-0.5) * ((n[:, None] - c[None, :]) / w) ** 2)], axis=1)
    h = flat
    last = len(net["layers"]) - 1
    for j, (W, b) in enumerate(net["layers"]):
        h = h @ W
        h += b
        if j < last:
            np.maximum(h, np.float32(0.0), out=h)
    return h
