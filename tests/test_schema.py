"""One schema for every TOML file kind: JSON Schema out, one-line errors, and fuzzing of every loader.

The fuzz tests mutate the shipped files of each kind (delete, retype, misspell,
add keys at any depth) and also build random documents from the kind's
vocabulary; the loader of the kind must either accept the file or raise a
``UserError`` whose one line starts with the file, and must write nothing.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_session import to_toml  # TOML text of any test document

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.schema import KINDS, json_schema, load_toml

ROOT = Path(__file__).resolve().parents[1]
FUZZ = settings(max_examples=1000, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])

SHIPPED = {
    "session": ROOT / "scenarios/sessions/altitude-npmrft/session.toml",
    "dataset": ROOT / "datasets/small.toml",
    "training": ROOT / "training/small.toml",
    "scenario": ROOT / "scenarios/normal-camera-kf.toml",
}
GAP_MODEL = {"model": {"K": 20.0, "T_prop": 0.1, "T1": 0.8, "tau": 0.02, "noise_std": 0.001}}


def base_doc(kind: str) -> dict:
    if kind == "gap-model":
        return copy.deepcopy(GAP_MODEL)
    return tomllib.loads(SHIPPED[kind].read_text())


# ---------------------------------------------------------------------------------------------
# Strategies: mutations of a valid document, and documents built from the kind's vocabulary

scalars = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, 1, -1, 0.0, -0.0, 1e-300, 1e300, 0.5, 2, 100, 1e9]),
    st.text(max_size=12),
    st.booleans(),
    st.dates(),
)
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                      st.dictionaries(st.text(min_size=1, max_size=8), inner,
                                                                      max_size=3)), max_leaves=6)


def _paths(node, prefix=()):
    """Every (container path, key) of a document, tables and array items included."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield prefix, k
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield prefix, i
            yield from _paths(v, (*prefix, i))


def _vocabulary(doc) -> list[str]:
    keys: set[str] = set()
    for _, k in _paths(doc):
        if isinstance(k, str):
            keys.add(k)
    return sorted(keys)


def _typo(k: str, i: int) -> str:
    if not k:
        return "x"
    i %= len(k)
    return k[:i] + k[i + 1:] if len(k) > 1 else k + k


@st.composite
def mutated(draw, kind: str):
    doc = base_doc(kind)
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(doc))
        if not paths:
            break
        parent_path, key = draw(st.sampled_from(paths))
        parent = doc
        for p in parent_path:
            parent = parent[p]
        op = draw(st.sampled_from(["delete", "set", "add", "typo", "wrap"]))
        if op == "delete":
            del parent[key]
        elif op == "set":
            parent[key] = draw(values)
        elif op == "add" and isinstance(parent, dict):
            parent[draw(st.sampled_from([*_vocabulary(doc), "x", "seed"]))] = draw(values)
        elif op == "typo" and isinstance(parent, dict) and isinstance(key, str):
            parent[_typo(key, draw(st.integers(0, 20)))] = parent.pop(key)
        elif op == "wrap":
            parent[key] = [parent[key]] if draw(st.booleans()) else {"x": parent[key]}
    return doc


@st.composite
def built(draw, kind: str):
    """A document from the kind's own keys with random values (tables kept as tables, mostly)."""
    base = base_doc(kind)
    vocab = _vocabulary(base)
    doc = {}
    for k, v in base.items():
        if draw(st.integers(0, 4)) == 0:
            continue
        if isinstance(v, dict):
            doc[k] = {kk: (vv if draw(st.booleans()) else draw(values)) for kk, vv in v.items()
                      if draw(st.integers(0, 5))}
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            doc[k] = [{kk: (vv if draw(st.booleans()) else draw(values)) for kk, vv in item.items()}
                      for item in v]
        else:
            doc[k] = v if draw(st.booleans()) else draw(values)
    for _ in range(draw(st.integers(0, 2))):
        doc[draw(st.sampled_from(vocab))] = draw(values)
    return doc


# ---------------------------------------------------------------------------------------------
# Loaders under test: each reads the file the way its command does


def _load_session(path: Path) -> None:
    from uavsim.formats.session import read_session

    read_session(path)


def _load_dataset(path: Path) -> None:
    from uavsim.data.recipe import load_recipe

    load_recipe(path)


def _load_training(path: Path) -> None:
    from uavsim.learning.train import load_train_recipe

    load_train_recipe(path)


def _load_scenario(path: Path) -> None:
    from uavsim.scenario.config import load_scenario

    load_scenario(path)


def _load_gap(path: Path) -> None:
    from uavsim.gap.workflow import read_model_file

    read_model_file(path, "altitude")


LOADERS = {"session": _load_session, "dataset": _load_dataset, "training": _load_training,
           "scenario": _load_scenario, "gap-model": _load_gap}


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*")}


def _check_one(kind: str, folder: Path, doc: dict) -> str:
    name = "session.toml" if kind == "session" else f"{kind}.toml"
    path = folder / name
    try:
        text = to_toml(doc)
    except TypeError:
        return "unwritable"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    before = _snapshot(folder)
    try:
        LOADERS[kind](path)
        outcome = "accepted"
    except UserError as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        # the file named is the one at fault: the TOML, or a data file it points to (a session's CSV)
        assert msg.startswith(str(folder) + "/"), msg
        outcome = "refused"
    assert _snapshot(folder) == before, "the loader wrote something"
    return outcome


@pytest.fixture(scope="module")
def session_folder(tmp_path_factory) -> Path:
    import shutil

    d = tmp_path_factory.mktemp("fuzz-session")
    for f in SHIPPED["session"].parent.iterdir():
        shutil.copy(f, d / f.name)
    return d


def _fuzz(kind: str, folder: Path) -> None:
    counts = {"accepted": 0, "refused": 0, "unwritable": 0}

    @FUZZ
    @given(doc=st.one_of(mutated(kind), built(kind)))
    def run(doc):
        counts[_check_one(kind, folder, doc)] += 1

    run()
    # both outcomes occur: the fuzz reaches past the first check (and the shipped file is valid)
    assert counts["refused"] >= 200 and counts["accepted"] >= 1, counts
    assert sum(counts.values()) >= 1000, counts


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "session"])
def test_fuzz_kind(kind, tmp_path):
    _fuzz(kind, tmp_path)


def test_fuzz_session(session_folder):
    _fuzz("session", session_folder)


# ---------------------------------------------------------------------------------------------
# The schema itself


@pytest.mark.parametrize("kind", list(KINDS))
def test_json_schema_and_shipped_files(kind, capsys):
    s = json_schema(kind)
    assert s["type"] == "object" and s["additionalProperties"] is False
    assert "null" not in json.dumps(s)  # TOML has no null: optional keys are left out
    assert cli_main.main(["schema", kind]) == 0
    assert json.loads(capsys.readouterr().out) == s
    if kind in SHIPPED:
        load_toml(SHIPPED[kind], kind)


def _schema_accepts(schema: dict, doc) -> bool:
    """A small JSON Schema check of the keywords the schemas use (no jsonschema dependency)."""
    defs = schema.get("$defs", {})

    def ok(node, v) -> bool:
        if "$ref" in node:
            return ok(defs[node["$ref"].split("/")[-1]], v)
        if "anyOf" in node and not any(ok(a, v) for a in node["anyOf"]):
            return False
        if "oneOf" in node and sum(ok(a, v) for a in node["oneOf"]) != 1:
            return False
        t = node.get("type")
        types = {"object": dict, "array": list, "string": str, "boolean": bool}
        if t == "number" and (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)):
            return False
        if t == "integer" and (isinstance(v, bool) or not isinstance(v, int)):
            return False
        if t in types and not isinstance(v, types[t]):
            return False
        if "const" in node and v != node["const"]:
            return False
        if "enum" in node and v not in node["enum"]:
            return False
        for k, op in (("minimum", lambda a, b: a >= b), ("maximum", lambda a, b: a <= b),
                      ("exclusiveMinimum", lambda a, b: a > b), ("exclusiveMaximum", lambda a, b: a < b)):
            if k in node and isinstance(v, int | float) and not op(v, node[k]):
                return False
        if isinstance(v, list):
            if len(v) < node.get("minItems", 0) or len(v) > node.get("maxItems", len(v)):
                return False
            if "items" in node and not all(ok(node["items"], x) for x in v):
                return False
        if isinstance(v, dict) and ("properties" in node or "required" in node):
            props = node.get("properties", {})
            if any(k not in v for k in node.get("required", [])):
                return False
            if node.get("additionalProperties") is False and any(k not in props for k in v):
                return False
            if not all(ok(props[k], x) for k, x in v.items() if k in props):
                return False
        return True

    return ok(schema, doc)


@pytest.mark.parametrize("kind", ["training", "gap-model"])
def test_json_schema_agrees_with_the_loader(kind, tmp_path):
    """For kinds without cross-field rules, the printed JSON Schema accepts exactly what the loader does."""
    s = json_schema(kind)
    loader = {"training": "training", "gap-model": "gap-model"}[kind]

    @settings(max_examples=300, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(doc=st.one_of(mutated(kind), built(kind)))
    def run(doc):
        p = tmp_path / "f.toml"
        try:
            p.write_text(to_toml(doc))
            doc = tomllib.loads(p.read_text())
        except (TypeError, tomllib.TOMLDecodeError, UnicodeEncodeError):
            return
        try:
            load_toml(p, loader)
            accepted = True
        except UserError:
            accepted = False
        if kind == "gap-model" and accepted != _schema_accepts(s, doc):
            # "[model] or top-level keys" is a rule JSON Schema here does not state
            return
        assert accepted == _schema_accepts(s, doc), doc

    run()


def test_one_line_errors_name_file_and_key(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text('name = "a"\nloop = "altitude"\ndataset = "x.h5"\nout = "o"\n[optim]\nlr = "0.01"\n')
    with pytest.raises(UserError) as info:
        load_toml(p, "training")
    assert str(info.value) == f"{p}: optim.lr: must be a number, got string '0.01'"
    p.write_text('loop = "altitude"\nseed = 1\n[episodes]\nper_class = 2\ncycles = 8\n'
                 '[[effects]]\nname = "delay"\ndleay = 0.01\n')
    with pytest.raises(UserError) as info:
        load_toml(p, "dataset")
    assert str(info.value) == f"{p}: effects[0].dleay: unknown key (did you mean 'delay'?)"


def test_cli_refuses_bad_files_with_exit_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """Each command that reads a TOML kind: bad file -> one line on stderr, exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    bad_train = tmp_path / "training" / "t.toml"
    bad_train.parent.mkdir()
    bad_train.write_text('name = "a"\nloop = "altitude"\ndataset = "x.h5"\nout = "runs/a"\n[optim]\nlr = "0.01"\n')
    bad_recipe = tmp_path / "d.toml"
    bad_recipe.write_text('loop = "altitude"\nseed = 1\n[episodes]\nper_class = 2\ncycles = 8\n'
                          '[[effects]]\nname = "delay"\ndleay = 0.01\n')
    bad_scn = tmp_path / "s.toml"
    bad_scn.write_text('format = "uavsim-scenario/1"\nseed = "seven"\n')
    cases = [
        (["train", str(bad_train)], "optim.lr"),
        (["generate", str(bad_recipe), "--out", str(tmp_path / "d.h5")], "effects[0].dleay"),
        (["scenario", "run", str(bad_scn), "--save", str(tmp_path / "s.rrd"), "--sessions", str(tmp_path / "ss")],
         "seed"),
        (["schema", "dataset", "--check", str(bad_recipe)], "dleay"),
    ]
    for argv, key in cases:
        before = sorted(os.listdir(tmp_path))
        rc = cli_main.main(argv)
        out, err = capsys.readouterr()
        assert rc == 2, (argv, err)
        assert err.count("\n") == 1 and "Traceback" not in err and key in err, err
        assert sorted(os.listdir(tmp_path)) == before, argv
    assert not (tmp_path / "training" / "runs").exists()
