"""``twinslam COMMAND --help`` documents every option a user can pass (issue #18 item 6)."""

from __future__ import annotations

import argparse

import pytest

from twinslam.cli.main import build_parser


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


@pytest.mark.parametrize("name", sorted(_subcommands()))
def test_every_option_of_every_command_says_what_it_does_and_its_default(name: str) -> None:
    parser = _subcommands()[name]
    text = parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and len(action.help) > 8, f"{name} {action.dest}: no help text"
        if action.option_strings and action.default not in (None, False):
            assert "default" in parser._get_formatter()._get_help_string(action), \
                f"{name} {action.option_strings[0]}: the default is not shown"
    assert "options:" in text


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
