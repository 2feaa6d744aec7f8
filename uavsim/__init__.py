"""uavsim: identify and tune multirotor loops with DNN-NP-MRFT on a MuJoCo hexarotor.

Data flows one way: recipe -> grid -> episodes -> preprocessed samples -> HDF5 ->
trainer -> model -> identification -> gains. The Python API (``uavsim.api``,
loaded on first use so that ``import uavsim`` stays light):

    import uavsim
    ans = uavsim.identify_session("scenarios/sessions/altitude-npmrft", models="training/runs/small")
    uavsim.export_gains(ans, "px4", "alt.params", cmd_scale=1.0)
    uavsim.tune("roll", T_prop=0.05, T1=0.4, tau=0.01, K=40.0)

Functions: ``identify_session``, ``plot_identification``, ``tune``, ``generate``,
``train``, ``find_gap``, ``import_log``, ``export_gains``, ``read_session``,
``write_session``, ``json_schema``; ``UserError`` is what bad input raises.

Each concern is one subpackage:

- ``uavsim.model``: the hexarotor MJCF, the lumped-parameter mapping, effects.
- ``uavsim.control``: MRFT, NP-MRFT, baselines and the step PD (vectorized).
- ``uavsim.sim``: the batched closed-loop runner on ``mujoco.batch``.
- ``uavsim.lumped``: lumped transfer functions and an exact reference simulator.
- ``uavsim.tuning``: tuning rule, relative sensitivity J, grids.
- ``uavsim.noise``: noise models and noise estimation.
- ``uavsim.formats``: flight sessions.
- ``uavsim.schema``: one schema (pydantic) for every TOML file kind.
- ``uavsim.logs``: flight logs in (PX4 ULog, ArduPilot DataFlash, ROS 2 bags).
- ``uavsim.autopilot``: gains out (PX4 and ArduPilot parameter files).
- ``uavsim.cli``: the ``uavsim`` command.
"""

from uavsim.errors import UserError

__version__ = "0.1.0"

_API = ("identify_session", "plot_identification", "tune", "generate", "train", "find_gap", "import_log", "export_gains",
        "read_session", "write_session", "json_schema")

__all__ = ["__version__", "UserError", *_API]


def __getattr__(name: str):
    if name in _API:
        from uavsim import api

        return getattr(api, name)
    raise AttributeError(f"module 'uavsim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
