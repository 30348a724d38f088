"""``twinslam COMMAND --help`` documents every option a user can pass."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import pytest

from twinslam.cli.main import COMMANDS, build_parser


def _choices(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    return _choices(build_parser())


def _entries(help_text: str) -> dict[str, str]:
    """Each option's entry of a rendered help text, by each of its option strings, with its
    lines joined (the text as a user reads it)."""
    entries: dict[str, str] = {}
    current: list[str] = []
    for line in help_text.splitlines():
        if re.match(r"^  -", line):               # an entry starts with its option strings
            current = [line]
            names = re.findall(r"(?:^|[ ,])(--?[\w-]+)", line.split("  ", 2)[1])
            for name in names:
                entries[name] = ""
            current_names = names
        elif current and line.startswith("      "):
            current.append(line)
        else:
            current = []
            continue
        for name in current_names:
            entries[name] = " ".join(" ".join(current).split())
    return entries


@pytest.mark.parametrize("name", sorted(_subcommands()))
def test_every_option_of_every_command_says_what_it_does_and_its_default(
        name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Read in the help as printed: every option has a text, and one with a default shows that
    default in its entry — its value, unless the option's own text words it."""
    monkeypatch.setenv("COLUMNS", "100")
    parser = _subcommands()[name]
    entries = _entries(parser.format_help())
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and len(action.help) > 8, f"{name} {action.dest}: no help text"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            entry = entries.get(action.option_strings[-1], "")
            assert entry, f"{name} {action.option_strings[-1]}: not in the help"
            # the value as printed, unless the text words the default itself ("default all");
            # argparse may wrap a long value at a hyphen (a checkout's path): compared without
            # the whitespace the wrap put in
            worded = "default" in action.help
            shown = "".join(str(action.default).split()) in "".join(entry.split())
            assert "default" in entry and (worded or shown), \
                f"{name} {action.option_strings[-1]}: the default {action.default!r} is not " \
                f"shown: {entry!r}"


def test_the_help_check_sees_a_default_that_is_not_shown() -> None:
    """The check above reads what is printed: an option whose help hides its default fails
    it (argparse's plain formatter shows no default)."""
    parser = argparse.ArgumentParser(prog="x", formatter_class=argparse.HelpFormatter)
    parser.add_argument("--slots", type=int, default=200, help="slots a run lasts")
    parser.add_argument("--seeds", type=int, default=5, help="runs (default 5)")
    entries = _entries(parser.format_help())
    assert "200" not in entries["--slots"] and "default 5" in entries["--seeds"]


def test_a_default_wrapped_at_a_hyphen_is_still_read_as_shown(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A checkout in a folder with hyphens (``/tmp/twinslam-clean-x/…``): argparse breaks the
    path at a hyphen, and the entry, its lines joined, holds it with a space in."""
    from twinslam.cli.console import HelpFormatter

    monkeypatch.setenv("COLUMNS", "60")
    parser = argparse.ArgumentParser(prog="x", formatter_class=HelpFormatter)
    path = "/tmp/twinslam-clean-5tlgp818/main/config/twinslam.yaml"
    parser.add_argument("--params", default=path, help="ROS 2 parameter file for the nodes")
    entry = _entries(parser.format_help())["--params"]
    assert path not in entry and "".join(path.split()) in "".join(entry.split())


def test_the_simulators_help_names_the_learned_policy_and_the_reference() -> None:
    text = _subcommands()["sim"].format_help()
    for words in ("mbrl:CHECKPOINT", "reference", "not a bound", "trace:FILE", "Mbit/s",
                  "lost_share"):
        assert words in " ".join(text.split()), words


def test_the_old_name_of_the_variational_twin_is_accepted_with_a_deprecation_line(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``--rate-model udt`` still parses (scripts written before the rename keep working) and
    the command says once what the model is called now."""
    from twinslam.cli.console import warn_aliases
    from twinslam.twin.registry import ALIASES, canonical

    args = _subcommands()["train"].parse_args(["--covis", "x.npz", "--rate-model", "udt"])
    assert canonical(args.rate_model) == "variational"
    warn_aliases([args.rate_model, "regime", "udt"], ALIASES)
    err = capsys.readouterr().err
    assert err.count("'udt' is the old name of 'variational'") == 1


def test_help_texts_read_as_plain_text() -> None:
    """The docstrings a description is made of are reStructuredText; a terminal shows their
    literals as plain words (``twinslam --help`` began with two backticks)."""
    texts = {"twinslam": build_parser().format_help(),
             **{name: p.format_help() for name, p in _subcommands().items()}}
    assert texts["twinslam"].split("\n\n")[1].startswith("twinslam: the command-line entry")
    assert not [name for name, text in texts.items() if "``" in text]
    # a description is not %-formatted as an option's help is: "%%" there shows as written
    assert not [name for name, text in texts.items() if "%%" in text]


def test_a_command_builds_its_parser_from_its_own_module_alone() -> None:
    """``twinslam trace …`` imports the trace command and not the thirteen others (all of
    them cost 2.4 s of CPU before its first line, rclpy among them); ``twinslam --help`` and a
    misspelt command still see every command."""
    assert set(_subcommands()) == set(COMMANDS)
    assert set(_choices(build_parser("sim"))) == {"sim"}
    assert set(_choices(build_parser("simulate"))) == set(COMMANDS)
    code = ("import sys\nfrom twinslam.cli.main import main\n"
            "code = main(['trace', 'info', 'missing.csv'])\n"
            "print(code, *sorted(m for m in sys.modules if m.startswith('twinslam.cli.commands.')"
            " or m in ('rclpy', 'torch')))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert "trace file missing.csv does not exist" in run.stderr
    assert run.stdout.split() == ["2", "twinslam.cli.commands.trace"], run.stdout + run.stderr
