"""Strict pydantic models and the one formatter of their errors, for the programs that
validate a file or a request with them (the gateway and gx2-sim; never gx2ctl's own
start-up, which must stay quick).

Strict: an unknown key is an error, so a typo never passes silently, and a YAML
``yes`` is not a bool nor ``"115200"`` an int (an int is still a float).
"""

from __future__ import annotations

import difflib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from .yamlfile import ConfigError, key_path, read_mapping

M = TypeVar("M", bound=BaseModel)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


def describe(error: ValidationError, source: str = "", *, skip: int = 0,
             noun: str = "key", model: type[BaseModel] | None = None) -> str:
    """Every problem pydantic found, in one line: ``source: where: what; where: what``.
    ``skip`` drops leading parts of the location (a tagged union's tag); ``noun`` is
    what an unknown name is called ("key", "field"); ``model``, what was validated,
    lets an unknown key name the key it may be a typo of.

    Pydantic lists problems in the order of the model's fields, with unknown keys last:
    a typo (``node:`` for ``nodes:``) came out as ``nodes: required key is missing``,
    the typo itself after it. An unknown key is most often the cause of the other
    problems near it, so it is said first; one that is close to a known key first of
    all, with that key. All are said (issue 43: ``(and 1 more)`` left a user fixing a
    file one run at a time)."""
    problems = error.errors(include_url=False)
    hints = {index: _near(model, tuple(problem["loc"][skip:]))
             for index, problem in enumerate(problems)
             if problem["type"] == "extra_forbidden"}
    order = sorted(range(len(problems)),
                   key=lambda i: 0 if hints.get(i) else 1 if i in hints else 2)
    said = [_problem(problems[i], hints.get(i), skip, noun) for i in order]
    return ": ".join([source, "; ".join(dict.fromkeys(said))] if source
                     else ["; ".join(dict.fromkeys(said))])


def _problem(problem: Any, near: str | None, skip: int, noun: str) -> str:
    """One problem: ``where: what``."""
    message = problem["msg"].removeprefix("Value error, ")
    if problem["type"] == "extra_forbidden":
        message = (f"unknown {noun} (did you mean {near}?)" if near
                   else "unknown key (a typo?)" if noun == "key" else f"unknown {noun}")
    elif problem["type"] == "missing":
        message = f"required {noun} is missing"
    elif problem["type"] in ("bool_type", "bool_parsing"):
        message = f"must be a boolean: write true or false, not {problem['input']!r}"
    location = tuple(problem["loc"][skip:])
    return f"{key_path(location)}: {message}" if location else message


def _near(model: type[BaseModel] | None, location: tuple[int | str, ...]) -> str | None:
    """The known key that an unknown one at ``location`` is closest to, if any is close."""
    if model is None or not location or not isinstance(location[-1], str):
        return None
    kind: Any = model
    for part in location[:-1]:
        kind = _inside(kind, part)
    known = [name for option in _options(kind) if _is_model(option)
             for name in option.model_fields]
    close = difflib.get_close_matches(location[-1], known, n=1, cutoff=0.6)
    return close[0] if close else None


def _inside(kind: Any, part: int | str) -> Any:
    """The type of the value at ``part`` of a value of type ``kind`` (None if unknown)."""
    for option in _options(kind):
        if isinstance(part, str) and _is_model(option) and part in option.model_fields:
            return option.model_fields[part].annotation
        if isinstance(part, int) and typing.get_origin(option) in (list, tuple):
            return typing.get_args(option)[0]
    return None


def _options(kind: Any) -> list[Any]:
    """``kind`` without its Annotated metadata, as the list of its union's members."""
    origin = typing.get_origin(kind)
    if origin is typing.Annotated:
        return _options(typing.get_args(kind)[0])
    if origin in (typing.Union, types.UnionType):
        return [member for arg in typing.get_args(kind) for member in _options(arg)]
    return [kind]


def _is_model(kind: Any) -> bool:
    return isinstance(kind, type) and issubclass(kind, BaseModel)


def load_model(path: str | Path, model: type[M]) -> M:
    """Read ``path`` as YAML and validate it as ``model``; raise ConfigError."""
    data = read_mapping(path)
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(describe(error, str(path), model=model)) from None
