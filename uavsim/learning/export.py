"""Export a trained network for embedded use, and the inference path that reads it.

An exported model is a folder:

* ``weights.npz``: the folded network (BatchNorm's running statistics folded into
  the next Linear layer, Dropout gone) as plain float32 arrays: ``W0, b0, W1, ...``
  stored input-major ``(in, out)``, the period features' ``rbf_centres`` and
  ``rbf_width``, and ``phase_samples`` (the output channel's cycle resampled to that
  many points before the first layer, ``uavsim.learning.model.phase_resample``; 0 or
  absent: none). numpy alone runs it (``Predictor``); this is what identification uses.
  It also holds the arrays the trainer hands over for identification (``J``: the
  cost matrix of the class decision, ``uavsim.ident.select``);
* ``model.onnx``: the same network for ONNX runtimes (opset 17, dynamic batch),
  input ``x`` (B, C, L) float32, output ``activations`` (B, n_classes);
* ``model.pt``: the same network as TorchScript, for libtorch;
* ``meta.json``: what identification needs without the training code: loop,
  grid hash, preprocessing (rate, input length, channels, beta), and the class
  table (time parameters, rule gains for K = 1, exact MRFT amplitude for K = 1, h = 1).

Importing this module and using ``Predictor`` needs numpy only: torch is imported
by ``export_model`` (training) and only when a folder exported before
``weights.npz`` existed is read (``python -m uavsim.learning.export DIR`` adds
the file to such a folder, where torch is installed):

    from uavsim.learning.export import Predictor
    pred = Predictor("training/runs/altitude")
    cls, act = pred.predict(x)            # x (B, C, L) float32 -> (B,) int64, (B, n) float32
"""

from __future__ import annotations

import io
import json
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError

__all__ = ["MODEL_FILE", "META_FILE", "META_FORMAT", "WEIGHTS_FILE", "WEIGHTS_FORMAT", "ONNX_FILE",
           "export_model", "write_weights", "Predictor"]

MODEL_FILE = "model.pt"
META_FILE = "meta.json"
META_FORMAT = "uavsim-model/1"
WEIGHTS_FILE = "weights.npz"
WEIGHTS_FORMAT = "uavsim-weights/1"
ONNX_FILE = "model.onnx"
ONNX_OPSET = 17


def _atomic_write_bytes(path: Path, writer) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def export_model(net, meta: dict[str, Any], out_dir: str | os.PathLike, *,
                 arrays: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``weights.npz``, ``model.onnx``, ``model.pt`` (TorchScript) and ``meta.json`` into ``out_dir``.

    Parameters
    ----------
    net : torch.nn.Module
        Network taking (B, C, L) float32 and returning (B, n_classes); an ``IdentNet``
        is folded (``fold_batchnorm``) first. ``weights.npz`` is written for the
        structure ``Predictor`` runs in numpy (linear layers with ReLUs between, optional
        period features); another structure gets only the TorchScript and ONNX files.
    meta : dict
        JSON-serializable description; must hold ``channels`` and ``input_length``.
    out_dir : path-like
        Target folder (created).
    arrays : dict or None
        More float arrays stored in ``weights.npz`` beside the network (e.g. ``J``).

    Returns
    -------
    Path
        The folder.
    """
    import torch

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    was_training = net.training
    net = net.eval()
    fold = getattr(net, "fold_batchnorm", None)  # uavsim's IdentNet: same outputs, fewer passes
    exported = fold() if fold is not None else net
    files = [MODEL_FILE, ONNX_FILE]
    try:
        example = torch.zeros(2, int(meta["channels"]), int(meta["input_length"]))
        # TorchScript is deprecated upstream in favour of torch.export but is still the
        # artefact that loads with torch alone on embedded targets (and in C++ via libtorch)
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            scripted = torch.jit.trace(exported.cpu(), example)
            _atomic_write_bytes(out / MODEL_FILE, lambda p: torch.jit.save(scripted, p))
            try:
                onnx = _onnx_bytes(exported.cpu(), example)
            except Exception as exc:  # noqa: BLE001 - an exporter gone from a newer torch must not lose the run
                print(f"warning: no {ONNX_FILE} ({type(exc).__name__}: {exc}); the other files are complete",
                      file=sys.stderr)
                files.remove(ONNX_FILE)
                if (out / ONNX_FILE).exists():
                    (out / ONNX_FILE).unlink()
            else:
                _atomic_write_bytes(out / ONNX_FILE, lambda p: Path(p).write_bytes(onnx))
        layers = _numpy_layers(exported, meta)
        if layers is not None:
            _write_weights(out / WEIGHTS_FILE, layers, arrays)
            files.append(WEIGHTS_FILE)
        elif (out / WEIGHTS_FILE).exists():
            (out / WEIGHTS_FILE).unlink()  # a stale file of another network must not be read
    finally:
        net.train(was_training)
    meta = dict(meta, format=META_FORMAT, files=sorted(files))
    _atomic_write_bytes(out / META_FILE, lambda p: Path(p).write_text(json.dumps(meta, indent=1)))
    return out


def _onnx_bytes(module, example) -> bytes:
    """The module as ONNX (batch axis dynamic), from torch's TorchScript-based exporter.

    The exporter built on ``torch.export`` needs ``onnxscript``; this network is a
    plain chain of matmuls, for which the older exporter is exact and needs nothing more.
    """
    import torch

    buf = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module, (example,), buf, dynamo=False, input_names=["x"], output_names=["activations"],
                          dynamic_axes={"x": {0: "batch"}, "activations": {0: "batch"}}, opset_version=ONNX_OPSET)
    return buf.getvalue()


def _write_weights(path: Path, net: dict[str, Any], extra: dict[str, np.ndarray] | None = None) -> None:
    arrays: dict[str, np.ndarray] = {"format": np.array(WEIGHTS_FORMAT), "n_layers": np.array(len(net["layers"]))}
    for k, v in (extra or {}).items():
        if k in arrays or (k[:1] in ("W", "b") and k[1:].isdigit()) or k.startswith("rbf_") or k == "phase_samples":
            raise ValueError(f"{k!r} is a name of the network's own arrays")
        arrays[k] = np.asarray(v, dtype=np.float64)
    for j, (W, b) in enumerate(net["layers"]):
        arrays[f"W{j}"], arrays[f"b{j}"] = W, b
    c, w = net["rbf"] if net["rbf"] is not None else (np.zeros(0, np.float32), np.float32(0.0))
    arrays["rbf_centres"], arrays["rbf_width"] = np.asarray(c, np.float32), np.asarray(w, np.float32)
    arrays["phase_samples"] = np.array(int(net.get("phase_samples", 0)))

    def write(p: str) -> None:
        with open(p, "wb") as f:
            np.savez(f, **arrays)

    _atomic_write_bytes(path, write)


def _read_weights(path: Path) -> dict[str, Any]:
    """``weights.npz`` as ``_forward_numpy`` takes it (no pickled objects are read)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["format"]) != WEIGHTS_FORMAT:
                raise UserError(f"{path}: format {str(z['format'])!r}, expected {WEIGHTS_FORMAT!r}")
            n = int(z["n_layers"])
            layers = [(np.ascontiguousarray(z[f"W{j}"], np.float32), np.ascontiguousarray(z[f"b{j}"], np.float32))
                      for j in range(n)]
            c = np.asarray(z["rbf_centres"], np.float32)
            rbf = (c, np.float32(z["rbf_width"])) if c.size else None
            m = int(z["phase_samples"]) if "phase_samples" in z.files else 0  # files before it: none
    except (OSError, ValueError, KeyError) as exc:
        raise UserError(f"{path}: not a weights file ({exc})") from None
    for j in range(1, n):
        if layers[j][0].shape[0] != layers[j - 1][0].shape[1]:
            raise UserError(f"{path}: layer {j} takes {layers[j][0].shape[0]} inputs, layer {j - 1} gives "
                            f"{layers[j - 1][0].shape[1]}")
    return {"layers": layers, "rbf": rbf, "phase_samples": m}


def write_weights(model_dir: str | os.PathLike) -> Path:
    """Add ``weights.npz`` and ``model.onnx`` to a folder exported with ``model.pt`` only (needs torch)."""
    import torch

    d = Path(model_dir)
    meta = _read_meta(d)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        module = torch.jit.load(str(d / MODEL_FILE), map_location="cpu").eval()
    layers = _numpy_layers(module, meta)
    if layers is None:
        raise UserError(f"{d / MODEL_FILE}: not the layer structure weights.npz holds (linear layers and ReLUs)")
    _write_weights(d / WEIGHTS_FILE, layers)
    example = torch.zeros(2, int(meta["channels"]), int(meta["input_length"]))
    _atomic_write_bytes(d / ONNX_FILE, lambda p: Path(p).write_bytes(_onnx_bytes(module, example)))
    meta["files"] = sorted({*meta.get("files", [MODEL_FILE]), WEIGHTS_FILE, ONNX_FILE})
    _atomic_write_bytes(d / META_FILE, lambda p: Path(p).write_text(json.dumps(meta, indent=1)))
    return d


def _read_meta(d: Path) -> dict[str, Any]:
    if not (d / META_FILE).is_file() or not ((d / WEIGHTS_FILE).is_file() or (d / MODEL_FILE).is_file()):
        raise UserError(f"no exported model in {d} (expected {META_FILE} and {WEIGHTS_FILE}; run `uavsim train`)")
    try:
        meta: dict[str, Any] = json.loads((d / META_FILE).read_text())
    except ValueError as exc:
        raise UserError(f"{d / META_FILE}: not valid JSON ({exc})") from None
    if meta.get("format") != META_FORMAT:
        raise UserError(f"{d / META_FILE}: format {meta.get('format')!r}, expected {META_FORMAT!r}")
    return meta


class Predictor:
    """Exported network + its metadata; numpy in, numpy out.

    Parameters
    ----------
    model_dir : path-like
        Folder written by ``export_model``.
    threads : int or None
        Torch intra-op threads when torch runs the network (a folder without
        ``weights.npz``, or ``module``); None leaves torch's setting. The numpy
        path uses the BLAS threads (``OPENBLAS_NUM_THREADS``/``OMP_NUM_THREADS``,
        read when numpy is first imported; one thread is the embedded case that
        ``uavsim bench infer`` measures).
    """

    def __init__(self, model_dir: str | os.PathLike, threads: int | None = None):
        d = Path(model_dir)
        self.meta = _read_meta(d)
        self.dir = d
        self.threads = threads
        self.channels = int(self.meta["channels"])
        self.input_length = int(self.meta["input_length"])
        self._module = None
        if (d / WEIGHTS_FILE).is_file():
            self.numpy_layers: dict[str, Any] | None = _read_weights(d / WEIGHTS_FILE)
            width = self.numpy_layers["layers"][0][0].shape[0]
            k = 0 if self.numpy_layers["rbf"] is None else self.numpy_layers["rbf"][0].size
            if width != self.channels * self.input_length + k:
                raise UserError(f"{d / WEIGHTS_FILE}: first layer takes {width} inputs, {META_FILE} says "
                                f"{self.channels} x {self.input_length} (+{k} period features)")
        else:
            self.numpy_layers = _numpy_layers(self.module, self.meta)

    @property
    def module(self):
        """The TorchScript network (``model.pt``), loaded with torch on first use."""
        if self._module is None:
            try:
                import torch
            except ImportError:
                raise UserError(f"{self.dir} has no {WEIGHTS_FILE} (exported by an older uavsim) and torch is "
                                f"not installed: add it with `python -m uavsim.learning.export {self.dir}` "
                                "where torch is installed") from None
            if not (self.dir / MODEL_FILE).is_file():
                raise UserError(f"{self.dir}: no {MODEL_FILE} (torch's copy of the network)")
            if self.threads is not None:
                torch.set_num_threads(int(self.threads))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                self._module = torch.jit.load(str(self.dir / MODEL_FILE), map_location="cpu").eval()
        return self._module

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
        import torch

        with torch.inference_mode():
            return self.module(torch.from_numpy(np.ascontiguousarray(x))).numpy()

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted classes (B,) int64 (argmax of the class activations) and those activations (B, n)."""
        a = self.activations(x)
        return a.argmax(axis=1).astype(np.int64), a


def _numpy_layers(module, meta: dict[str, Any]) -> dict[str, Any] | None:
    """The folded TorchScript network's weights as numpy, for ``_forward_numpy``; None for another structure.

    A single identification is one input row: there a matmul chain in numpy is
    about twice as fast as the TorchScript call (``uavsim bench infer``), with
    the same weights and the same float32 arithmetic.
    """
    layers = getattr(module, "layers", None)
    if layers is None:
        return None
    # a loaded TorchScript module names its children's classes ``original_name``
    name = lambda c: getattr(c, "original_name", type(c).__name__)  # noqa: E731
    kinds = [name(c) for c in layers.children()]
    if not kinds or kinds[-1] != "InputMajorLinear" or any(
            k != ("InputMajorLinear" if i % 2 == 0 else "ReLU") for i, k in enumerate(kinds)):
        return None
    Ws = [(np.ascontiguousarray(c.weight_t.detach().numpy(), dtype=np.float32),
           np.ascontiguousarray(c.bias.detach().numpy(), dtype=np.float32))
          for c in layers.children() if name(c) == "InputMajorLinear"]
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
    # an IdentNet knows its resampling; a loaded TorchScript copy does not, its meta.json does
    m = getattr(getattr(module, "cfg", None), "phase_samples", None)
    if m is None:
        m = (meta.get("net") or {}).get("phase_samples", 0)
    return {"layers": Ws, "rbf": rbf, "phase_samples": int(m or 0)}


def _forward_numpy(net: dict[str, Any], x: np.ndarray) -> np.ndarray:
    """``IdentNet.forward`` of the folded network in numpy: x (B, C, L) float32 -> (B, n_classes) float32.

    The inputs are right-aligned and zero-padded (``uavsim.data.preprocess``), so the first
    layer multiplies only the columns from each channel's first non-zero sample of the batch
    on: the same sum without its zero terms (a cycle half the input's length halves the
    largest matmul; float32 rounding may differ in the last bits from the full product). Each
    channel has its own start because a phase-resampled output channel (``phase_samples``)
    spans its ``m`` points while the relay channel spans the cycle's samples.
    """
    m = net.get("phase_samples", 0)
    if m:
        x = _phase_resample(x, m)
    B, C, L = x.shape
    (W0, b0), rest = net["layers"][0], net["layers"][1:]
    h = np.broadcast_to(b0, (B, b0.size)).copy()
    for ch in range(C):
        nz = np.flatnonzero(x[:, ch, :].any(axis=0))
        s = int(nz[0]) if nz.size else L
        h += x[:, ch, s:] @ W0[ch * L + s : (ch + 1) * L]
    if net["rbf"] is not None:
        c, w = net["rbf"]
        n = np.log(np.maximum(np.abs(x[:, -1, :]).sum(axis=1), np.float32(1.0)))
        h += np.exp(np.float32(-0.5) * ((n[:, None] - c[None, :]) / w) ** 2) @ W0[C * L :]
    for W, b in rest:
        np.maximum(h, np.float32(0.0), out=h)
        h = h @ W
        h += b
    return h


def _phase_resample(x: np.ndarray, m: int) -> np.ndarray:
    """``uavsim.learning.model.phase_resample`` in numpy, float32 like the network (same formula)."""
    B, C, L = x.shape
    n = np.count_nonzero(x[:, -1, :], axis=1)
    step = (np.maximum(n - 1, 0).astype(np.float32) / np.float32(max(m - 1, 1)))
    t = (L - n).astype(np.float32)[:, None] + np.arange(m, dtype=np.float32)[None, :] * step[:, None]
    i0 = np.clip(np.floor(t), 0, L - 1)
    w = (t - i0).astype(np.float32)
    i0 = i0.astype(np.int64)
    i1 = np.minimum(i0 + 1, L - 1)
    y = x[:, 0, :]
    yp = np.take_along_axis(y, i0, 1) * (np.float32(1.0) - w) + np.take_along_axis(y, i1, 1) * w
    yp[n < 2] = 0.0
    out = x.copy()
    out[:, 0, : L - m] = 0.0
    out[:, 0, L - m :] = yp
    return out


def _main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m uavsim.learning.export MODEL_DIR   (adds weights.npz and model.onnx; needs torch)",
              file=sys.stderr)
        return 2
    try:
        print(f"wrote {WEIGHTS_FILE} and {ONNX_FILE} into {write_weights(argv[0])}")
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
