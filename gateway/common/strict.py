"""Strict pydantic models and the one formatter of their errors, for the programs that
validate a file or a request with them (the gateway and gx2-sim; never gx2ctl's own
start-up, which must stay quick).

Strict: an unknown key is an error, so a typo never passes silently, and a YAML
``yes`` is not a bool nor ``"115200"`` an int (an int is still a float).
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from .yamlfile import ConfigError, key_path, read_mapping

M = TypeVar("M", bound=BaseModel)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


def describe(error: ValidationError, source: str = "", *, skip: int = 0,
             noun: str = "key") -> str:
    """The first problem pydantic found as one line, ``source: where: what`` (and how
    many more there are). ``skip`` drops leading parts of the location (a tagged
    union's tag); ``noun`` is what an unknown name is called ("key", "field")."""
    problems = error.errors(include_url=False)
    first = problems[0]
    message = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        message = "unknown key (a typo?)" if noun == "key" else f"unknown {noun}"
    elif first["type"] == "missing":
        message = f"required {noun} is missing"
    elif first["type"] in ("bool_type", "bool_parsing"):
        message = f"must be a boolean: write true or false, not {first['input']!r}"
    more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
    location = tuple(first["loc"][skip:])
    parts = [part for part in (source, key_path(location) if location else "") if part]
    return ": ".join([*parts, message]) + more


def load_model(path: str | Path, model: type[M]) -> M:
    """Read ``path`` as YAML and validate it as ``model``; raise ConfigError."""
    data = read_mapping(path)
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(describe(error, str(path))) from None
