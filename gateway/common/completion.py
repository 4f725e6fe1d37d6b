"""Shell completion (bash, zsh) and man pages for every program, generated from its own
argparse parser, so that neither can say something the program does not accept.

Each program's parser (:class:`gateway.common.args.ArgumentParser`) has
``--print-completion SHELL`` (the script, by shtab) and ``--print-man`` (the roff page,
by argparse-manpage); both libraries are imported only then, so no other run pays for
them. A hidden ``--complete-nodes FILE`` prints the node addresses a configuration
names, for the completion of a NODE argument to call.

What an argument completes to follows from how the parser reads it: an argparse type
made by :func:`gateway.common.args.argtype` carries its :class:`~gateway.common.values.Kind`
(a node address: the nodes of the ``--config`` on the line; a kind with choices, such as
a record: those), and a metavar naming a file or directory (``FILE``, ``FILE.mcap``,
``DIR``) completes paths.
"""

from __future__ import annotations

import argparse
import copy
import re
from collections.abc import Iterator
from typing import Any

from .values import NODE, Kind
from .version import installed

SHELLS = ("bash", "zsh")
NODES_OPTION = "--complete-nodes"
NODES_FUNCTION = "_gx2_complete_nodes"
PROJECT = "gx2-gateway"
"""The distribution: its version and programs are in each man page."""
FILE_METAVARS = re.compile(r"FILE(\..*)?|.*FILE|PATH|PREFIX")
DIR_METAVARS = re.compile(r"DIR")

# A NODE argument completes to the addresses of the --config FILE given earlier on the
# line (also as --config=FILE, which bash splits at '='), asked of the program itself
# (the command word as typed, ~ expanded) so that the same YAML reader reads it; the
# program prints nothing for a file it cannot read, and errors are silenced here too.
# The zsh function reads the line from LBUFFER: zsh narrows $words to the subcommand's
# own words, which no longer hold the program's options.
BASH_NODES = r"""
@NODES_FUNCTION@() {
  local i config=
  for ((i = 1; i < COMP_CWORD; i++)); do
    case ${COMP_WORDS[i]} in
      --config)
        config=${COMP_WORDS[i+1]}
        [[ $config == = ]] && config=${COMP_WORDS[i+2]} ;;
      --config=*) config=${COMP_WORDS[i]#--config=} ;;
    esac
  done
  [[ -n $config ]] || return 0
  compgen -W "$("${COMP_WORDS[0]/#\~/$HOME}" @NODES_OPTION@ "${config/#\~/$HOME}" \
    2>/dev/null)" -- "$1"
}"""
ZSH_NODES = r"""
@NODES_FUNCTION@() {
  local i config
  local -a typed nodes
  typed=(${(Q)${(z)LBUFFER}})
  for ((i = 2; i < $#typed; i++)); do
    case $typed[i] in
      --config) config=$typed[i+1] ;;
      --config=*) config=${typed[i]#--config=} ;;
    esac
  done
  [[ -n $config ]] || return 1
  nodes=(${(f)"$(${typed[1]/#\~/$HOME} @NODES_OPTION@ ${config/#\~/$HOME} 2>/dev/null)"})
  _describe -t nodes 'node address' nodes
}"""
BASH_NODES, ZSH_NODES = (
    snippet.replace("@NODES_FUNCTION@", NODES_FUNCTION).replace("@NODES_OPTION@", NODES_OPTION)
    for snippet in (BASH_NODES, ZSH_NODES))


# --- the actions every program's parser has ------------------------------------------

class PrintCompletion(argparse.Action):
    """``--print-completion SHELL``: the completion script, then exit."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        print(completion_script(parser, values), end="")
        parser.exit()


class PrintMan(argparse.Action):
    """``--print-man``: the man page, then exit."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        print(man_page(parser), end="")
        parser.exit()


class CompleteNodes(argparse.Action):
    """``--complete-nodes FILE`` (hidden): FILE's node addresses, one a line, then exit."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        addresses = node_addresses(values)
        if addresses:
            print("\n".join(map(str, addresses)))
        parser.exit()


def add_options(parser: argparse.ArgumentParser) -> None:
    """The options above, on a program's own parser."""
    parser.add_argument("--print-completion", choices=SHELLS, action=PrintCompletion,
                        metavar="SHELL", help="print the shell completion script for "
                        "SHELL (bash or zsh) and exit")
    parser.add_argument("--print-man", nargs=0, action=PrintMan,
                        help="print the man page (roff) and exit")
    parser.add_argument(NODES_OPTION, action=CompleteNodes, metavar="FILE",
                        help=argparse.SUPPRESS)


def node_addresses(path: str) -> list[int]:
    """The node addresses the configuration at ``path`` lists (a gateway's or the
    simulator's: both have ``nodes:`` with ``address:``); none for a file that is not
    one: a completion shows no error."""
    from .yamlfile import read_mapping
    # whatever the reason: besides ConfigError, PyYAML raises ValueError for a date
    # that cannot be (2001-02-30) and RecursionError for brackets nested thousands deep
    try:
        config = read_mapping(path)
    except Exception:
        return []
    # the one-station form's nodes:, or every station's (base_stations:)
    stations = config.get("base_stations")
    groups = [config.get("nodes")] + ([s.get("nodes") for s in stations if isinstance(s, dict)]
                                      if isinstance(stations, list) else [])
    nodes = [node for group in groups if isinstance(group, list) for node in group]
    found = []
    for node in nodes:
        address = node.get("address") if isinstance(node, dict) else None
        if isinstance(address, int) and not isinstance(address, bool):
            try:
                found.append(NODE.check(address))
            except ValueError:
                continue
    return found


# --- completion ------------------------------------------------------------------------

def completion_script(parser: argparse.ArgumentParser, shell: str) -> str:
    """The ``shell`` completion script for ``parser``'s program."""
    import shtab
    annotated = copy.deepcopy(parser)  # the parser that runs is left as it was
    for action in actions(annotated):
        completer = completer_for(action, shtab.FILE, shtab.DIRECTORY)
        if completer is not None:
            action.complete = completer  # type: ignore[attr-defined]
    return shtab.complete(annotated, shell)


def actions(parser: argparse.ArgumentParser) -> Iterator[argparse.Action]:
    """Every action of the parser and of its subcommands' parsers."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen: set[int] = set()
            for sub in action.choices.values():
                if id(sub) not in seen:  # an alias names the same parser
                    seen.add(id(sub))
                    yield from actions(sub)
        else:
            yield action


def completer_for(action: argparse.Action, files: dict[str, str],
                  directories: dict[str, str]) -> dict[str, Any] | None:
    """shtab's ``complete`` for one argument, or None for its default (choices, if any)."""
    if action.choices is not None or action.nargs == 0:
        return None
    kind = getattr(action.type, "kind", None)
    if kind is NODE:
        return {"bash": NODES_FUNCTION, "zsh": NODES_FUNCTION,
                "preamble": {"bash": BASH_NODES, "zsh": ZSH_NODES}}
    if isinstance(kind, Kind) and kind.choices:
        return words(kind)
    metavar = action.metavar if isinstance(action.metavar, str) else ""
    if FILE_METAVARS.fullmatch(metavar):
        return files
    if DIR_METAVARS.fullmatch(metavar):
        return directories
    return None


def words(kind: Kind) -> dict[str, Any]:
    """A completer of the kind's choices: bash takes a function, zsh a list."""
    function = "_gx2_words_" + re.sub(r"\W", "_", kind.name)
    listed = " ".join(kind.choices)
    return {"bash": function, "zsh": f"({listed})",
            "preamble": {"bash": f'\n{function}() {{\n  compgen -W "{listed}" -- "$1"\n}}'}}


# --- man pages -------------------------------------------------------------------------

def man_page(parser: argparse.ArgumentParser) -> str:
    """The roff man page (section 1) of ``parser``'s program."""
    from argparse_manpage.manpage import Manpage
    page_parser = copy.deepcopy(parser)  # changed below; the parser that runs is not
    for group in page_parser._action_groups:
        if any(isinstance(a, argparse._SubParsersAction) for a in group._group_actions):
            group.title = "commands"
    # a subcommand's page shows its help, then its description: once where they are one
    for sub, help_text in subcommands(page_parser):
        if sub.description == help_text:
            sub.description = None
    page = Manpage(page_parser, {
        "project_name": PROJECT, "version": installed(), "manual_title": f"{PROJECT} manual",
        "description": summary(parser.description or "")}, format="single-commands-section")
    # argparse-manpage escapes the synopsis's first word (the program) but leaves the
    # others as they are, where roff needs \- for a hyphen that is typed (an option's
    # dash), as the library gives it everywhere else
    first, *rest = page.synopsis
    page.synopsis = [first, *(escape(word) for word in rest)]
    others = [name for name in programs() if name != parser.prog]
    page.add_section("see also", "=", ",\n".join(f".BR {escape(name)} (1)"
                                                 for name in others))
    return str(page)


def subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[argparse.ArgumentParser,
                                                                   str | None]]:
    """Every subcommand's parser below ``parser``, with its help in the list of commands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for listed in action._choices_actions:
                sub = action.choices[listed.dest]
                yield sub, listed.help
                yield from subcommands(sub)


def programs() -> list[str]:
    """The distribution's programs (pyproject.toml's ``[project.scripts]``)."""
    from importlib.metadata import PackageNotFoundError, distribution
    try:
        scripts = distribution(PROJECT).entry_points.select(group="console_scripts")
    except PackageNotFoundError:  # pragma: no cover - a source tree, not installed
        return []
    return sorted(script.name for script in scripts)


def summary(description: str) -> str:
    """The description's first sentence, without its full stop: the NAME line."""
    return re.split(r"(?<=\.)\s", description, maxsplit=1)[0].rstrip(".")


def escape(text: str) -> str:
    return text.replace("\\", "\\\\").replace("-", "\\-")

