"""Simulated episodes saved as flight sessions, so sim and flight share one path.

    path = episode_to_session(res, i=0, loop="altitude", args=ns, path="out/alt")

``args`` carries the run parameters (beta, h, tau_obs, a_n, rate); the
episode's lumped parameters become the session's ``[model]``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavsim.formats.session import (
    MRFT_RUN,
    NP_MRFT_RUN,
    ModelSpec,
    Run,
    RunData,
    RunSpec,
    Session,
    write_session,
)
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import EpisodeResult

#: lumped parameters of ``uavsim sim relay``'s loops where the command line gives none
DEMO_PARAMS: dict[str, dict[str, float]] = {
    "altitude": dict(K=1.0, T_prop=0.1, T1=0.8, tau=0.02),
    "roll": dict(K=1.0, T_prop=0.05, T1=0.4, tau=0.01),
    "pitch": dict(K=1.0, T_prop=0.05, T1=0.4, tau=0.01),
}


def relay_session(
    res: EpisodeResult,
    i: int,
    params: LumpedParams,
    *,
    beta: float,
    h: float,
    rate_hz: float,
    tau_obs: float = 0.0,
    a_n: float = 0.0,
    bias: float = 0.0,
    noise_std: float = 0.0,
    with_model: bool = True,
    file: str = "relay.csv",
) -> Session:
    """Session holding episode ``i`` of ``res`` as one mrft / np-mrft run."""
    np_mrft = tau_obs > 0 or a_n > 0
    spec = RunSpec(
        file=file,
        kind=NP_MRFT_RUN if np_mrft else MRFT_RUN,
        beta=float(beta),
        h=float(h),
        tau_obs=float(tau_obs) if np_mrft else None,
        a_n=float(a_n) if np_mrft else None,
        bias=float(bias),
    )
    data = RunData(
        t=np.array(res.t, dtype=np.float64),
        r=np.array(res.r[i], dtype=np.float64),
        y=np.array(res.y[i], dtype=np.float64),
        u=np.array(res.u[i], dtype=np.float64),
    )
    model = None
    if with_model:
        model = ModelSpec(
            K=params.K, T_prop=params.T_prop, T1=params.T1, tau=params.tau, T2=params.T2, noise_std=float(noise_std)
        )
    return Session(loop=params.loop, control_rate_hz=float(rate_hz), runs=[Run(spec, data)], model=model)


def episode_to_session(res: EpisodeResult, i: int, loop: str, args, path: str | Path) -> Path:
    """Write episode ``i`` as a session folder at ``path`` (CLI helper)."""
    kw = {k: getattr(args, k) for k in ("K", "T_prop", "T1", "tau")}
    p = LumpedParams(loop, **{k: (v if v is not None else DEMO_PARAMS[loop][k]) for k, v in kw.items()})
    s = relay_session(res, i, p, beta=args.beta, h=args.h, rate_hz=args.rate, tau_obs=args.tau_obs, a_n=args.a_n)
    return write_session(s, path)
