"""Visual-servoing scenarios: identify and tune a loop through a camera chain, then test it.

A scenario file (:mod:`~uavsim.scenario.config`) names the true loops, the
sensor chain and the test; :mod:`~uavsim.scenario.flow` runs noise estimation,
NP-MRFT, identification, tuning and the test on :mod:`~uavsim.scenario.episode`
(``LoopBatch`` with the vision chain as its measurement stage);
:mod:`~uavsim.scenario.record` writes the Rerun recording and run file,
:mod:`~uavsim.scenario.table` and :mod:`~uavsim.scenario.trends` compare with
the paper.

    from uavsim.scenario.config import load_scenario
    from uavsim.scenario.flow import run_scenario
    result = run_scenario(load_scenario("scenarios/normal-camera-kf.toml"))
"""
