"""Lumped process models of the multirotor loops (paper eq. 6-7).

Parameters and ranges (``params``), exact frequency responses and the
describing-function MRFT prediction (``frequency``), the lateral model over the
closed attitude loop (``lateral``), exact time-domain simulation, MRFT limit
cycles and step ISE (``simulate``), and the frequency-domain step ISE used for
J matrices (``ise``).

    from uavsim.lumped import LumpedParams, freq_response, mrft_prediction, exact_limit_cycle, step_ise
    p = LumpedParams("altitude", K=1.0, T_prop=0.3, T1=0.2, tau=0.0128)
    omega, amp = mrft_prediction(p, beta=-0.73, h=1.0)       # DF
    period, amp_exact = exact_limit_cycle(p, beta=-0.73)      # exact
    Q = step_ise(p, kp=1.0, kd=0.3, N=10 * omega)
"""

from uavsim.lumped.frequency import (
    check_beta,
    freq_response,
    freq_response_batch,
    mrft_prediction,
    mrft_prediction_batch,
)
from uavsim.lumped.ise import loop_is_stable_batch, step_ise_batch
from uavsim.lumped.params import (
    INNER_LOOPS,
    LATERAL_LOOPS,
    LOOPS,
    RANGES,
    LumpedParams,
    loop_family,
)
from uavsim.lumped.simulate import (
    exact_limit_cycle,
    fourier_limit_cycle,
    simulate,
    simulate_pd_step_batch,
    simulate_relay_batch,
    step_ise,
    step_ise_time,
)

__all__ = [
    "INNER_LOOPS",
    "LATERAL_LOOPS",
    "LOOPS",
    "RANGES",
    "LumpedParams",
    "loop_family",
    "check_beta",
    "freq_response",
    "freq_response_batch",
    "mrft_prediction",
    "mrft_prediction_batch",
    "step_ise_batch",
    "loop_is_stable_batch",
    "exact_limit_cycle",
    "fourier_limit_cycle",
    "simulate",
    "simulate_pd_step_batch",
    "simulate_relay_batch",
    "step_ise",
    "step_ise_time",
]
