"""The commands behind figures of ``docs/results/`` that no product command prints.

Each module reproduces figures of one page and runs as ``python -m uavsim.results.<module>``
(``--help`` for its options); the page names the command beside the figure. Product
measurements have their own commands (``uavsim evaluate``, ``uavsim bench``,
``uavsim grid report``, ``uavsim testbed score``); these are the studies around them.

- :mod:`~uavsim.results.lateral_grid`: coverage of the lateral grid and its 200 Hz table
  (``lateral-grid.md``);
- :mod:`~uavsim.results.optimal_gains`: why the ISE step has no derivative kick and the
  filter is fixed, the optima's gain margins, latencies of the optimum and the robust PD
  (``optimal-gains.md``);
- :mod:`~uavsim.results.onnx_latency`: one forward of an exported network with
  onnxruntime against numpy (``io.md``);
- :mod:`~uavsim.results.training_sets`: figures read off a training set (rejections by
  noise level, the cycle's lengthening by noise kind, gain recovery from one cycle;
  ``training-sets.md``).

    python -m uavsim.results.lateral_grid --seed 2026 --per-class 10 > figures.json
    python -m uavsim.results.optimal_gains --kick --free-filter --margins
    python -m uavsim.results.training_sets datasets/altitude.h5
"""
