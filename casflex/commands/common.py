"""Helpers shared by the command-line verbs: the argument parser, the arguments every verb
spells alike, angle parsing, deprecated spellings and the check of figure files (made
before any heavy work; output directories are checked with
:func:`casflex._validate.output_directory`).

The conventions (enforced by ``tests/cli/test_cli_conventions.py``):

* a robot file is the positional ``ROBOT.toml`` (:func:`add_robot_argument`); other
  files are ``STUDY.toml``, ``PROBLEM.toml``, ``LOG.csv``;
* joints are 1-based (``--joint 3``, ``--joints 2 3``); the Python API is 0-based;
* ``--modes N`` is the number of modes; ``--step S`` a grid step in rad, or with a
  ``deg`` suffix (:func:`add_model_arguments`);
* ``--gravity/--no-gravity`` (:func:`add_gravity_argument`): gravity is left out unless
  ``--gravity`` is given;
* every verb that builds modal tables takes ``--cache-dir DIR`` and ``--no-cache``
  (:func:`add_cache_arguments`, :func:`cache_dir_of`);
* verbs that plot frequencies take ``--unit {rad/s,Hz}`` (default rad/s,
  :func:`add_unit_argument`); ``--plot FILE.png`` writes a figure;
* help lines are lower-case, without a trailing period, defaults as ``(default X)``;
  a verb's help starts with an imperative verb;
* an old spelling keeps working for one release and prints one line on stderr
  (:func:`add_deprecated_alias`, :func:`deprecation_note`).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from casflex._validate import fail, output_file
from casflex.errors import ModelError

__all__ = [
    "ArgumentParser",
    "parse_angle",
    "plot_path",
    "add_robot_argument",
    "add_modes_argument",
    "add_model_arguments",
    "add_cache_arguments",
    "cache_dir_of",
    "disk_cache",
    "add_gravity_argument",
    "add_unit_argument",
    "add_plot_argument",
    "add_processes_argument",
    "add_deprecated_alias",
    "deprecation_note",
    "FREQUENCY_UNITS",
]

#: the frequency units a figure may be drawn in (``--unit``)
FREQUENCY_UNITS = ("rad/s", "Hz")

#: a command-line token that is a negative value, not an option: "-1.5", "-1e-3",
#: "-45deg", "-0.5rad", "-pi", "-0.5pi", "-0.5*pi"
NEGATIVE_VALUE = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(deg|rad)?$"
                            r"|^-(\d*\.?\d*\*?)pi$")


class ArgumentParser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` that reads negative values with units as values.

    argparse takes a token that starts with ``-`` for an option unless it looks like a
    plain negative number, so ``--from -180deg`` or ``--q 0 0 -pi`` would fail. Tokens
    matching :data:`NEGATIVE_VALUE` are passed on with a leading space, which argparse
    treats as a value and every casflex converter strips (no casflex option looks like a
    negative number). Sub-parsers made by ``add_subparsers`` are of this class too.

    Parameters
    ----------
    *args, **kwargs
        As for :class:`argparse.ArgumentParser`.

    Examples
    --------
    >>> p = ArgumentParser()
    >>> _ = p.add_argument("--q", nargs=2)
    >>> [parse_angle(v, "--q") for v in p.parse_args(["--q", "-180deg", "-0"]).q]
    [-3.141592653589793, -0.0]
    """

    def parse_known_args(self, args: Sequence[str] | None = None,
                         namespace: argparse.Namespace | None = None,
                         ) -> tuple[argparse.Namespace, list[str]]:
        """:meth:`argparse.ArgumentParser.parse_known_args` with negative values protected.

        Parameters
        ----------
        args : sequence of str, optional
            Tokens (default ``sys.argv[1:]``).
        namespace : argparse.Namespace, optional
            Object to fill.

        Examples
        --------
        >>> p = ArgumentParser()
        >>> _ = p.add_argument("--to")
        >>> p.parse_known_args(["--to", "-pi"])[0].to.strip()
        '-pi'
        """
        if args is None:
            import sys

            args = sys.argv[1:]
        args = [" " + a if isinstance(a, str) and NEGATIVE_VALUE.match(a) else a
                for a in args]
        return super().parse_known_args(args, namespace)


def parse_angle(text: str, option: str) -> float:
    """Parse ``"0.5"`` (rad), ``"30deg"``, ``"0.5rad"``, ``"pi"`` or ``"-0.5*pi"`` into
    radians.

    Parameters
    ----------
    text : str
        The command-line token.
    option : str
        The option name, for the error message.

    Examples
    --------
    >>> round(parse_angle("180deg", "--q"), 6), round(parse_angle("-0.5pi", "--to"), 6)
    (3.141593, -1.570796)
    """
    raw = str(text).strip()
    factor = 1.0
    for suffix, f in (("deg", math.pi / 180.0), ("rad", 1.0), ("pi", math.pi)):
        if raw.lower().endswith(suffix):
            raw, factor = raw[: -len(suffix)], f
            break
    if factor == math.pi:  # "pi", "-pi", "0.5pi", "0.5*pi"
        raw = raw.rstrip("*")
        raw = raw + "1" if raw in ("", "-", "+") else raw
    try:
        value = float(raw) * factor
    except ValueError:
        raise ModelError(f"{option}: {text!r} is not an angle (a number in rad, or with a "
                         "'deg' suffix)") from None
    if not math.isfinite(value):
        raise ModelError(f"{option}: {text!r} must be finite")
    return value


def plot_path(value: str | os.PathLike | None, option: str = "--plot") -> Path | None:
    """Check a figure file option before any heavy work: its directory exists and is
    writable and matplotlib can write its format (``None`` when the option is not given).

    Parameters
    ----------
    value : str or os.PathLike or None
        The option's value.
    option : str
        The option name, for the error message.

    Examples
    --------
    >>> plot_path(None) is None, plot_path("modes.png").name
    (True, 'modes.png')
    >>> plot_path("no_such_dir/modes.png")
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --plot = 'no_such_dir/modes.png': the directory 'no_such_dir' \
does not exist; create it first
    >>> plot_path("modes.doc")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --plot = 'modes.doc': unknown figure format 'doc'; use one of ...
    """
    if value is None:
        return None
    path = output_file(value, option)
    fmt = path.suffix.lower().lstrip(".")
    if fmt:
        from matplotlib.figure import Figure

        formats = sorted(Figure().canvas.get_supported_filetypes())
        if fmt not in formats:
            raise fail(option, str(value), f"unknown figure format {fmt!r}; use one of "
                                           + ", ".join(formats))
    return path



def deprecation_note(old: str, new: str) -> None:
    """Write the one-line note of a deprecated spelling on stderr.

    Parameters
    ----------
    old : str
        The old spelling (``"--count"``).
    new : str
        What to write instead (``"--modes"``).

    Examples
    --------
    >>> import contextlib, io
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     deprecation_note("--count", "--modes")
    >>> err.getvalue()
    'casflex: deprecated: --count; use --modes (the old spelling goes in the next release)\\n'
    """
    print(f"casflex: deprecated: {old}; use {new} (the old spelling goes in the next "
          "release)", file=sys.stderr, flush=True)


class _DeprecatedAlias(argparse.Action):
    """Store like the new option, after a deprecation note on stderr."""

    def __init__(self, option_strings, dest, new="", **kwargs):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        deprecation_note(option_string, self.new)
        setattr(namespace, self.dest, values)


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str, dest: str,
                         **kwargs) -> None:
    """Accept the old spelling ``old`` of option ``new`` (same ``dest``), hidden from the
    help; using it prints :func:`deprecation_note`.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    old, new : str
        Old and new option strings.
    dest : str
        The new option's attribute.
    **kwargs
        As for :meth:`~argparse.ArgumentParser.add_argument` (``type``, ``nargs``...).

    Examples
    --------
    >>> import contextlib, io
    >>> p = ArgumentParser()
    >>> _ = p.add_argument("--modes", type=int, default=5)
    >>> add_deprecated_alias(p, "--count", "--modes", "modes", type=int)
    >>> with contextlib.redirect_stderr(io.StringIO()):
    ...     p.parse_args(["--count", "2"]).modes
    2
    """
    parser.add_argument(old, dest=dest, action=_DeprecatedAlias, new=new,
                        default=argparse.SUPPRESS, help=argparse.SUPPRESS, **kwargs)


def add_robot_argument(parser: argparse.ArgumentParser,
                       help: str = "robot description (TOML)") -> None:
    """The positional robot file, ``ROBOT.toml`` (attribute ``robot``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    help : str
        Help line.

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_robot_argument(p)
    >>> p.parse_args(["r.toml"]).robot
    'r.toml'
    """
    parser.add_argument("robot", metavar="ROBOT.toml", help=help)


def add_modes_argument(parser: argparse.ArgumentParser,
                       default: int | None, help: str | None = None) -> None:
    """``--modes N``: the number of modes.

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
    default : int or None
    help : str, optional
        Help line (default ``"number of modes (default N)"``).

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_modes_argument(p, 3)
    >>> p.parse_args([]).modes
    3
    """
    parser.add_argument("--modes", type=int, default=default, metavar="N",
                        help=help or f"number of modes (default {default})")


def add_model_arguments(parser: argparse.ArgumentParser, *,
                        modes: int = 3, step: str | None = None,
                        step_help: str | None = None) -> None:
    """``--modes N`` and ``--step S`` (grid step of the modal tables, an angle).

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
    modes : int
        Default number of modes.
    step : str, optional
        Default step as written on the command line (``"6deg"``); ``None`` for the
        library's default.
    step_help : str, optional
        Help line of ``--step``.

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_model_arguments(p, modes=3, step="6deg")
    >>> a = p.parse_args(["--step", "1.5deg"])
    >>> a.modes, round(parse_angle(a.step, "--step"), 6)
    (3, 0.02618)
    """
    add_modes_argument(parser, modes)
    default = ("default 1.5deg for one shape joint, 6deg for more" if step is None
               else f"default {step}")
    parser.add_argument("--step", default=step, metavar="S",
                        help=step_help or "grid step of the modal tables, rad or with a "
                        f"'deg' suffix ({default})")


def add_cache_arguments(parser: argparse.ArgumentParser) -> None:
    """``--cache-dir DIR`` and ``--no-cache``: where modal tables (and the other cached
    results) are kept; read them back with :func:`cache_dir_of`.

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_cache_arguments(p)
    >>> cache_dir_of(p.parse_args([])), cache_dir_of(p.parse_args(["--no-cache"]))
    (None, False)
    """
    parser.add_argument("--cache-dir", default=None, metavar="DIR",
                        help="cache of the modal tables and other built results (default "
                        "$CASFLEX_CACHE or ~/.cache/casflex)")
    parser.add_argument("--no-cache", action="store_true",
                        help="neither read nor write the cache (build everything afresh)")


def cache_dir_of(args: argparse.Namespace) -> str | bool | None:
    """The ``cache_dir`` argument of the library from ``--cache-dir`` / ``--no-cache``:
    a path, ``None`` (the default cache) or ``False`` (no cache).

    Parameters
    ----------
    args : argparse.Namespace
        With ``cache_dir`` and ``no_cache`` (missing attributes count as not given).

    Raises
    ------
    casflex.errors.ModelError
        Both options given.

    Examples
    --------
    >>> cache_dir_of(argparse.Namespace(cache_dir="c", no_cache=False))
    'c'
    >>> cache_dir_of(argparse.Namespace(cache_dir="c", no_cache=True))
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --no-cache: not with --cache-dir 'c'
    """
    path = getattr(args, "cache_dir", None)
    if getattr(args, "no_cache", False):
        if path is not None:
            raise ModelError(f"--no-cache: not with --cache-dir {path!r}")
        return False
    return path


@contextlib.contextmanager
def disk_cache(cache_dir: str | bool | None) -> Iterator[str | None]:
    """The ``cache_dir`` for work that must keep files on disk (compiled libraries):
    with ``False`` (``--no-cache``) a temporary directory, removed afterwards, so that
    nothing is read from or left in a cache; otherwise ``cache_dir`` itself.

    Parameters
    ----------
    cache_dir : str, bool or None
        From :func:`cache_dir_of`.

    Examples
    --------
    >>> with disk_cache(False) as d:
    ...     exists = os.path.isdir(d)
    >>> exists, os.path.exists(d)
    (True, False)
    >>> with disk_cache("c") as d:
    ...     d
    'c'
    """
    if cache_dir is False:
        with tempfile.TemporaryDirectory(prefix="casflex-no-cache-") as tmp:
            yield tmp
    else:
        yield cache_dir


def add_gravity_argument(parser: argparse.ArgumentParser, default: bool | None = False,
                         help: str | None = None) -> None:
    """``--gravity/--no-gravity``: include the robot's gravity (left out by default, as in
    the dissertation's simulations, §3.3.7.1).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    default : bool or None
        ``False`` (the convention); ``None`` lets a verb tell "not given" apart during a
        deprecation period.
    help : str, optional
        Help line.

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_gravity_argument(p)
    >>> p.parse_args([]).gravity, p.parse_args(["--gravity"]).gravity
    (False, True)
    """
    parser.add_argument("--gravity", action=argparse.BooleanOptionalAction, default=default,
                        help=help or "include the robot's gravity (default --no-gravity: "
                        "left out, §3.3.7.1)")


def add_unit_argument(parser: argparse.ArgumentParser) -> None:
    """``--unit {rad/s,Hz}``: the frequency unit of the figure (default rad/s; the JSON is
    always in rad/s).

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_unit_argument(p)
    >>> p.parse_args([]).unit, p.parse_args(["--unit", "Hz"]).unit
    ('rad/s', 'Hz')
    """
    parser.add_argument("--unit", choices=FREQUENCY_UNITS, default="rad/s",
                        help="frequency unit of the figure (default rad/s; the JSON is "
                        "in rad/s)")


def add_plot_argument(parser: argparse.ArgumentParser, help: str) -> None:
    """``--plot FILE.png``: write a figure (checked with :func:`plot_path` before any
    heavy work).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    help : str
        What the figure shows (lower-case, no trailing period).

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_plot_argument(p, "draw the modes")
    >>> p.parse_args(["--plot", "m.png"]).plot
    'm.png'
    """
    parser.add_argument("--plot", metavar="FILE.png", default=None, help=help)


def add_processes_argument(parser: argparse.ArgumentParser,
                           help: str = "worker processes (default all CPUs; 1 = no pool)",
                           ) -> None:
    """``--processes P``: the size of the local process pool.

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
    help : str
        Help line.

    Examples
    --------
    >>> p = ArgumentParser()
    >>> add_processes_argument(p)
    >>> p.parse_args(["--processes", "2"]).processes
    2
    """
    parser.add_argument("--processes", type=int, default=None, metavar="P", help=help)
