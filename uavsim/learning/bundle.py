"""What an exported network carries for identification: the ``identification`` section of ``meta.json``.

Written by the trainer beside the network (``uavsim.learning.export``), read by
``uavsim.ident.bundle``: the control rate of the class table's PDs, the grid's
rule, the preprocessing settings, the relay its training runs flew (``relay``: whether
it trimmed its bias, ``uavsim.control.relay``), and for a lateral network the attitude loop
its sub-grid closes, and the class decision (least expected log J over the cost matrix
``J`` that ``weights.npz`` carries: ``uavsim.learning.decision``). The class table itself (with the grid's table of PDs at
the control rate, ``table_*`` columns) is the dataset's, copied as ``classes``.

    from uavsim.learning.bundle import bundle_section
    meta["identification"] = bundle_section(loop="altitude", grid_hash=h, rate_hz=200.0, beta=-0.73,
                                            input_length=456, cycles=1)
"""

from __future__ import annotations

from typing import Any

from uavsim.errors import UserError

__all__ = ["BUNDLE_FORMAT", "bundle_section"]

BUNDLE_FORMAT = "uavsim-ident/1"


def bundle_section(*, loop: str, grid_hash: str, rate_hz: float, beta: float | None, input_length: int,
                   cycles: int, att_class: int | None = None, bias_trim: str = "off") -> dict[str, Any]:
    """The ``identification`` section of an export's ``meta.json`` (called by the trainer).

    The rule (and for a lateral sub-grid its attitude loop) comes from the package grid and
    table the dataset was generated on. A dataset of another grid than the installed one
    (``grid_hash``) gets the dataset's ``beta`` with the default rule's phase margin and no
    attitude loop (``grid_matched`` false): identification of a lateral network refuses it.
    """
    from uavsim.data.preprocess import CHANNELS, INPUT_RATE_HZ
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.rule import TuningRule

    grid = load_grid(loop)
    matched = not grid_hash or not grid.hash or grid_hash == grid.hash
    att = None
    rule = grid.rule if matched else TuningRule()
    if loop == "lateral" and matched:
        if att_class is None:
            raise UserError("a lateral dataset names its attitude class (att_class)")
        from uavsim.tuning.table import load_table

        sub = grid.lateral(int(att_class))
        t = load_table("lateral", rate_hz, grid=grid).lateral(int(att_class))
        att = dict(t.attitude) if t.attitude is not None else dict(sub.attitude)
        att["att_class"] = int(att_class)
        rule = sub.rule
    return {"format": BUNDLE_FORMAT, "loop": loop, "rate_hz": float(rate_hz), "grid_matched": bool(matched),
            "rule": {"beta": float(beta if beta is not None else rule.beta), "pm_deg": float(rule.pm_deg),
                     "gain_scale": float(rule.gain_scale)},
            "preprocess": {"input_rate_hz": INPUT_RATE_HZ, "input_length": int(input_length), "cycles": int(cycles),
                           "channels": list(CHANNELS)},
            "relay": {"bias_trim": str(bias_trim)},
            "attitude": att,
            "class_decision": {"decision": "bayes", "cost": "weights.npz J: rows class answered, columns true "
                               "class, clipped to [1, 1000]", "belief": "softmax(a / T), T: weights.npz temperature"}}
