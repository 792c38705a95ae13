"""Writing a calibrated robot file: the original text with the fitted values put in.

The robot file's text is edited line by line so that its comments, order and layout
stay: a key that is present gets the new value and a trailing comment saying where it came
from; a missing key is added to its table (the table is added at the end of its
``[[link]]`` block when the file has none). The edited text is read back with
:func:`casflex.robot.loads` and every fitted value checked, so a layout the editor cannot
handle (an inline table, a value spread over several lines) is an error, never a silently
wrong file.
"""

from __future__ import annotations

import re

from casflex._problemfile import parse_toml
from casflex.errors import ModelError
from casflex.identification.parameters import (
    ParameterPath,
    parameter_value,
    parse_parameter_path,
)
from casflex.robot import loads

__all__ = ["calibrated_text"]

_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.\s]+?)\s*\]\]?\s*(#.*)?$")


def _blocks(lines):
    """Per ``[[link]]`` block: {table or None: (first line, end line)}; end exclusive."""
    blocks, current, table, start = [], None, None, None

    def close(end):
        if current is not None:
            current[table] = (start, end)

    for i, line in enumerate(lines):
        m = _HEADER.match(line)
        if not m:
            continue
        name = m.group(1).replace(" ", "")
        close(i)
        if line.strip().startswith("[[") and name == "link":
            current = {}
            blocks.append(current)
            table, start = None, i
        elif name.startswith("link.") and current is not None:
            table, start = name[5:], i
        else:  # another table ([[sensor]] ...): no link block is open
            current = None
    close(len(lines))
    return blocks


def _format(value):
    return repr(float(value))  # shortest round-trip form, valid TOML (6.21e+10, 0.25)


def calibrated_text(text: str, paths: list[ParameterPath], values: list[float],
                    comment: str) -> str:
    """The robot file ``text`` with the parameters set to ``values``.

    Parameters
    ----------
    text : str
        The robot file's TOML text.
    paths : list of ParameterPath
        Parameters (from :func:`casflex.identification.parse_parameter_path`).
    values : list of float
        Their fitted values, in the units of the paths' keys.
    comment : str
        Trailing comment put on every changed line (where the values came from).

    Returns
    -------
    str
        The new TOML text; it reads back with :func:`casflex.robot.loads` and gives the
        fitted values.

    Raises
    ------
    ModelError
        A layout the editor cannot change safely (the message names the parameter).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.identification.parameters import parse_parameter_path
    >>> text = open("problems/arm2link.toml").read()
    >>> robot = load("problems/arm2link.toml")
    >>> p = parse_parameter_path("link2.tip.mass", robot)
    >>> new = calibrated_text(text, [p], [0.25], "fitted")
    >>> loads(new).links[3].tip.mass
    0.25
    >>> new.splitlines()[-2:]
    ['[link.tip]', 'mass = 0.25  # fitted']
    """
    lines = text.splitlines()
    for path, value in zip(paths, values, strict=True):
        blocks = _blocks(lines)
        if path.row >= len(blocks):
            raise ModelError(f"{path.text}: the robot text has no [[link]] table number "
                             f"{path.row + 1}")
        block = blocks[path.row]
        new_line = f"{path.key} = {_format(value)}  # {comment}"
        key_re = re.compile(rf"^\s*{re.escape(path.key)}\s*=")
        where = block.get(path.table)
        if where is None:
            if path.table is None:
                raise ModelError(f"{path.text}: cannot find the link's table")
            main = block[None]
            for line in lines[main[0]:main[1]]:
                if re.match(rf"^\s*{re.escape(path.table)}\s*=", line):
                    raise ModelError(f"{path.text}: the link's {path.table} is an inline table;"
                                     f" write it as [link.{path.table}] to let casflex edit it")
            end = max(r[1] for r in block.values())
            while end > main[0] + 1 and not lines[end - 1].strip():
                end -= 1
            lines[end:end] = [f"[link.{path.table}]", new_line]
            continue
        first, end = where
        hit = [i for i in range(first + 1, end) if key_re.match(lines[i])]
        if hit:
            lines[hit[0]] = new_line
        else:
            pos = end
            while pos > first + 1 and not lines[pos - 1].strip():
                pos -= 1
            lines.insert(pos, new_line)
    out = "\n".join(lines) + "\n"
    robot = loads(out)
    raw = parse_toml(out)
    for path, value in zip(paths, values, strict=True):
        got = parameter_value(robot, parse_parameter_path(path.text, robot, raw=raw))
        if got is None or abs(got - float(value)) > 1e-12 * max(abs(float(value)), 1e-300):
            raise ModelError(f"{path.text}: the edited robot text gives {got!r}, not the "
                             f"fitted {float(value)!r}; edit the file by hand")
    return out
