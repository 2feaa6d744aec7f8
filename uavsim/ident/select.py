"""Class selection: the answer of least expected log J under the network's belief.

The network is trained with a cost-sensitive loss over the table's robust
answers, yet its most likely class is not the answer of least cost: many classes
are near-equivalent for a true class while some (answer, truth) pairs are
unstable. The class answered is the minimum-expected-cost (Bayes) decision, the
cost being log J over the bundle's cost matrix ``J`` (``ModelBundle.cost``: the dataset's, rows class
answered, columns true class) with the network's softmax at the bundle's
temperature as the belief
(``uavsim.learning.decision``: the same decision the trainer picks its best
epoch on). ``decision="argmax"`` (the most likely class) is kept for comparison;
it is also what a bundle exported without ``J`` answers, and what the trainer
exports as the decision where it had the lower mean log J on the validation set
(``ModelBundle.decision``).

    from uavsim.ident.select import choose_class, decide_class
    d = decide_class(bundle, bundle.predictor.activations(x))       # Decision: cls, expected_J, p, decision
    cls = choose_class(bundle, bundle.predictor.activations(x), decision="argmax")     # (m,) int
"""

from __future__ import annotations

import numpy as np

from uavsim.errors import UserError
from uavsim.ident.bundle import ModelBundle
from uavsim.learning.decision import DECISIONS, Decision, decide

__all__ = ["DECISIONS", "Decision", "decide_class", "choose_class"]


def decide_class(bundle: ModelBundle, activations: np.ndarray, *, decision: str | None = None) -> Decision:
    """The class decision for the network's activations (m, n) or (n,).

    ``decision``: ``"bayes"``, ``"argmax"``, or None for the bundle's (``ModelBundle.decision``).
    ``expected_J`` is that of the class answered (nan without a cost matrix).
    """
    if decision is not None and decision not in DECISIONS:
        raise UserError(f"decision must be one of {', '.join(DECISIONS)}, got {decision!r}")
    if decision == "bayes" and bundle.cost is None:
        raise UserError(f"{bundle.dir}: exported without the cost matrix J (weights.npz) the Bayes decision "
                        "needs: retrain, or decide by argmax")
    return decide(activations, bundle.cost, decision=decision or bundle.decision, temperature=bundle.temperature)


def choose_class(bundle: ModelBundle, activations: np.ndarray, *, decision: str | None = None) -> np.ndarray:
    """The class of each input, (m,) int64 (``decide_class``)."""
    return decide_class(bundle, activations, decision=decision).cls
