"""Helpers shared by the command-line verbs: the argument parser, angle parsing and the
check of figure files (made before any heavy work; output directories are checked with
:func:`casflex._validate.output_directory`)."""

from __future__ import annotations

import argparse
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

from casflex._validate import fail, output_file
from casflex.errors import ModelError

__all__ = ["ArgumentParser", "parse_angle", "plot_path"]

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

