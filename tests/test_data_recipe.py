"""Recipes: strict parsing, errors that name the key and the file, shipped recipes valid."""

from pathlib import Path

import pytest

from uavsim.data.recipe import load_recipe, parse_recipe
from uavsim.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
MINIMAL = 'loop = "altitude"\nseed = 1\n[episodes]\nper_class = 2\ncycles = 5\n'


def test_minimal_defaults():
    r = parse_recipe(MINIMAL)
    assert r.loop == "altitude" and r.seed == 1 and r.episodes.per_class == 2
    assert r.noise.kinds == ("none",) and r.test.beta is None and r.episodes.dt == 0.001
    assert r.text == MINIMAL and len(r.hash) == 64


@pytest.mark.parametrize("text, needle", [
    (MINIMAL + "[test]\nbetta = -0.7\n", "test.betta"),
    ("colour = 1\n" + MINIMAL, "colour: unknown key"),
    (MINIMAL + "[[effects]]\nname = 'delay'\ndleay = 0.01\n", "effects[0].dleay: unknown key (did you mean 'delay'?)"),
    (MINIMAL + "[[effects]]\nname = 'delay'\ndelay = [0.01, -0.1]\n", "reversed"),
    (MINIMAL + "[[effects]]\nname = 'delay'\ndelay = [-0.1, 0.01]\n", "effects[0]: effect delay: delay must be >= 0"),
    (MINIMAL + "[noise]\nkinds = ['pink']\n", "noise.kinds"),
    (MINIMAL + "[noise]\nlevel = [0.0, 0.3]\n", "noise.level"),
    (MINIMAL + "[randomize]\nbias = 0.7\n", "randomize.bias"),
    (MINIMAL.replace("seed = 1\n", ""), "seed"),
    (MINIMAL.replace('"altitude"', '"yaw"'), "loop"),
    (MINIMAL + "duration_s = 5.0\n", "exactly one"),
    (MINIMAL.replace("cycles = 5", "cycles = 2.5"), "cycles"),
    (MINIMAL + "[[effects]]\nname = 'warp'\n", "warp"),
    (MINIMAL + "[test]\nbeta = 1.0\n", "beta"),
    (MINIMAL.replace("[episodes]", "[episodes]\ndt = 0.0007"), "whole number"),
    ("loop = [", "not valid TOML"),
])
def test_bad_recipes_name_the_problem(text, needle):
    with pytest.raises(UserError, match=r"bad\.toml") as exc:
        parse_recipe(text, "bad.toml")
    assert needle in str(exc.value)


def test_load_names_file(tmp_path):
    p = tmp_path / "r.toml"
    p.write_text(MINIMAL + "[preprocess]\nkeep_raws = true\n")
    with pytest.raises(UserError, match=r"r\.toml.*preprocess\.keep_raws"):
        load_recipe(p)
    with pytest.raises(UserError, match="cannot read"):
        load_recipe(tmp_path / "missing.toml")


def test_effect_ranges():
    r = parse_recipe(MINIMAL + "[[effects]]\nname = 'delay'\ndelay = [0.0, 0.005]\n")
    assert r.effects[0].name == "delay" and r.effects[0].params["delay"] == (0.0, 0.005)


@pytest.mark.parametrize("name", ["small", "altitude", "attitude", "lateral"])
def test_shipped_recipes_parse(name):
    r = load_recipe(ROOT / "datasets" / f"{name}.toml")
    assert r.name == name
