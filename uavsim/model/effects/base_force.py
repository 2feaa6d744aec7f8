"""External forces on the body (wind, pulls), set once per control sample."""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from uavsim.model.effects.base import Effect


class ForceEffect(Effect):
    """An effect that pushes the vehicle; ``target = "force"``."""

    target = "force"

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator, drag_Ns_per_m: np.ndarray) -> None:
        """Start ``n`` episodes; ``drag_Ns_per_m`` (n, 3) is the body's translational damping."""
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.rng = rng
        self.drag = np.asarray(drag_Ns_per_m, dtype=np.float64)

    @abstractmethod
    def force(self, t: float, vel: np.ndarray) -> np.ndarray:
        """World-frame force (n, 3), N, at time ``t`` s given body velocity ``vel`` (n, 3) m/s."""
