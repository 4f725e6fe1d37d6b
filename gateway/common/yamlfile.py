"""Reading a YAML configuration file, with errors a person can act on.

Every problem becomes one line naming the file and what is wrong (``nodes.yaml: line
3: key 'nodes' appears twice``), never a traceback. Validation of what the file says
is :mod:`gateway.common.strict`'s.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml


class ConfigError(Exception):
    """A configuration file cannot be used; ``str()`` is the one-line message."""


BOOL_TAG = "tag:yaml.org,2002:bool"


class _UniqueKeyLoader(yaml.SafeLoader):
    """safe_load, except that a key given twice is an error: with PyYAML the last one
    would win silently, and a typo'd copy of a key would hide the real one; and that
    only ``true`` and ``false`` are booleans (below)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set[object] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} appears twice", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# PyYAML follows YAML 1.1, where yes, no, on and off (any case) are booleans too: a
# ``allow_eeprom_write: yes`` would be taken as true without a word, and ``name: on``
# would be no name at all. YAML 1.2's core schema, which the docs promise, has only
# true and false (and True, TRUE, False, FALSE): the others stay text, which a key that
# wants a boolean then refuses in one line (strict.py's "write true or false").
_UniqueKeyLoader.yaml_implicit_resolvers = {
    first: [(tag, pattern) for tag, pattern in resolvers if tag != BOOL_TAG]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_UniqueKeyLoader.add_implicit_resolver(
    BOOL_TAG, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))


def read_mapping(path: str | Path) -> dict[str, Any]:
    """The YAML mapping in ``path``; ConfigError naming the file for anything else."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as error:
        raise ConfigError(f"{source}: cannot read: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{source}: not a text file") from None
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader: no objects
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(error, "problem", None) or "invalid YAML"
        raise ConfigError(f"{source}: {where}{problem}") from None
    except ValueError as error:
        # PyYAML's own constructors raise plain ValueError for a value that parses but
        # cannot be built, e.g. the impossible date 2026-02-30.
        raise ConfigError(f"{source}: {error}") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: (top level): must be a mapping of keys, "
                          f"not {type(data).__name__}")
    return data


def key_path(location: tuple[int | str, ...]) -> str:
    """``("nodes", 1, "address")`` -> ``nodes[1].address``."""
    path = ""
    for part in location:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    return path or "(top level)"
