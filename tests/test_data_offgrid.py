"""Off-centre training episodes (``randomize.offgrid``) and their per-sample cost vectors."""

import math
from pathlib import Path

import numpy as np
import pytest

from uavsim.data.generate import generate
from uavsim.data.h5 import open_dataset
from uavsim.data.plan import load_family_grid, make_plan
from uavsim.data.recipe import load_recipe, parse_recipe
from uavsim.errors import UserError
from uavsim.ident.response import fit_response
from uavsim.learning.train import load_training_data
from uavsim.lumped.params import box_coordinates
from uavsim.lumped.sampled import step_ise_sampled

ROOT = Path(__file__).resolve().parents[1]
SMALL = (ROOT / "datasets" / "small.toml").read_text()


def _offgrid_text(share: float) -> str:
    return SMALL.replace("y0 = 0.5\n", f"y0 = 0.5\noffgrid = {share}\n", 1)


def test_offgrid_parsed_checked_and_off_by_default():
    assert load_recipe(ROOT / "datasets" / "small.toml").randomize.offgrid == 0.0
    assert parse_recipe(_offgrid_text(0.5)).randomize.offgrid == 0.5
    with pytest.raises(UserError, match="offgrid"):
        parse_recipe(_offgrid_text(1.5))
    lateral = (ROOT / "datasets" / "lateral.toml").read_text()
    assert "[randomize]" in lateral
    with pytest.raises(UserError, match="offgrid"):
        parse_recipe(lateral.replace("[randomize]\n", "[randomize]\noffgrid = 0.5\n", 1))


def test_plan_draws_off_centre_processes_in_their_cells_and_moves_no_other_draw():
    r0 = parse_recipe(SMALL, "small.toml")
    r = parse_recipe(_offgrid_text(0.5), "small.toml")
    g = load_family_grid(r)
    p0, p, again = make_plan(r0, g), make_plan(r, g), make_plan(r, g)
    assert p0.process is None and p0.offgrid is None
    for k in ("K", "bias", "noise_kind", "noise_level", "labels"):
        assert np.array_equal(getattr(p, k), getattr(p0, k)), k
    for k, v in p.process.items():
        assert np.array_equal(v, again.process[k])  # seeded: the same plan again
    nt = p.n_train
    off = p.offgrid
    assert off[:nt].sum() == round(0.5 * r.episodes.per_class) * len(r.classes) and not off[nt:].any()
    cls = p.class_index[p.labels]
    centre = {k: np.asarray(g.params[k], float)[cls] for k in ("T_prop", "T1", "tau")}
    for k in centre:
        assert np.array_equal(p.process[k][~off], centre[k][~off])
        assert not np.any(p.process[k][off] == centre[k][off])
    # each drawn process is nearer its own class than any other class of the whole grid
    P = box_coordinates(r.loop, p.process)
    C = box_coordinates(r.loop, g.params)
    near = np.argmin(((P[:, None, :] - C[None, :, :]) ** 2).sum(axis=-1), axis=1)
    assert np.array_equal(near, cls)
    assert np.all((P >= 0) & (P <= 1))
    # the expected cycle follows the drawn process (noise scale, episode length), not the centre's
    assert not np.allclose(p.a0[:nt][off[:nt]], p0.a0[:nt][off[:nt]])


@pytest.fixture(scope="module")
def offgrid_set(tmp_path_factory):
    d = tmp_path_factory.mktemp("offgrid")
    rec = d / "small-offgrid.toml"
    rec.write_text(_offgrid_text(0.5))
    out = d / "small-offgrid.h5"
    generate(load_recipe(rec), out, progress=False)
    return rec, out


def test_costs_are_the_answers_sampled_ise_on_each_own_process(offgrid_set):
    _, out = offgrid_set
    ds = open_dataset(out)
    N, nc = ds.n, ds.n_classes
    assert ds.cost.shape == (N, nc) and ds.attrs["offgrid"] == 0.5 and "cost_source" in ds.attrs
    assert ds.offgrid.any() and not ds.offgrid.all()
    finite = np.isfinite(ds.cost)
    assert np.allclose(np.nanmin(np.where(finite, ds.cost, np.nan), axis=1), 1.0)
    c = ds.class_table
    rate = float(ds.attrs["rate_hz"])
    for s in (0, int(np.flatnonzero(ds.offgrid)[0]), N - 1):
        # one (answer, process) pair at a time, from the stored process and response
        resp = ds.response_re[s] + 1j * ds.response_im[s]
        ise = np.empty(nc)
        for i in range(nc):
            K_hat = fit_response(np.array([resp]), np.array([ds.response_period[s]]), T_prop=c["T_prop"][i],
                                 T1=c["T1"][i], tau_class=c["tau"][i], rate_hz=rate)["K"][0]
            q = step_ise_sampled(ds.attrs["loop"], np.array([c["table_robust_kp"][i] / K_hat]),
                                 np.array([c["table_robust_kd"][i] / K_hat]),
                                 np.array([2 * math.pi * c["table_filter_hz"][i]]), rate, K=np.array([ds.K[s]]),
                                 T_prop=np.array([ds.process_T_prop[s]]), T1=np.array([ds.process_T1[s]]),
                                 tau=np.array([ds.process_tau[s]]))[0]
            ise[i] = q if np.isfinite(q) else np.inf
        assert np.allclose(ds.cost[s], ise / ise.min(), rtol=1e-9)
    # the trainer reads them: each sample's own row, where a set without them takes J's columns
    data = load_training_data(out)
    idx = np.arange(N)
    assert np.array_equal(data.costs(idx), ds.cost)
    data.cost = None
    assert np.array_equal(data.costs(idx), ds.J[:, ds.labels].T)


def test_offgrid_set_same_recipe_same_bytes(offgrid_set, tmp_path):
    from test_data_generate_identity import h5_digest

    rec, out = offgrid_set
    again = tmp_path / "again.h5"
    generate(load_recipe(rec), again, progress=False)
    assert h5_digest(again) == h5_digest(out)


def test_best_target_is_each_samples_least_cost_class(offgrid_set, tmp_path):
    import dataclasses
    import hashlib
    import json

    from uavsim.learning.train import best_classes, load_train_recipe

    _, out = offgrid_set
    data = load_training_data(out)
    best = best_classes(data)
    C = np.where(np.isfinite(data.cost), data.cost, np.inf)
    assert np.array_equal(best, C.argmin(axis=1)) and np.all(C[np.arange(len(best)), best] == 1.0)
    data.cost = None
    with pytest.raises(UserError, match="per-sample costs"):
        best_classes(data)
    text = (ROOT / "training" / "attitude.toml").read_text()
    (tmp_path / "training").mkdir()
    p = tmp_path / "training" / "t.toml"
    p.write_text(text.replace('weight = 5.0\n', 'weight = 5.0\ntarget = "best"\n', 1))
    assert load_train_recipe(p).loss_target == "best"
    p.write_text(text.replace('weight = 5.0\n', 'weight = 5.0\ntarget = "nearest"\n', 1))
    with pytest.raises(UserError):
        load_train_recipe(p)
    # the defaults leave the fingerprint of recipes written before the keys (resume) as it was
    r = load_train_recipe(ROOT / "training" / "attitude.toml")
    d = dataclasses.asdict(r)
    for k in ("source", "max_minutes", "threads", "device", "epochs", "patience", "loss_target", "phase_samples"):
        d.pop(k)
    assert r.fingerprint() == hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]
