"""One schema for every TOML file uavsim reads, checked by one library (pydantic v2).

Five kinds of file, each a pydantic model in this package:

============  ======================================  ==========================
kind          file                                    model
============  ======================================  ==========================
session       ``SESSION/session.toml``                ``schema.session``
dataset       dataset recipes, ``datasets/*.toml``    ``schema.dataset``
training      training recipes, ``training/*.toml``   ``schema.training``
scenario      ``scenarios/*.toml``                    ``schema.scenario``
gap-model     ``uavsim gap --model FILE``             ``schema.gap``
============  ======================================  ==========================

Every model refuses unknown keys (with the closest known key as a hint),
checks types strictly (no string for a number, no boolean for an integer, no
NaN or infinity) and ranges at load, and the loaders turn the first problem
into one ``UserError`` line ``FILE: key.path: problem`` (exit 2 in the CLI).
``uavsim schema KIND`` prints the JSON Schema, which editors (Even Better
TOML / taplo, VS Code) use to check a TOML file as it is typed.

Why pydantic rather than msgspec: the files need cross-field rules (exactly one
of two keys, one parameter set per effect or run kind, ranges of [lo, hi]
pairs) and discriminated unions, and their JSON Schema should carry the
descriptions and bounds; pydantic does all of it in one declaration and its
errors carry the key path this module prints. It costs ~0.1 s of import, once.

    from uavsim.schema import load_toml, json_schema
    doc = load_toml("training/small.toml", "training")    # dict, validated
    json_schema("dataset")                                 # dict (JSON Schema)
"""

from __future__ import annotations

import difflib
import importlib
import os
import tomllib
import typing
from pathlib import Path
from typing import Any

from uavsim.errors import UserError, short_repr, type_name

__all__ = ["KINDS", "SchemaError", "model_of", "json_schema", "validate", "parse_toml", "load_toml"]

#: kind -> (module, model class name, what the file is)
KINDS: dict[str, tuple[str, str, str]] = {
    "session": ("uavsim.schema.session", "SessionFile", "a flight session's session.toml"),
    "dataset": ("uavsim.schema.dataset", "DatasetRecipe", "a dataset recipe (datasets/*.toml)"),
    "training": ("uavsim.schema.training", "TrainingRecipe", "a training recipe (training/*.toml)"),
    "scenario": ("uavsim.schema.scenario", "ScenarioFile", "a scenario (scenarios/*.toml)"),
    "gap-model": ("uavsim.schema.gap", "GapModelFile", "the model file of `uavsim gap --model FILE`"),
}


class SchemaError(UserError):
    """A file that does not match its schema; the message is ``FILE: key.path: problem`` on one line."""

    def __init__(self, message: str) -> None:
        super().__init__(message.replace("\r", "\\r").replace("\n", "\\n"))


def model_of(kind: str):
    """The pydantic model class of ``kind`` (a key of ``KINDS``)."""
    if kind not in KINDS:
        raise UserError(f"unknown file kind {kind!r} (known: {', '.join(KINDS)})")
    mod, name, _ = KINDS[kind]
    return getattr(importlib.import_module(mod), name)


def json_schema(kind: str) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of ``kind``, with a title and ``$id`` naming the kind."""
    s = _no_null(model_of(kind).model_json_schema())
    s.setdefault("title", kind)
    s["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    s["$id"] = f"uavsim:{kind}"
    s["description"] = (s.get("description") or KINDS[kind][2]).strip()
    return s


def _no_null(node: Any) -> Any:
    """TOML has no null: an optional key is one that may be left out, not one that may be null."""
    if isinstance(node, list):
        return [_no_null(x) for x in node]
    if not isinstance(node, dict):
        return node
    node = {k: _no_null(v) for k, v in node.items()}
    alts = node.get("anyOf")
    if isinstance(alts, list) and {"type": "null"} in alts:
        rest = [a for a in alts if a != {"type": "null"}]
        node.pop("anyOf")
        if len(rest) == 1:
            node = {**rest[0], **node}
        else:
            node["anyOf"] = rest
        if node.get("default", 0) is None:
            node.pop("default")
    return node


def validate(kind: str, doc: Any, where: str):
    """Validate a parsed TOML document; returns the model instance or raises ``SchemaError``."""
    from pydantic import ValidationError

    model = model_of(kind)
    if not isinstance(doc, dict):
        raise SchemaError(f"{where}: the file must be a TOML table of keys")
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        raise SchemaError(format_error(exc, model, where)) from None
    except UserError as exc:  # a validator that asks another part of uavsim (an effect's own checks)
        raise SchemaError(f"{where}: {exc}") from None


def parse_toml(text: str, where: str) -> dict[str, Any]:
    """TOML text -> dict, a syntax error as one ``SchemaError`` line naming ``where``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SchemaError(f"{where}: not valid TOML ({exc})") from None


def load_toml(path: str | os.PathLike, kind: str) -> dict[str, Any]:
    """Read, parse and validate the TOML file ``path`` as ``kind``; returns the document (a dict)."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise SchemaError(f"{p}: cannot read (no such file)") from None
    except IsADirectoryError:
        raise SchemaError(f"{p}: is a folder, not a {kind} file") from None
    except OSError as exc:
        raise SchemaError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise SchemaError(f"{p}: not UTF-8 text (bad byte at offset {exc.start})") from None
    doc = parse_toml(text, str(p))
    validate(kind, doc, str(p))
    return doc


# ---------------------------------------------------------------------------------------------
# Error messages: the first problem, ``key.path: what``, with the closest key for an unknown one


_short = short_repr
_type_word = type_name


def _unwrap(ann: Any) -> Any:
    """Strip Annotated/Optional: the model or container type a key holds."""
    while True:
        origin = typing.get_origin(ann)
        if origin is typing.Annotated:
            ann = typing.get_args(ann)[0]
        elif origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
            args = [a for a in typing.get_args(ann) if a is not type(None)]
            if len(args) != 1:
                return ann
            ann = args[0]
        else:
            return ann


def _walk(model: Any, loc: tuple) -> tuple[list[str], Any]:
    """Render ``loc`` as key path parts and return the model class at its end (for key hints).

    Union members chosen by a tag (a run's ``kind``, an effect's ``name``) appear in
    pydantic's location as the tag: it is dropped from the path, the member kept.
    """
    from pydantic import BaseModel

    parts: list[str] = []
    cur: Any = model
    for el in loc:
        cur = _unwrap(cur)
        if isinstance(el, int):
            if parts:
                parts[-1] += f"[{el}]"
            else:
                parts.append(f"[{el}]")
            args = typing.get_args(cur)
            cur = args[0] if args else None
            continue
        if isinstance(cur, type) and issubclass(cur, BaseModel) and el in cur.model_fields:
            parts.append(str(el))
            cur = cur.model_fields[el].annotation
            continue
        members = [_unwrap(a) for a in typing.get_args(cur)] if cur is not None else []
        tagged = [m for m in members if isinstance(m, type) and getattr(m, "TAG", None) == el]
        if tagged:
            cur = tagged[0]
            continue
        if isinstance(cur, type) and issubclass(cur, BaseModel):
            parts.append(str(el))  # an unknown key: the class is its parent's
            return parts, cur
        parts.append(str(el))
        cur = None
    return parts, cur


def _keys_of(model: Any) -> list[str]:
    from pydantic import BaseModel

    if isinstance(model, type) and issubclass(model, BaseModel):
        return [f.alias or n for n, f in model.model_fields.items()]
    return []


def format_error(exc, model, where: str) -> str:
    """The first error of a pydantic ``ValidationError`` as ``where: key.path: problem``."""
    errs = exc.errors(include_url=False)
    # an unknown key is the likeliest cause of the other errors (a misspelt required key)
    errs.sort(key=lambda e: e["type"] != "extra_forbidden")
    e = errs[0]
    loc = tuple(e["loc"])
    parts, _ = _walk(model, loc)
    if e["type"] == "extra_forbidden":
        _, parent = _walk(model, loc[:-1])
        known = _keys_of(_unwrap(parent))
        close = difflib.get_close_matches(str(loc[-1]), known, n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}?" if close else ("known keys: " + ", ".join(known) if known else "")
        what = f"unknown key ({hint})" if hint else "unknown key"
    else:
        what = _problem(e)
    path = ".".join(parts) if parts else "(top level)"
    more = f" (and {len(errs) - 1} more problem{'s' if len(errs) > 2 else ''})" if len(errs) > 1 else ""
    return f"{where}: {path}: {what}{more}"


def _problem(e: dict) -> str:
    t, v, ctx = e["type"], e.get("input"), e.get("ctx") or {}
    got = f", got {_type_word(v)} {_short(v)}"
    if t == "missing":
        return "missing (required)"
    if t in ("float_type", "float_parsing", "int_type", "int_parsing", "int_from_float", "decimal_type"):
        want = "an integer" if t.startswith("int") else "a number"
        return f"must be {want}{got}"
    if t == "finite_number":
        return f"must be finite, got {_short(v)}"
    if t in ("string_type", "bool_type", "list_type", "dict_type", "model_type", "model_attributes_type",
             "tuple_type"):
        want = {"string_type": "a string", "bool_type": "true or false", "list_type": "an array",
                "tuple_type": "an array"}.get(t, "a table")
        return f"must be {want}{got}"
    if t == "literal_error":
        close = difflib.get_close_matches(str(v), [s.strip("'") for s in str(ctx.get("expected", "")).split(" or ")
                                                   for s in s.split(", ")], n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}? " if close else ""
        return f"unknown value {_short(v)} ({hint}expected {ctx.get('expected', '')})"
    bounds = {"greater_than": (">", "gt"), "greater_than_equal": (">=", "ge"), "less_than": ("<", "lt"),
              "less_than_equal": ("<=", "le")}
    if t in bounds:
        op, key = bounds[t]
        return f"must be {op} {ctx.get(key)}, got {_short(v)}"
    if t in ("too_short", "too_long"):
        return e["msg"][0].lower() + e["msg"][1:] + got
    if t == "value_error":
        return str(ctx.get("error", e["msg"]))
    if t == "union_tag_invalid":
        return f"unknown {ctx.get('discriminator', 'tag').strip(chr(39))} {_short(ctx.get('tag'))} " \
               f"(expected {ctx.get('expected_tags')})"
    if t == "union_tag_not_found":
        return f"missing key {ctx.get('discriminator', '').strip(chr(39))!r}"
    return e["msg"][0].lower() + e["msg"][1:] + got
