"""Class selection: the network's answer.

The network is trained with the J-weighted loss over the table's robust answers
(``uavsim.learning.loss``), so its most likely class is already the one whose
table answer costs least in expectation; a second look at the candidates (their
harmonics, or an expected-J decision over the top few) did not lower J against
the optimum in the off-grid evaluation (``uavsim evaluate``,
docs/results/identification.md) and is not made.

    from uavsim.ident.select import choose_class
    cls = choose_class(bundle.predictor.activations(x))      # (m,) int
"""

from __future__ import annotations

import numpy as np

__all__ = ["choose_class"]


def choose_class(activations: np.ndarray) -> np.ndarray:
    """The class of each input: the argmax of the network's activations (m, n_classes) -> (m,) int64."""
    a = np.atleast_2d(np.asarray(activations))
    return a.argmax(axis=1).astype(np.int64)
