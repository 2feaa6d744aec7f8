"""Per-sample cost vectors: what each class's table answer would cost the sample's own process.

The table's ``J`` (``uavsim.tuning.table``) is exact for a process at a class
centre; a process between classes (every process a flight meets) has its own.
For a sample of process ``P`` (gain ``K``, lags ``T_prop``, ``T1``, delay ``tau``)
and every class ``i``, identification's answer were it to say ``i``
(``uavsim.ident.gains``) is the class's robust PD over the gain fitted to the
sample's measured response with the class's lags (``fit_response``), with the
class's derivative filter; its cost is the exact sampled step ISE on ``P`` at the
control rate (``uavsim.lumped.sampled``, as ``uavsim evaluate`` scores answers),

    cost_i = ISE(answer_i on P) / min_j ISE(answer_j on P)

(inf where the answer destabilizes ``P``). Relative to the best answer, not to
``P``'s own optimum: the expected-log-J loss is indifferent to a per-sample
factor, and the best answer is the target a classifier can reach.

    C = sample_costs("attitude", 200.0, process, K, response, response_period, table)
    C.shape        # (N, n_classes)
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sample_costs", "COST_SOURCE"]

#: what the dataset's ``cost`` holds (attribute ``cost_source``)
COST_SOURCE = ("ISE at the control rate of each class's table robust PD over the gain fitted to the sample's "
               "response with that class's lags, on the sample's process, over the least of them (inf: unstable)")


def sample_costs(loop: str, rate_hz: float, process: dict[str, np.ndarray], K: np.ndarray, response: np.ndarray,
                 response_period: np.ndarray, table: dict[str, np.ndarray], *, batch: int = 65536) -> np.ndarray:
    """Cost vectors of samples (module docstring), (N, n_classes) float64.

    Parameters
    ----------
    loop : ``altitude`` or ``attitude``
    rate_hz : control rate of the table and of the response's samples
    process : (N,) ``T_prop``, ``T1``, ``tau`` of each sample's process, s
    K : (N,) each sample's true gain
    response, response_period : (N,) complex measured response and its period, s (``CycleFeatures``)
    table : the class table, (n_classes,) each: ``T_prop``, ``T1``, ``tau``, ``table_robust_kp``,
        ``table_robust_kd``, ``table_filter_hz`` (K = 1)
    batch : (sample, class) pairs per sampled-ISE call (memory)

    A sample with no finite cost (no measured response) gets a row of NaN.
    """
    from uavsim.ident.response import fit_response
    from uavsim.lumped.sampled import pd_step_ise

    N = len(K)
    nc = len(table["table_robust_kp"])
    rep = np.repeat(np.arange(N), nc)
    cls = np.tile(np.arange(nc), N)
    K_hat = fit_response(np.asarray(response)[rep], np.asarray(response_period, dtype=np.float64)[rep],
                         T_prop=np.asarray(table["T_prop"], dtype=np.float64)[cls],
                         T1=np.asarray(table["T1"], dtype=np.float64)[cls],
                         tau_class=np.asarray(table["tau"], dtype=np.float64)[cls], rate_hz=rate_hz)["K"]
    kp = np.asarray(table["table_robust_kp"], dtype=np.float64)[cls] / K_hat
    kd = np.asarray(table["table_robust_kd"], dtype=np.float64)[cls] / K_hat
    N_rad = 2.0 * math.pi * np.asarray(table["table_filter_hz"], dtype=np.float64)[cls]
    fam = "altitude" if loop == "altitude" else "attitude"
    ise = pd_step_ise(fam, rate_hz, kp, kd, N_rad, batch=batch, K=np.asarray(K, dtype=np.float64)[rep],
                      **{k: np.asarray(process[k], dtype=np.float64)[rep] for k in ("T_prop", "T1", "tau")})
    ise = np.where(ise > 0, ise, np.inf)
    ise = ise.reshape(N, nc)
    best = ise.min(axis=1, keepdims=True)
    with np.errstate(all="ignore"):
        C = ise / best
    C[~np.isfinite(best[:, 0])] = np.nan
    return C
