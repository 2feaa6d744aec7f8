"""The sim-vs-measured gap workflow: which physical effect does the model lack?

``run_gap`` simulates every run of a flight session on the MuJoCo loop with
the session's model and the session's controller semantics, compares measured
and simulated runs on features that separate effects (period, amplitude,
offset, asymmetry, harmonics, waveform shape, residual spectrum, staircase
levels, step metrics; per run, so amplitude and frequency dependence show),
fits every effect of the vocabulary by batched grid search, and names the
one that closes the gap -- or ``none``.

Modules: :mod:`~uavsim.gap.features` (features, z-scores, the gap),
:mod:`~uavsim.gap.simulate` (sessions on ``LoopBatch``, with per-episode
registry effects for batched fits),
:mod:`~uavsim.gap.workflow` (fit, rank, decide), :mod:`~uavsim.gap.report`
(plots, Rerun recording, updated model), :mod:`~uavsim.gap.hidden`
(hidden-effect sessions for tests and ``uavsim bench gap``),
:mod:`~uavsim.gap.iterate` (what ``uavsim gap`` runs: base model identified
when the session has none, effects added one by one, ``none`` / ``absorbed`` /
``unexplained``), :mod:`~uavsim.gap.residual` (the residual's character),
:mod:`~uavsim.gap.overlay` (the report's overlays and ranking),
:mod:`~uavsim.gap.colour` (the model noise's colour where the samples are a staircase).

    from uavsim.formats import read_session
    from uavsim.gap import run_gap, format_table, write_report

    session = read_session("flights/thermal_kf")
    result = run_gap(session, seed=0)
    print(format_table(result))            # effect, params, gap before/after, ranking, where they disagree
    write_report(session, result, "reports/thermal_kf")
"""

from uavsim.gap.iterate import FlowResult, analyse, format_flow
from uavsim.gap.report import model_toml, write_report
from uavsim.gap.workflow import (
    CANDIDATES,
    GapResult,
    format_table,
    read_model_file,
    run_gap,
    updated_session,
)

__all__ = [
    "CANDIDATES",
    "FlowResult",
    "analyse",
    "format_flow",
    "GapResult",
    "format_table",
    "model_toml",
    "read_model_file",
    "run_gap",
    "updated_session",
    "write_report",
]
