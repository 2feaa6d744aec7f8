"""The controller of a session run, from its ``RunSpec``: the one place a run's kind becomes a controller.

A session's ``[[runs]]`` entry names the controller that produced the run and its
settings (``docs/formats/session.md``); simulation, replay, the testbed and the
gap workflow build that controller here, so that a new run kind is one branch in
one function.

    from uavsim.control.runs import run_controller
    ctrl = run_controller(run.spec, rate_hz=200.0, reading=session.reading)   # n = 1
    u = ctrl(np.array([r - y]))     # a PD with ``reads_reference``: ctrl(np.array([r - y]), np.array([r]))
"""

from __future__ import annotations

from uavsim.control.pd import PD
from uavsim.control.relay import MRFT, NPMRFT, READING
from uavsim.errors import UserError
from uavsim.formats.session import MRFT_RUN, NP_MRFT_RUN, STEP_RUN, RunSpec

__all__ = ["run_controller"]


def run_controller(spec: RunSpec, rate_hz: float, *, n: int = 1, reading: int = READING) -> NPMRFT | MRFT | PD:
    """The controller of run ``spec`` (``n`` identical copies), in the session format's semantics.

    Parameters
    ----------
    spec : RunSpec
        The run's entry: ``np-mrft`` (``beta``, ``h``, ``tau_obs``, ``a_n``, ``bias``, ``bias_trim``),
        ``mrft`` (``beta``, ``h``, ``bias``, ``bias_trim``) or ``step`` (``kp``, ``kd``, ``derivative_filter_hz``, ``derivative``).
    rate_hz : float
        The session's controller rate, Hz.
    n : int
        Batch size.
    reading : int
        The relay reading of the session's format version (``Session.reading``).
    """
    bias = spec.bias or 0.0
    if spec.kind == NP_MRFT_RUN:
        return NPMRFT(spec.beta, spec.h, spec.tau_obs or 0.0, spec.a_n or 0.0, rate_hz, n, bias=bias, reading=reading,
                      bias_trim=spec.bias_trim)
    if spec.kind == MRFT_RUN:
        return MRFT(spec.beta, spec.h, rate_hz, n, bias=bias, reading=reading, bias_trim=spec.bias_trim)
    if spec.kind == STEP_RUN:
        return PD(spec.kp, spec.kd, spec.derivative_filter_hz, rate_hz, n, derivative=spec.derivative)
    raise UserError(f"{spec.file}: unknown run kind {spec.kind!r} (known: {NP_MRFT_RUN}, {MRFT_RUN}, {STEP_RUN})")
