"""Tiny ``uavsim-dataset/1`` files for the learning tests, written by the real writer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from uavsim.data.h5 import write_dataset


def synthetic_cycles(n_classes: int, per_class: int, L: int, seed: int, noise: float = 0.05):
    """Separable fake cycles: class c is a sine of c+1 half-periods, plus its relay square wave."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, L, endpoint=False)
    X, y = [], []
    for c in range(n_classes):
        base_y = np.sin(np.pi * (c + 1) * t)
        base_u = np.sign(np.sin(np.pi * (c + 1) * t + 0.3))
        for _ in range(per_class):
            X.append(np.stack([base_y + noise * rng.standard_normal(L), base_u]))
            y.append(c)
    return np.asarray(X, np.float32), np.asarray(y, np.int32)


def tiny_J(n_classes: int) -> np.ndarray:
    """J growing with class distance (rows predicted, columns true), 1 on the diagonal, not symmetric."""
    i, j = np.meshgrid(np.arange(n_classes), np.arange(n_classes), indexing="ij")
    return 1.0 + 0.2 * (i - j) ** 2 + 0.05 * np.maximum(i - j, 0)


def write_tiny_dataset(path: Path, n_classes: int = 6, per_class: int = 40, L: int = 32, seed: int = 0,
                       loop: str = "altitude", response: bool = True) -> Path:
    """Synthetic cycles of ``n_classes`` unit-gain altitude-like classes; with ``response``, each episode's
    fundamental response is its class's ``K G(j w)`` (as sampled at 200 Hz) times 1% noise."""
    from uavsim.data.preprocess import held_response
    from uavsim.lumped.frequency import freq_response_batch

    X, y = synthetic_cycles(n_classes, per_class, L, seed)
    N = len(y)
    rng = np.random.default_rng(seed + 100)
    K = np.exp(rng.uniform(np.log(0.5), np.log(2.0), N))
    classes = {k: np.linspace(0.1, 1.0, n_classes) for k in
               ("T_prop", "T1", "tau", "kp", "kd", "derivative_filter_hz", "omega", "amplitude", "period")}
    classes["tau"] = np.linspace(0.005, 0.05, n_classes)
    if response:  # the classes' own rule gains, so that a right class gives the right gains
        from uavsim.tuning.grid import load_grid
        from uavsim.tuning.rule import TuningRule

        g = load_grid("altitude")
        rule = TuningRule(g.beta, g.pm_deg).gains_batch("altitude", K=1.0, T_prop=classes["T_prop"],
                                                        T1=classes["T1"], tau=classes["tau"])
        classes.update(kp=rule["kp"], kd=rule["kd"], omega=rule["omega"], table_robust_kp=rule["kp"],
                       table_robust_kd=rule["kd"])
    eps = {"inputs": X, "labels": y, "K": K, "bias": np.zeros(N), "noise_kind": np.zeros(N),
           "noise_level": np.zeros(N), "period": np.ones(N), "amplitude": K * classes["amplitude"][y],
           "y0": np.zeros(N), "tau_obs": np.zeros(N), "a_n": np.zeros(N), "episode": np.arange(N),
           "sim_seed": np.zeros(N)}
    if response:
        period = 1.0 + 0.5 * y / n_classes
        w = 2 * np.pi / period
        G = freq_response_batch("altitude", w[:, None], K=K, T_prop=classes["T_prop"][y], T1=classes["T1"][y],
                                tau=classes["tau"][y])[:, 0]
        r = held_response(G, w, 200.0) * (1 + 0.01 * rng.standard_normal(N))
        eps.update(response_re=r.real, response_im=r.imag, response_period=period)
    attrs = {"loop": loop, "grid_hash": "test", "grid_version": 1, "beta": -0.73, "h": 1.0, "tau_obs": 0.0,
             "a_n": 0.0, "rate_hz": 200.0, "input_length": L, "channels": ["y", "u"], "recipe": "seed = 0\n",
             "seed": seed, "versions": json.dumps({}), "git_commit": "test", "n_episodes": N, "n_diverged": 0,
             "n_rejected": 0, "noise_kinds": ["none"]}
    return write_dataset(path, eps, classes, tiny_J(n_classes), attrs)


def trained_like_net(hidden=(64, 32), period_features: int = 8, seed: int = 0, phase_samples: int = 0):
    """An ``IdentNet`` (2 x 40 inputs, 5 classes) in eval mode whose BatchNorms are far from the identity,
    as after training: running statistics, scales and shifts drawn at random."""
    import torch

    from uavsim.learning.model import IdentNet, NetConfig

    torch.manual_seed(seed)
    net = IdentNet(NetConfig(2, 40, 5, hidden=list(hidden), period_features=period_features,
                             phase_samples=phase_samples))
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.uniform_(-2, 2)
                m.running_var.uniform_(0.1, 4)
                m.weight.uniform_(0.5, 2)
                m.bias.uniform_(-1, 1)
    return net.eval()


#: altitude classes with periods 0.26, 0.60, 1.27 s
CLASSES = [153, 76, 10]


def three_class_set(path: Path, grid, L: int) -> None:
    """Three far-apart altitude classes simulated with the exact lumped model (h = 1, K in [0.5, 2], 2% noise)."""
    from uavsim.data.preprocess import features_batch
    from uavsim.lumped.simulate import simulate_relay_batch

    rng = np.random.default_rng(0)
    per = 24
    X, labels, K, A = [], [], [], []
    for lab, c in enumerate(CLASSES):
        p = grid.params_of(c)
        Ks = np.exp(rng.uniform(np.log(0.5), np.log(2.0), per))
        n_steps = int(8 * grid.period[c] * 200)
        sim = simulate_relay_batch("altitude", grid.beta, 1.0, 0.005, n_steps, K=Ks, T_prop=p.T_prop, T1=p.T1,
                                   tau=p.tau)
        y = -sim["e"] + 0.02 * grid.amplitude[c] * Ks[:, None] * rng.standard_normal(sim["e"].shape)
        x, _, amp, ok = features_batch(y, sim["u"], 200.0, 1.0, 0.0, L)
        assert ok.all()
        X.append(x)
        A.append(amp)
        labels += [lab] * per
        K.append(Ks)
    N = len(labels)
    z = np.zeros(N)
    eps = {"inputs": np.concatenate(X), "labels": np.array(labels), "K": np.concatenate(K), "bias": z,
           "noise_kind": z, "noise_level": z, "period": z, "amplitude": np.concatenate(A), "y0": z, "tau_obs": z, "a_n": z,
           "episode": np.arange(N), "sim_seed": z}
    ci = np.array(CLASSES)
    classes = {k: np.asarray(grid.params[k])[ci] for k in ("T_prop", "T1", "tau")}
    classes.update({k: np.asarray(getattr(grid, k))[ci] for k in
                    ("kp", "kd", "derivative_filter_hz", "omega", "amplitude", "period")})
    classes["grid_index"] = ci.astype(float)
    # the grid's table at 200 Hz, as generation writes it (identification answers from it)
    from uavsim.data.generate import class_table_gains

    classes.update({k: v[ci] for k, v in class_table_gains("altitude", 200.0, None).items() if k != "J"})
    attrs = {"loop": "altitude", "grid_hash": grid.hash, "grid_version": grid.version, "beta": grid.beta, "h": 1.0,
             "tau_obs": 0.0, "a_n": 0.0, "rate_hz": 200.0, "input_length": L, "channels": ["y", "u"],
             "cycles_per_input": 1, "recipe": "seed = 0\n", "seed": 0, "versions": "{}", "git_commit": "test",
             "n_episodes": N, "n_diverged": 0, "n_rejected": 0, "noise_kinds": ["none"]}
    write_dataset(path, eps, classes, np.asarray(grid.J)[np.ix_(ci, ci)], attrs)


@pytest.fixture(scope="session")
def three_model(tmp_path_factory):
    """A tiny network trained on ``three_class_set``: (folder, exported model folder, grid)."""
    from uavsim.data.preprocess import input_length
    from uavsim.learning.train import load_train_recipe, train
    from uavsim.tuning.grid import load_grid

    tmp = tmp_path_factory.mktemp("three")
    grid = load_grid("altitude")
    three_class_set(tmp / "three.h5", grid, input_length(grid))
    (tmp / "training").mkdir()
    rp = tmp / "training" / "three.toml"
    rp.write_text('name = "three"\nloop = "altitude"\ndataset = "three.h5"\nout = "model"\nseed = 2\n'
                  "[net]\nhidden = [64, 32]\ndropout = 0.1\n[optim]\nepochs = 25\nbatch_size = 16\nlr = 0.003\n"
                  "[early_stopping]\npatience = 25\nval_fraction = 0.2\n")
    rep = train(load_train_recipe(rp), quiet=True)
    assert rep["val"]["top1"] == 1.0
    return tmp, Path(rep["out"]), grid


class ClassNetwork:
    """A stand-in network whose activations put ``logit`` on class ``cls`` and 0 elsewhere (tests only)."""

    def __init__(self, n: int, logit: float = 1.0):
        self.n_classes, self.input_length, self.cls, self.logit = n, 0, 0, logit

    def activations(self, x):
        a = np.zeros((1, self.n_classes), np.float32)
        a[0, self.cls] = self.logit
        return a


def lateral_grid_bundle(a: int):
    """Attitude class ``a``'s lateral sub-grid, a bundle of its classes and table with a ``ClassNetwork``
    stand-in (sure of one class), and its attitude loop."""
    from uavsim.data.assemble import class_table_gains
    from uavsim.ident.bundle import ModelBundle
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.table import load_table

    sub = load_grid("lateral").lateral(a)
    tab = class_table_gains("lateral", 200.0, a)
    classes = {k: np.asarray(sub.params[k], float) for k in ("T2", "tau")}
    classes["period"] = 2 * np.pi / np.asarray(sub.omega, float)
    classes.update({k: v for k, v in tab.items() if k != "J"})
    att = dict(load_table("lateral").lateral(a).attitude)
    b = ModelBundle(dir=Path("grid"), loop="lateral", rate_hz=200.0, rule=sub.rule, input_length=0, cycles=1,
                    input_rate_hz=200.0, classes=classes, predictor=ClassNetwork(sub.n, logit=8.0), meta={}, attitude=att,
                    att_class=a, cost=tab["J"], temperature=1.0, decision="bayes")
    return sub, b, att


def lateral_class_truths(sub, b, att, *, K: float = 1.0, T2_factor: float = 1.0, tau_factor: float = 1.0,
                         tau_add_s: float = 0.0):
    """The sub-grid's classes as true processes (gain ``K``; ``T2`` times ``T2_factor`` within the box, the outer
    delay times ``tau_factor`` plus ``tau_add_s``), their optima and exact responses at the classes' MRFT points."""
    from uavsim.lumped.lateral import lateral_response_sampled
    from uavsim.lumped.params import RANGES
    from uavsim.tuning.optimal import optimal_gains

    n = sub.n
    truth = {"K": np.full(n, float(K)), "T_prop": np.full(n, att["T_prop"]), "T1": np.full(n, att["T1"]),
             "tau": b.classes["tau"] * tau_factor + tau_add_s,
             "T2": np.clip(b.classes["T2"] * T2_factor, *RANGES["lateral"]["T2"]), "tau_in": np.full(n, att["tau_in"]),
             "att_kp": np.full(n, att["att_kp"]), "att_kd": np.full(n, att["att_kd"]),
             "att_N": np.full(n, 2 * math.pi * att["att_filter_hz"]), "att_rate_hz": np.full(n, 200.0)}
    q_opt = optimal_gains("lateral", 200.0, rule=b.rule, **truth).ise
    w = np.asarray(sub.omega, float)
    G = np.array([lateral_response_sampled(np.array([w[t]]), 200.0, **{k: float(v[t]) for k, v in truth.items()
                                                                       if k != "att_rate_hz"})[0][0]
                  for t in range(n)])
    return truth, q_opt, w, G
