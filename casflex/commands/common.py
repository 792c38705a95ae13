"""Helpers shared by the command-line verbs."""

from __future__ import annotations

import math

from casflex.errors import ModelError

__all__ = ["parse_angle"]


def parse_angle(text, option):
    """Parse ``"0.5"`` (rad), ``"30deg"`` or ``"0.5rad"`` into radians.

    Parameters
    ----------
    text : str
        The command-line token.
    option : str
        The option name, for the error message.

    Examples
    --------
    >>> round(parse_angle("180deg", "--q"), 6)
    3.141593
    """
    raw = str(text).strip()
    factor = 1.0
    for suffix, f in (("deg", math.pi / 180.0), ("rad", 1.0)):
        if raw.endswith(suffix):
            raw, factor = raw[: -len(suffix)], f
            break
    try:
        value = float(raw) * factor
    except ValueError:
        raise ModelError(f"{option}: {text!r} is not an angle (a number in rad, or with a "
                         "'deg' suffix)") from None
    if not math.isfinite(value):
        raise ModelError(f"{option}: {text!r} must be finite")
    return value
