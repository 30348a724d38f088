"""The set-up's installer hands uv the package sources pip is configured with: a machine whose
wheels come from a mirror, a folder or behind constraints gets the same files from either."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[1]


def _installer() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "install_requirements", REPO / "tools" / "install_requirements.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["install_requirements"] = module
    spec.loader.exec_module(module)
    return module


#: `pip config list` on a machine with a folder of wheels, two mirrors and constraints, some
#: set in files and some by PIP_* variables
LISTED = """\
:env:.cert='/etc/ssl/certs/ca-certificates.crt'
:env:.find-links='/opt/wheels'
:env:.disable-pip-version-check='1'
global.find-links='/srv/old-wheels'
global.constraint='/etc/xdg/pip/constraints.txt'
global.extra-index-url='file:///opt/pypi/simple file:///opt/pypi-more/simple'
global.index-url='https://pypi.example/simple'
install.index-url='https://mirror.example/simple'
install.no-index='false'
install.pre='yes'
freeze.find-links='/not/for/install'
"""


def test_pip_config_is_read_in_pips_precedence() -> None:
    """The environment over the ``install`` section over ``global``; other commands' sections
    are not what ``pip install`` reads."""
    config = _installer().parse_config_list(LISTED)
    assert config["find-links"] == "/opt/wheels"
    assert config["index-url"] == "https://mirror.example/simple"
    assert config["extra-index-url"] == "file:///opt/pypi/simple file:///opt/pypi-more/simple"
    assert config["cert"] == "/etc/ssl/certs/ca-certificates.crt"
    assert "/not/for/install" not in config.values()


def test_uv_gets_every_source_pip_has_and_picks_the_best_version_over_all() -> None:
    """Each list item its own option, flags only where pip's are on, the certificate through
    the environment, and the index strategy that makes uv choose as pip does (the CPU torch
    wheel from the folder of wheels beside an index's)."""
    module = _installer()
    args, env = module.uv_arguments(module.parse_config_list(LISTED))
    pairs = set(itertools.pairwise(args))    # each option beside its value
    assert args[:2] == ["--index-strategy", "unsafe-best-match"]
    assert ("--find-links", "/opt/wheels") in pairs
    assert ("--extra-index-url", "file:///opt/pypi/simple") in pairs
    assert ("--extra-index-url", "file:///opt/pypi-more/simple") in pairs
    assert ("--constraint", "/etc/xdg/pip/constraints.txt") in pairs
    assert ("--index-url", "https://mirror.example/simple") in pairs
    assert "--prerelease=allow" in args and "--no-index" not in args
    assert env == {"SSL_CERT_FILE": "/etc/ssl/certs/ca-certificates.crt"}


def test_credentials_in_an_index_url_are_not_printed(capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The command line it prints (a CI log) hides the user and token of a private index; uv
    itself gets them."""
    module = _installer()
    run: list[list[str]] = []
    monkeypatch.setattr(module, "pip_configuration", lambda python: {
        "index-url": "https://ci:s3cret@mirror.example/simple"})
    monkeypatch.setattr(module.subprocess, "call", lambda command, env: run.append(command) or 0)
    assert module.install_with_uv("/venv/bin/python", "requirements.txt", Path("/venv/bin/uv")) == 0
    printed = capsys.readouterr().out
    assert "s3cret" not in printed and "https://***@mirror.example/simple" in printed
    assert "https://ci:s3cret@mirror.example/simple" in run[0]
