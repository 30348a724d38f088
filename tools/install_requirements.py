"""Install a requirements file into a virtual environment with uv, configured as pip is.

Why not pip: pip's resolver spends its time deciding which of every file of every release of
every project (131 000 links for ours: torch, numpy and ray publish thousands of wheels) fits
this interpreter, in Python on one core (its resolution alone took 74 s on the development
VM), before anything else of the set-up can start. uv installs the same pins from an empty
cache in 17–37 s where pip took 122–139 s (`python -m bench.installer`).

uv does not read pip's configuration, and the package sources of a machine live there (a
mirror, a folder of wheels such as the CPU build of torch, constraints): this script reads
``pip config list`` — pip's files and its ``PIP_*`` variables, in pip's precedence — and hands
uv the same sources, with uv told to pick the best version over all of them as pip does.
Where uv cannot be installed (no index reachable that has it) or ``--installer pip`` is asked
for, pip installs instead; a requirement uv cannot resolve fails as pip's would.

Usage: ``python tools/install_requirements.py VENV_PYTHON REQUIREMENTS [--installer uv|pip]``
(run by ``make``; VENV_PYTHON is the environment's interpreter, which has pip).
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

#: the uv release installed into the environment to install the rest
UV_REQUIREMENT = "uv==0.13.9"

#: pip's option (as its configuration names it) → uv's, for options that take values; pip
#: reads a list option's value from a file as whitespace-separated items
LIST_OPTIONS = {"find-links": "--find-links", "extra-index-url": "--extra-index-url",
                "constraint": "--constraint", "trusted-host": "--allow-insecure-host"}
VALUE_OPTIONS = {"index-url": "--index-url"}
FLAG_OPTIONS = {"no-index": "--no-index", "pre": "--prerelease=allow"}
#: pip's options that uv takes from the environment instead
ENVIRONMENT_OPTIONS = {"cert": "SSL_CERT_FILE", "client-cert": "SSL_CLIENT_CERT",
                       "timeout": "UV_HTTP_TIMEOUT", "default-timeout": "UV_HTTP_TIMEOUT",
                       "proxy": "HTTPS_PROXY"}
#: the sections ``pip install`` reads, lowest precedence first (``:env:`` is PIP_* variables)
SECTIONS = ("global", "install", ":env:")
TRUE = {"1", "true", "yes", "on"}


def pip_configuration(python: str) -> dict[str, str]:
    """``pip install``'s effective configuration, as ``python -m pip config list`` says."""
    return parse_config_list(subprocess.run([python, "-m", "pip", "config", "list"],
                                            capture_output=True, text=True, check=True).stdout)


def parse_config_list(listed: str) -> dict[str, str]:
    """Option name → value from ``pip config list``'s lines (``section.option='value'``): the
    ``install`` section over ``global`` and the environment over both (pip's order); the
    sections ``pip install`` does not read are left out."""
    found: dict[tuple[str, str], str] = {}
    for line in listed.splitlines():
        name, sep, value = line.partition("=")
        section, dot, option = name.rpartition(".")
        if not sep or not dot or section not in SECTIONS:
            continue
        try:
            found[(section, option)] = str(ast.literal_eval(value))
        except (ValueError, SyntaxError):    # pip prints repr(); anything else, as written
            found[(section, option)] = value.strip("'\"")
    merged: dict[str, str] = {}
    for section in SECTIONS:
        merged.update({option: value for (where, option), value in found.items()
                       if where == section})
    return merged


def uv_arguments(config: dict[str, str]) -> tuple[list[str], dict[str, str]]:
    """uv's command-line options and environment for pip's ``config``. Options uv has no
    counterpart for are left out (pip's behaviour they set — verbosity, caching — does not
    change which files are installed)."""
    args = ["--index-strategy", "unsafe-best-match"]   # pip's: the best version of any index
    env: dict[str, str] = {}
    for option, value in config.items():
        if option in LIST_OPTIONS:
            for item in value.split():
                args += [LIST_OPTIONS[option], item]
        elif option in VALUE_OPTIONS:
            args += [VALUE_OPTIONS[option], value]
        elif option in FLAG_OPTIONS and value.lower() in TRUE:
            args.append(FLAG_OPTIONS[option])
        elif option in ENVIRONMENT_OPTIONS:
            env[ENVIRONMENT_OPTIONS[option]] = value
            if option == "proxy":
                env["HTTP_PROXY"] = value
    return args, env


def install_with_pip(python: str, requirements: str) -> int:
    """pip itself (bytecode left to the set-up's step that writes only what is imported)."""
    return subprocess.call([python, "-m", "pip", "install", "--quiet",
                            "--disable-pip-version-check", "--no-compile", "-r", requirements])


def uv_executable(python: str) -> Path | None:
    """uv installed into the environment by pip (one small wheel), or None where it cannot be."""
    uv = Path(python).parent / "uv"
    if uv.exists():
        return uv
    got = subprocess.run([python, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                          "--no-compile", UV_REQUIREMENT], capture_output=True, text=True)
    if got.returncode != 0 or not uv.exists():
        tail = got.stderr.strip().splitlines()[-1:] or ["uv missing after its install"]
        print(f"install_requirements: cannot install {UV_REQUIREMENT} ({tail[0]}); "
              "installing with pip", file=sys.stderr)
        return None
    return uv


def install_with_uv(python: str, requirements: str, uv: Path) -> int:
    args, env = uv_arguments(pip_configuration(python))
    command = [str(uv), "pip", "install", "--quiet", "--python", python, *args,
               "-r", requirements]
    shown = [re.sub(r"(?<=//)[^/@\s]+@", "***@", arg) for arg in command[1:3] + args]
    print("installing", requirements, "with uv", shlex.join(shown), flush=True)
    return subprocess.call(command, env={**os.environ, **env})


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("python", help="the virtual environment's interpreter")
    parser.add_argument("requirements", help="the requirements file to install")
    parser.add_argument("--installer", choices=("uv", "pip"), default="uv",
                        help="uv (pip's configuration handed over; pip where uv cannot be "
                             "installed) or pip itself (default: %(default)s)")
    options = parser.parse_args(argv)
    if options.installer == "uv":
        uv = uv_executable(options.python)
        if uv is not None:
            return install_with_uv(options.python, options.requirements, uv)
    return install_with_pip(options.python, options.requirements)


if __name__ == "__main__":
    sys.exit(main())
