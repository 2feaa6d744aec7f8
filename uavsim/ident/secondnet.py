"""A second network, trained on relay runs at the second run's ``beta``: its belief multiplies the first's.

Two measured points (``uavsim.ident.twopoint``) tell the classes apart only where a class's
gain and delay fitted to both miss one of them; the cycle's *shape* tells more, and the
first network reads only its own run's. Where the model root holds a network trained on
relay runs at the second run's ``beta`` (``<loop>-second``, ``make train``: the recipes
``datasets/altitude-second.toml`` and ``training/altitude-second.toml``), it reads the
second run's cycle too (``extract_cycle`` with its own bundle, so the same checks), and
the belief becomes

    p(c) ~ p_first(c)^w  p_two_points(c)  p_second(c)

(the beliefs of two independent looks at the process, on the same grid of classes).
``w`` is 1, except where the first run's point is unsteady: its spread, in units of
``uavsim.ident.family.FAMILY_SPREAD_LIMITS`` (``unsteady_spread``), beyond ``UNSTEADY_SPREAD``,
while the second run's cycle is steady within ``SECOND_SPREAD_LIMITS``.
There ``w`` is ``UNSTEADY_TEMPER``, and ``LOST_TEMPER`` (0: the first network ignored) where the first
point lags so far beyond the relay's phase that it is no limit cycle of the relay
(``uavsim.ident.cycle.phase_lost``): under 15-20 % noise the first run's small cycle can
carry no limit cycle at all, and its network is then confident about noise (development
seed 14: belief 0.99999 on a class whose PD is unstable on the process, read off a point 96
degrees from the process's response), while the second run's cycle, several times larger for
the same sensor, measured its point within 0.33 degrees and 0.6 % (p95 over the 1,553 of 2,985
altitude episodes of development seeds 11-20 whose first point was not steady).

The guard's lag family (``uavsim.ident.lagfamily``) keeps weighing its members by the first
network's (tempered) belief, as it was set.

On development seeds 11-20 (3,000 off-grid altitude processes, noise 0-20 %, both runs flown in
MuJoCo with a user's settings) the second network took the pooled p95 of J from 1.0917 to 1.0755,
and the seeds whose p95 is over 1.10 from 3 to 0, with the same 3 unstable answers of 3,000
(docs/results/identification.md). Without the tempering it answered 5 unstable.

    from uavsim.ident.secondnet import load_second_bundle, second_reading
    b2 = load_second_bundle(model_dir, bundle)          # None where the root holds none
    reading = second_reading(b2, y2, u2, rate_hz=200.0, h=h2, bias=bias2)   # None where its run is refused
    identify_cycle(f, bundle, second=f2, second_network=reading)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uavsim.data.preprocess import CycleFeatures
from uavsim.errors import NoOscillation, UserError
from uavsim.ident.bundle import ModelBundle, load_bundle
from uavsim.ident.cycle import extract_cycle
from uavsim.ident.family import SECOND_SPREAD_LIMITS, family_applies, unsteady_spread
from uavsim.ident.select import cycle_activations
from uavsim.learning.decision import softmax
from uavsim.learning.export import META_FILE
from uavsim.lumped.params import BOX_KEYS

__all__ = ["SECOND_NET_SUFFIX", "UNSTEADY_SPREAD", "UNSTEADY_TEMPER", "LOST_TEMPER", "SecondReading",
           "second_model_dir", "load_second_bundle", "second_reading", "first_weight", "multiply_beliefs"]

#: the second network's folder beside the first's: ``training/runs/altitude-second``
SECOND_NET_SUFFIX = "-second"
#: a first point whose spread is beyond this many times ``FAMILY_SPREAD_LIMITS`` (either part, as
#: ``point_spread`` scales it) is unsteady: 5.6 % of the altitude episodes of development seeds 11-20,
#: holding 18 of their 31 answers of J over 1.2 and all 3 unstable ones
UNSTEADY_SPREAD = 8.0
#: the power on the first network's belief where its point is unsteady and the second run's steady
#: (1: no change; 0: the first network ignored, which raised the p95 on development seeds 11, 14, 16, 20)
UNSTEADY_TEMPER = 0.5
#: the power where the first point lags beyond the relay's phase by more than
#: ``uavsim.ident.cycle.PHASE_LAG_MAX_DEG`` (no limit cycle of the relay: ``phase_lost``) and the second run's is
#: steady: that run's network read noise (development seed 14: a point 120 deg beyond the relay's phase,
#: belief 1.0 on a class whose PD, even at x0.5, is unstable on the process; the second network put 3e-16 on
#: it). Not where the point only scatters (``unsteady_spread``): there 0 instead of ``UNSTEADY_TEMPER`` beyond
#: the guard's 40 times the limits moved 4 answers of development seed 14, 3 of them up (to J 1.093)
LOST_TEMPER = 0.0


@dataclass(frozen=True)
class SecondReading:
    """The second network's look at the second run.

    Attributes
    ----------
    activations : (1, n) float array
        The network's activations on the run's cycle (the grid's ``n`` classes).
    temperature : float
        Its belief's temperature (``softmax(activations / temperature)``).
    model_dir : str
        Its folder.
    beta : float
        The relay's ``beta`` it was trained on.
    """

    activations: np.ndarray
    temperature: float
    model_dir: str
    beta: float

    def belief(self) -> np.ndarray:
        """``softmax(activations / temperature)``, (1, n)."""
        return softmax(self.activations, self.temperature)


def second_model_dir(model_dir: str | os.PathLike) -> Path | None:
    """The second network's folder beside a first network's folder ``model_dir``, or None where there is none."""
    d = Path(model_dir)
    cand = d.parent / f"{d.name}{SECOND_NET_SUFFIX}"
    return cand if (cand / META_FILE).is_file() else None


def load_second_bundle(model_dir: str | os.PathLike, first: ModelBundle, *,
                       beta: float | None = None) -> ModelBundle | None:
    """The second network of ``first`` (folder ``model_dir``), checked against it; None where there is none,
    or where it was trained at another ``beta`` than the second run's (``beta``, when given).

    Raises ``UserError`` where it classifies another loop or another grid, or was trained at the first's ``beta``.
    """
    d = second_model_dir(model_dir)
    if d is None:
        return None
    b = load_bundle(d)
    if b.loop != first.loop:
        raise UserError(f"{d}: a {b.loop} network beside the {first.loop} one")
    same = b.n_classes == first.n_classes and all(
        np.allclose(b.column(k), first.column(k), rtol=1e-9, atol=0.0) for k in BOX_KEYS[first.loop])
    if not same:
        raise UserError(f"{d}: its classes are not those of {model_dir} (a network of another grid)")
    if abs(b.rule.beta - first.rule.beta) < 1e-6:
        raise UserError(f"{d}: trained at the first network's beta ({first.rule.beta:g}), not a second run's")
    if beta is not None and abs(float(beta) - b.rule.beta) > 1e-6:
        return None  # a second run at another beta than its network's: the point alone
    return b


def second_reading(bundle: ModelBundle, y: np.ndarray, u: np.ndarray, *, rate_hz: float, h: float,
                   bias: float) -> SecondReading | None:
    """The second network's activations on a second run (``y``, ``u``: (T,), as ``extract_cycle`` takes them);
    None where that run holds no cycle its network reads (``NoOscillation``)."""
    try:
        f = extract_cycle(y, u, rate_hz=rate_hz, h=h, bias=bias, bundle=bundle)
    except NoOscillation:
        return None
    return SecondReading(activations=cycle_activations(bundle, f), temperature=bundle.temperature,
                         model_dir=str(bundle.dir), beta=bundle.rule.beta)


def first_weight(first: CycleFeatures, second: CycleFeatures, *, lost: bool = False) -> float:
    """The power on the first network's belief (module docstring): ``LOST_TEMPER`` where the first point is no
    limit cycle of the relay (``lost``: ``uavsim.ident.cycle.phase_lost`` at the network's ``beta``),
    ``UNSTEADY_TEMPER`` where it is unsteady, each only where the second run's cycle is steady; else 1."""
    if not family_applies(second.response_spread, second.response_cycles, limits=SECOND_SPREAD_LIMITS):
        return 1.0
    if lost:
        return LOST_TEMPER
    return UNSTEADY_TEMPER if unsteady_spread(first) >= UNSTEADY_SPREAD else 1.0


def multiply_beliefs(activations: np.ndarray, temperature: float, reading: SecondReading) -> np.ndarray:
    """Activations (1, n) at ``temperature`` whose belief is theirs times the second network's, normalized."""
    with np.errstate(divide="ignore"):
        lp = np.asarray(activations, dtype=np.float64) / temperature + np.log(reading.belief())
    return temperature * (lp - lp.max(axis=1, keepdims=True))
