"""The class decision of a cost-sensitive classifier: least expected log J under its softmax.

Many classes are near-equivalent for a true class (their robust table gains give
J close to 1 on it), while a class a level too fast can be unstable on a slow
one (J clipped to ``COST_CLIP[1]``, as the loss clips it). So the class answered
is the minimum-expected-cost (Bayes) decision over the cost matrix ``J`` (rows:
class answered, columns: true class; the dataset's, which the loss weighs), with
the network's softmax as the belief and log J as the cost, the cost the loss
(``uavsim.learning.loss``, ``"expected"``) trains the network to avoid:

    p = softmax(a / T)    cost_i = sum_j p_j log min(max(J_ij, 1), 1e3)    class = argmin_i cost_i

Why log J rather than J: with J itself an unstable neighbour (1e3) outweighs
everything else as soon as the belief gives it a few tenths of a percent, so the
decision drifts to classes that are mediocre everywhere. Measured on the
altitude validation set (network of 8-12 epochs, the expected-log-J loss):
expected J gave p95 J 1.22-1.40, expected log J 1.12-1.13 with 1 unstable answer
of 1264, argmax 1.12-1.17 with 3-7 unstable. ``expected_J`` reports
``exp(cost)``, the belief's geometric-mean J of the class answered.

The temperature ``T`` calibrates the belief (``fit_temperature``: least
negative log-likelihood of the true classes of a held-out set). A J-weighted
loss scales the activations by ``J`` inside its softmax, so ``softmax(a)`` of
such a network is much flatter than its accuracy (a tiny network that is always
right gives the right class p ~ 0.4), and the decision over it drifts to the
classes of least average J; calibrated, it follows the network where the network
is sure and hedges where it is not. ``decision="argmax"`` (the most likely class)
is kept for comparison. numpy only: the trainer picks its best epoch on this
decision and exports ``J`` and ``T``; identification (``uavsim.ident.select``)
answers it.

    from uavsim.learning.decision import decide, fit_temperature
    T = fit_temperature(val_activations, val_labels)          # (m, n), (m,) -> float
    d = decide(activations, J, temperature=T)                 # Decision: cls, expected_J, p
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError

__all__ = ["DECISIONS", "COST_CLIP", "TEMPERATURE_RANGE", "Decision", "softmax", "clip_cost", "log_cost", "expected_cost",
           "fit_temperature", "decide"]

#: class decisions: least expected J (``bayes``), most likely class (``argmax``)
DECISIONS = ("bayes", "argmax")
#: J is clipped to this range as the loss clips it (an unstable pair costs 1e3)
COST_CLIP = (1.0, 1e3)
#: temperatures ``fit_temperature`` searches
TEMPERATURE_RANGE = (0.02, 50.0)


@dataclass(frozen=True)
class Decision:
    """The class of each input and what the decision knew.

    Attributes
    ----------
    cls : (m,) int64
        Class answered.
    expected_J : (m,) float64
        ``exp`` of the expected log clipped J of the answered class under ``p`` (its
        geometric-mean J; nan without a cost matrix).
    p : (m, n) float64
        The network's softmax.
    decision : str
        The decision made (``bayes`` or ``argmax``; identification's: ``uavsim.ident.select``).
    scale : (m,) float64 or None
        Factor on the answered class's table ``kp`` and ``kd`` where the decision chose one
        (identification's ``stable``); None: 1.
    """

    cls: np.ndarray
    expected_J: np.ndarray
    p: np.ndarray
    decision: str
    scale: np.ndarray | None = None


def softmax(activations: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    """Softmax of ``activations / temperature`` over the last axis, (m, n) float64 (one input: (1, n))."""
    a = np.atleast_2d(np.asarray(activations, dtype=np.float64)) / float(temperature)
    e = np.exp(a - a.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


def clip_cost(cost) -> np.ndarray:
    """Costs (relative ISE, any shape) clipped to ``COST_CLIP``; inf (unstable) and nan (not computed) are the worst."""
    return np.clip(np.nan_to_num(np.asarray(cost, dtype=np.float64), nan=COST_CLIP[1], posinf=COST_CLIP[1]), *COST_CLIP)


def log_cost(J: np.ndarray, n: int | None = None) -> np.ndarray:
    """``log`` of ``J`` clipped to ``COST_CLIP``, (n, n): the cost the decision weighs.

    An unstable pair (inf) or one not computed (nan) is the clip's worst cost. ``n``: the
    network's class count, checked against ``J``'s shape.
    """
    J = np.asarray(J, dtype=np.float64)
    if J.ndim != 2 or J.shape[0] != J.shape[1] or (n is not None and J.shape[0] != n):
        raise UserError(f"cost matrix J has shape {J.shape}, the network has {n} classes")
    return np.log(clip_cost(J))


def expected_cost(p: np.ndarray, J: np.ndarray | None = None, *, log_J: np.ndarray | None = None) -> np.ndarray:
    """Expected log of the clipped J of answering each class, ``sum_j p_j log J[i, j]``.

    (m, n) from ``p`` (m, n) and ``J`` (n, n), or ``log_J`` (``log_cost(J)``, n x n) where
    the caller keeps it (one identification: the log of a 208 x 208 J costs more than the product).
    """
    p = np.atleast_2d(np.asarray(p, dtype=np.float64))
    if log_J is None:
        log_J = log_cost(J, p.shape[1])
    elif log_J.shape != (p.shape[1], p.shape[1]):
        raise UserError(f"log cost matrix has shape {log_J.shape}, the network has {p.shape[1]} classes")
    return p @ log_J.T


def fit_temperature(activations: np.ndarray, labels: np.ndarray) -> float:
    """The temperature of least mean negative log-likelihood of ``labels`` (m,) under ``softmax(a / T)``.

    The NLL is convex in ``1 / T``; searched in ``TEMPERATURE_RANGE`` (a set the network
    classifies without error ends at the sharp end). An empty set gives 1.
    """
    from scipy.optimize import minimize_scalar

    a = np.atleast_2d(np.asarray(activations, dtype=np.float64))
    y = np.asarray(labels, dtype=np.int64)
    if a.shape[0] == 0:
        return 1.0
    a = a - a.max(axis=1, keepdims=True)
    a_true = a[np.arange(y.size), y]

    def nll(beta: float) -> float:
        z = beta * a
        return float(np.mean(np.log(np.exp(z).sum(axis=1)) - beta * a_true))

    lo, hi = 1.0 / TEMPERATURE_RANGE[1], 1.0 / TEMPERATURE_RANGE[0]
    r = minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4 * lo})
    return float(1.0 / r.x)


def decide(activations: np.ndarray, J: np.ndarray | None = None, *, decision: str = "bayes",
           temperature: float = 1.0, log_J: np.ndarray | None = None) -> Decision:
    """The class of each input (module docstring); ``J`` None allows only ``argmax``.

    Parameters
    ----------
    activations : (m, n) or (n,)
        The network's activations.
    J : (n, n) or None
        Cost matrix, rows class answered, columns true class.
    decision : ``"bayes"`` or ``"argmax"``
    temperature : float
        ``T`` of the belief ``softmax(a / T)`` (``fit_temperature``); argmax does not depend on it.
    log_J : (n, n) or None
        ``log_cost(J)`` where the caller keeps it (``expected_cost``).
    """
    if decision not in DECISIONS:
        raise UserError(f"decision must be one of {', '.join(DECISIONS)}, got {decision!r}")
    if not (math.isfinite(temperature) and temperature > 0):
        raise UserError(f"temperature must be a positive number, got {temperature!r}")
    p = softmax(activations, temperature)
    if J is None:
        if decision == "bayes":
            raise UserError("the Bayes decision needs the cost matrix J (a bundle exported without it: retrain, "
                            "or decide by argmax)")
        cls = p.argmax(axis=1).astype(np.int64)
        return Decision(cls, np.full(cls.size, np.nan), p, decision)
    cost = expected_cost(p, J, log_J=log_J)
    cls = (cost.argmin(axis=1) if decision == "bayes" else p.argmax(axis=1)).astype(np.int64)
    return Decision(cls, np.exp(cost[np.arange(cls.size), cls]), p, decision)
