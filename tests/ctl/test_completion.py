"""Shell completion and man pages, as a user installs them: the script a program prints
with --print-completion, sourced into a real bash (or zsh), completing a typed line;
the page --print-man prints, rendered by man.

bash is driven as its programmable completion drives it: COMP_WORDS, COMP_CWORD,
COMP_LINE and COMP_POINT set, and the function the script registered with
``complete -F`` called with the command, the word and the word before it (bash(1),
"Programmable Completion"). zsh completes only inside its line editor, so it runs in a
pseudo-terminal (zsh/zpty) with compadd wrapped to print what it offers.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from gateway.common.completion import NODES_OPTION, escape
from gateway.common.values import POLLABLE_RECORD, STREAMABLE_RECORD
from gateway.ctl.cli import build_parser
from gateway.daemon.config import load_config
from tests.helpers.processes import script, spawn_run

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "config" / "nodes.yaml"

# The function a completion script registers for its program, then its COMPREPLY, one
# word a line. $1: the script; $2: the line; the rest: COMP_WORDS.
BASH_DRIVER = r"""
source "$1" || exit 3
COMP_LINE=$2; COMP_POINT=${#COMP_LINE}; shift 2
COMP_WORDS=("$@"); COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 ))
spec=$(complete -p "${COMP_WORDS[0]}") || exit 4
function=${spec##* -F }; function=${function%% *}
"$function" "${COMP_WORDS[0]}" "${COMP_WORDS[COMP_CWORD]}" "${COMP_WORDS[COMP_CWORD-1]}"
printf '%s\n' "${COMPREPLY[@]}"
"""

# $1: a directory holding the _program script; $2: the line, completed with a tab.
# Each offered word is printed after a marker the echoed input cannot hold (the typed
# text shows $((1+1)), the output 2); the completion's end closes the inner shell.
ZSH_DRIVER = r"""
zmodload zsh/zpty
zpty z zsh -f -i
zpty -w z "PROMPT= ; fpath=($1 \$fpath); autoload -U compinit; compinit -u -D"
zpty -w z 'compadd() { local -a hits; builtin compadd -A hits "$@";
  (( $#hits )) && print -rl -- "[$((1+1))]"${^hits}; builtin compadd "$@"; }'
zpty -w z 'comppostfuncs=(done_); done_() { print -r -- "[$((2*3))]"; exit }'
zpty -w z "$2"$'\t'
local chunk all
while zpty -r z chunk; do all+=$chunk; [[ $all == *'[6]'* ]] && break; done
print -r -- $all
"""


@pytest.fixture(scope="module")
def scripts(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every program's bash script (as ``<name>.bash``) and zsh script (``_<name>``),
    as the program printed it."""
    folder = tmp_path_factory.mktemp("completion")
    for name in ("gx2ctl", "gx2-gateway", "gx2-sim"):
        for shell, file in (("bash", f"{name}.bash"), ("zsh", f"_{name}")):
            run = spawn_run([script(name), "--print-completion", shell], capture_output=True,
                            text=True, timeout=60, check=True)
            assert run.stderr == "", run.stderr
            (folder / file).write_text(run.stdout)
    return folder


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory with the example nodes.yaml, and the programs on PATH as a
    user has them (the completion runs the program it completes)."""
    shutil.copy(EXAMPLE, tmp_path / "nodes.yaml")
    (tmp_path / "broken.yaml").write_text("nodes: [{address: 76}\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PATH", f"{Path(script('gx2ctl')).parent}{os.pathsep}"
                       f"{os.environ['PATH']}")
    return tmp_path


def words_of(line: str) -> list[str]:
    """COMP_WORDS for a line: split at blanks and at '=' (in COMP_WORDBREAKS), with an
    empty word last when the line ends in a blank."""
    return re.findall(r"[^ =]+|=", line) + ([""] if line.endswith(" ") else [])


def bash_complete(scripts: Path, line: str) -> list[str]:
    words = words_of(line)
    run = subprocess.run(["bash", "-c", BASH_DRIVER, "bash", str(scripts / f"{words[0]}.bash"),
                          line, *words], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0 and run.stderr == "", run
    return [word for word in run.stdout.splitlines() if word]


def zsh_complete(scripts: Path, line: str) -> list[str]:
    run = subprocess.run(["zsh", "-f", "-c", ZSH_DRIVER, "zsh", str(scripts), line],
                         capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run
    return list(dict.fromkeys(re.findall(r"\[2\]([^\s\x1b]+)", run.stdout)))


def configured() -> list[str]:
    """The example's node addresses, as the gateway itself reads them."""
    return [str(node.address) for node in load_config(EXAMPLE).nodes]


# --- bash ------------------------------------------------------------------------------

@pytest.mark.parametrize(("line", "offered"), [
    ("gx2ctl sta", ["start", "status"]),
    ("gx2ctl st", ["start", "status", "stop", "store"]),
    ("gx2ctl eeprom ", ["read", "write"]),
    ("gx2ctl bias c", ["capture"]),
    ("gx2ctl --print-completion ", ["bash", "zsh"]),
    ("gx2ctl export --format ", ["csv", "mat", "parquet", "ros2"]),
    ("gx2ctl export --frame ", ["enu", "ned"]),
    ("gx2ctl poll 76 firm", ["firmware_version"]),
    ("gx2ctl store 76 ", ["accel", "gyro"]),
    ("gx2-gateway --log-level ", ["DEBUG", "ERROR", "INFO", "WARNING"]),
])
def test_bash_completes_commands_and_choices(scripts: Path, here: Path, line: str,
                                             offered: list[str]) -> None:
    assert sorted(bash_complete(scripts, line)) == offered


@pytest.mark.parametrize(("line", "included"), [
    ("gx2ctl --", ["--config", "--control", "--timeout", "--json", "--print-completion",
                   "--print-man", "--version"]),
    ("gx2ctl status --", ["--check"]),
    ("gx2ctl bias capture --", ["--ms"]),
    ("gx2ctl record --", ["--seconds"]),
    ("gx2-gateway --", ["--config", "--check", "--log-level", "--print-man"]),
    ("gx2-sim --", ["--nodes", "--config", "--data-loss", "--print-completion"]),
])
def test_bash_completes_options(scripts: Path, here: Path, line: str,
                                included: list[str]) -> None:
    offered = bash_complete(scripts, line)
    assert set(included) <= set(offered), offered
    assert NODES_OPTION not in offered  # the completion's own helper stays hidden


def test_bash_completes_the_records_a_command_takes(scripts: Path, here: Path) -> None:
    assert bash_complete(scripts, "gx2ctl start 76 ") == list(STREAMABLE_RECORD.choices)
    assert bash_complete(scripts, "gx2ctl poll 76 ") == list(POLLABLE_RECORD.choices)
    assert bash_complete(scripts, "gx2ctl start 76 eu") == ["euler", "euler_angrate"]


@pytest.mark.parametrize("line", [
    "gx2ctl --config nodes.yaml ping ",
    "gx2ctl --config nodes.yaml ping 76 ",
    "gx2ctl --timeout 2 --config=nodes.yaml stop ",
    "gx2ctl --config nodes.yaml tail ",
    "gx2ctl --config nodes.yaml eeprom read ",
])
def test_bash_completes_node_addresses_from_the_config(scripts: Path, here: Path,
                                                       line: str) -> None:
    assert bash_complete(scripts, line) == configured() == ["76", "77", "95"]


def test_bash_completes_node_addresses_by_their_start(scripts: Path, here: Path) -> None:
    assert bash_complete(scripts, "gx2ctl --config nodes.yaml start 7") == ["76", "77"]


@pytest.mark.parametrize("line", [
    "gx2ctl ping ",                             # no --config: nothing to offer
    "gx2ctl --config broken.yaml ping ",        # and never an error on the line
    "gx2ctl --config missing.yaml ping ",
])
def test_bash_offers_no_node_without_a_readable_config(scripts: Path, here: Path,
                                                       line: str) -> None:
    assert bash_complete(scripts, line) == []


def test_bash_completes_files_where_a_file_is_asked_for(scripts: Path, here: Path) -> None:
    assert bash_complete(scripts, "gx2-gateway --config no") == ["nodes.yaml"]
    assert bash_complete(scripts, "gx2ctl --config bro") == ["broken.yaml"]


# --- the helper the node completion calls ----------------------------------------------

@pytest.mark.parametrize("text", [
    "nodes: [{address: 76}\n",                       # not YAML
    "- 76\n",                                        # not a mapping
    "nodes: 76\n",                                   # not a list
    "nodes: [{address: 2001-02-30}]\n",              # PyYAML: ValueError, not YAMLError
    "nodes: " + "[" * 5000 + "]" * 5000 + "\n",      # PyYAML: RecursionError
    "nodes: [{address: true}, {address: 0}, {address: '76'}, 77]\n",  # no valid address
], ids=["yaml", "mapping", "list", "date", "deep", "addresses"])
def test_complete_nodes_prints_nothing_for_a_bad_file(tmp_path: Path, text: str) -> None:
    (tmp_path / "bad.yaml").write_text(text)
    run = spawn_run([script("gx2ctl"), NODES_OPTION, str(tmp_path / "bad.yaml")],
                    capture_output=True, text=True, timeout=60)
    assert (run.returncode, run.stdout, run.stderr) == (0, "", "")


def test_complete_nodes_lists_every_stations_nodes(tmp_path: Path) -> None:
    (tmp_path / "stations.yaml").write_text(
        "base_stations:\n  - {port: sim://, nodes: [{address: 76}, {address: 77}]}\n"
        "  - {port: sim://, nodes: [{address: 95}]}\n  - garbage\n")
    run = spawn_run([script("gx2ctl"), NODES_OPTION, str(tmp_path / "stations.yaml")],
                    capture_output=True, text=True, timeout=60)
    assert (run.returncode, run.stdout.split(), run.stderr) == (0, ["76", "77", "95"], "")


@pytest.mark.parametrize("path", ["missing.yaml", "."])
def test_complete_nodes_prints_nothing_for_no_file(tmp_path: Path, path: str) -> None:
    run = spawn_run([script("gx2ctl"), NODES_OPTION, path], capture_output=True,
                    text=True, timeout=60, cwd=tmp_path)
    assert (run.returncode, run.stdout, run.stderr) == (0, "", "")


# --- zsh -------------------------------------------------------------------------------

needs_zsh = pytest.mark.skipif(shutil.which("zsh") is None, reason="zsh is not installed")


@needs_zsh
@pytest.mark.parametrize(("line", "offered"), [
    ("gx2ctl sta", ["start", "status"]),
    ("gx2ctl start 76 eu", ["euler", "euler_angrate"]),
    ("gx2ctl --config nodes.yaml ping ", ["76", "77", "95"]),
    ("gx2-gateway --log-level ", ["DEBUG", "ERROR", "INFO", "WARNING"]),
])
def test_zsh_completes(scripts: Path, here: Path, line: str, offered: list[str]) -> None:
    assert sorted(zsh_complete(scripts, line)) == offered


@needs_zsh
@pytest.mark.parametrize("command", ["status", "stop"])
def test_zsh_offers_every_option_the_command_takes(scripts: Path, here: Path,
                                                   command: str) -> None:
    # read from the parser, so an option added to a command (or the gateway's options,
    # which every command takes after it too) cannot leave this test behind
    commands = next(a for a in build_parser()._actions
                    if isinstance(a, argparse._SubParsersAction))
    takes = sorted(o for a in commands.choices[command]._actions
                   for o in a.option_strings if o.startswith("--"))
    assert {"--config", "--json", "--timeout"} <= set(takes)
    line = f"gx2ctl {command} {'76 ' if command == 'stop' else ''}--"
    assert sorted(zsh_complete(scripts, line)) == takes


# --- man pages -------------------------------------------------------------------------

def man_page(name: str) -> str:
    run = spawn_run([script(name), "--print-man"], capture_output=True, text=True,
                    timeout=60, check=True)
    assert run.stderr == ""
    return run.stdout


def commands_and_options(parser: argparse.ArgumentParser,
                         path: str) -> tuple[list[str], list[str]]:
    """Every subcommand (``gx2ctl eeprom read``) and every option string below
    ``parser``, but the help that each has (a man page does not list it)."""
    commands, options = [], []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for word, sub in action.choices.items():
                commands.append(f"{path} {word}")
                more = commands_and_options(sub, f"{path} {word}")
                commands += more[0]
                options += more[1]
        elif action.help != argparse.SUPPRESS:
            options += [o for o in action.option_strings if o not in ("-h", "--help")]
    return commands, options


def test_the_man_page_names_every_command_and_option() -> None:
    page = man_page("gx2ctl")
    commands, options = commands_and_options(build_parser(), "gx2ctl")
    assert len(commands) > 20 and len(options) > 10
    for command in commands:
        assert f".SS \\fB{command}\\fR" in page, command
    for option in options:
        assert f"\\fB{escape(option)}\\fR" in page, option
    assert escape(NODES_OPTION) not in page
    # the synopsis too: an option's dash is roff's \- (a bare "-" is a hyphen, which
    # some renderers print as U+2010, not what a user types)
    assert "[\\-\\-config FILE] [\\-\\-control ENDPOINT]" in page


def renderer() -> list[str] | None:
    """man, or groff if man is not installed, with every warning on; None if neither."""
    if shutil.which("man"):
        return ["man", "--warnings=w", "-E", "UTF-8", "-l"]
    if shutil.which("groff"):
        return ["groff", "-man", "-ww", "-Tutf8"]
    return None


@pytest.mark.parametrize(("name", "summary"), [
    ("gx2ctl", "Control a running gx2-gateway"),
    ("gx2-gateway", "Gateway for MicroStrain 3DM-GX2"),
    ("gx2-sim", "A virtual 3DM-GX2 wireless base station"),
])
def test_each_man_page_renders_without_warnings(tmp_path: Path, name: str,
                                                summary: str) -> None:
    command = renderer()
    if command is None:
        pytest.skip("neither man nor groff is installed")
    page = tmp_path / f"{name}.1"
    page.write_text(man_page(name))
    run = subprocess.run([*command, str(page)], capture_output=True, text=True, timeout=30,
                         env={**os.environ, "MANWIDTH": "80", "MANPAGER": "cat"})
    assert run.returncode == 0 and run.stderr == "", run.stderr
    text = re.sub(r".\x08", "", run.stdout)  # overstrike bold, where a pager would show it
    flat = " ".join(text.split())
    assert f"{name} - {summary}" in flat
    assert "SEE ALSO" in flat and "--print-completion SHELL" in flat
