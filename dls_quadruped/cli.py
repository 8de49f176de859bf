"""Command-line conventions shared by every entry point (train, play, mpc.run, demo, eval, ...).

A user error (a bad flag, a bad task file, a missing or unfitting checkpoint, an existing run
directory) prints one line ``<prog>: error: <message>`` on stderr and exits with status 2; a
Ctrl-C exits with 130 and one line. Anything else is a bug and keeps its traceback.

    if __name__ == "__main__":
        run_cli(main)
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from collections.abc import Callable
from typing import Any, NoReturn

import yaml

from dls_quadruped.envs.config import ConfigError

USER_ERROR_STATUS = 2


class UserError(Exception):
    """An error the user can fix from the message alone (printed as one line, no traceback)."""


def _shows_default(action: argparse.Action) -> bool:
    """Whether ``--help`` should print the option's default: a value that is not None, False, empty or suppressed,
    for an option that takes a value and whose help does not already say its default."""
    default = action.default
    return (bool(action.option_strings) and action.nargs != 0 and default is not None
            and default is not argparse.SUPPRESS and default is not False and default not in ((), [], "")
            and "default" not in (action.help or "").lower())


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The description as written (the modules' docstrings carry command examples) and every option's default
    after its help (``(default: 10.0)``), unless the help already names it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if _shows_default(action):
            text += (" " if text else "") + "(default: %(default)s)"
        return text


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose usage errors are one line (the usage is in ``--help``) and whose
    ``--help`` shows every option's default (:class:`HelpFormatter`).

    ``prog`` defaults to the module run with ``python -m`` (``dls_quadruped.eval``, not
    ``__main__.py``), the name :func:`run_cli` reports its errors under.
    """

    def __init__(self, *args: Any, **kwargs: Any):
        kwargs.setdefault("prog", _prog())
        if kwargs.get("formatter_class") in (None, argparse.HelpFormatter, argparse.RawDescriptionHelpFormatter):
            kwargs["formatter_class"] = HelpFormatter
        super().__init__(*args, **kwargs)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        if not action.help and _shows_default(action):  # argparse prints no help line for an option without help
            action.help = "(default: %(default)s)"
        return action

    def error(self, message: str) -> NoReturn:
        self.exit(USER_ERROR_STATUS, f"{self.prog}: error: {message} (see --help)\n")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number (refuses nan and inf, which ``float`` accepts)."""
    value = float(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = finite_float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def torch_device(text: str) -> str:
    """argparse type: a torch device this machine has ("cpu", "cuda", "cuda:1", ...).

    Refuses a misspelt device ("cpux": torch's own message, shortened to the allowed kinds we run on)
    and a CUDA device on a build or machine without one, before anything is built
    (:func:`~dls_quadruped.core.device.checked_device`).
    """
    from dls_quadruped.core.device import checked_device

    try:
        checked_device(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


SET_FORM = "KEY=VALUE, KEY a dotted path into the task file and VALUE YAML (e.g. --set env.episode_length_s=10)"
"""The allowed form of ``--set``, quoted by its errors."""


EXPONENT_FLOAT = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+")
"""A float in exponent notation, which YAML 1.1 (PyYAML) reads as a float only with a dot and a signed exponent
(``1.0e-3``) and otherwise as a string (``1e-3``, ``5E4``, ``1.0e3``)."""


def set_pair(text: str) -> tuple[str, Any]:
    """argparse type of ``--set``: ``KEY=VALUE`` -> (dotted key, value parsed as YAML).

    ``agent.algorithm.entropy_coef=0.0`` -> ``("agent.algorithm.entropy_coef", 0.0)``; ``[0.5,1]`` is a list,
    ``null`` deletes the key as it does in a task file; an unquoted number in exponent notation is a float
    (``1e-3``, which PyYAML alone reads as a string; quoted, ``'1e-3'`` stays a string). No ``=``, an empty key or
    key part (``a..b``), an empty value and a value that is not YAML are refused, naming the pair and the allowed
    form.
    """
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} has no '='; expected {SET_FORM}")
    if not key or not all(key.split(".")):
        raise argparse.ArgumentTypeError(f"{text!r}: empty key or key part; expected {SET_FORM}")
    if not value.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: no value after '=' (null deletes a key); expected {SET_FORM}")
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError as err:
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise argparse.ArgumentTypeError(f"{text!r}: the value is not YAML ({problem}); expected {SET_FORM}") from None
    if isinstance(parsed, str) and EXPONENT_FLOAT.fullmatch(value.strip()):
        parsed = float(parsed)
    return key, parsed


def add_set_argument(parser: argparse.ArgumentParser, note: str = "") -> None:
    """Add the repeatable ``--set KEY=VALUE`` (``set_pair``) to ``parser``; read it with :func:`set_overrides`.

    Args:
        note: appended to the help (which task the pairs apply to, what they cannot change).
    """
    parser.add_argument("--set", dest="set", type=set_pair, action="append", default=[], metavar="KEY=VALUE",
                        help="override a value of the task file, repeatable: KEY a dotted path "
                             "(agent.algorithm.entropy_coef, env.episode_length_s), VALUE YAML (0.0, [0.5,1.0], "
                             "null deletes the key); applied after the other flags and checked like the file"
                             + (f"; {note}" if note else ""))


def set_overrides(pairs: list[tuple[str, Any]]) -> dict:
    """The nested overrides dict of ``--set`` pairs (``load_task(..., overrides=...)``), later pairs winning.

    ``[("env.episode_length_s", 10), ("agent.algorithm.entropy_coef", 0.0)]`` ->
    ``{"env": {"episode_length_s": 10}, "agent": {"algorithm": {"entropy_coef": 0.0}}}``.
    """
    out: dict = {}
    for key, value in pairs:
        *parents, leaf = key.split(".")
        node = out
        for part in parents:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        node[leaf] = value
    return out


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception types reported as one line: ours, task-file errors and missing input files."""
    return UserError, ConfigError, FileNotFoundError


def _prog() -> str:
    """The running command: the module of ``python -m`` (without ``.__main__``) or the script's name."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    if spec is None:
        return os.path.basename(sys.argv[0])
    return spec.name.removesuffix(".__main__")


def run_cli(main: Callable[..., Any], *args: Any) -> None:
    """Call ``main(*args)``; report user errors and Ctrl-C as one line and exit non-zero."""
    try:
        main(*args)
    except KeyboardInterrupt:
        print(f"{_prog()}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except user_errors() as err:
        message = str(err).strip().splitlines()
        print(f"{_prog()}: error: {' '.join(message) if message else type(err).__name__}", file=sys.stderr)
        raise SystemExit(USER_ERROR_STATUS) from None
