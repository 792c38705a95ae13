"""Every public function, class and method of casflex has a numpydoc docstring with an example.

The project rule: every public function has a numpydoc docstring with a runnable example,
and CI runs those examples (pytest's ``--doctest-modules`` over ``casflex/``, see
``pyproject.toml``). This test checks that the examples exist:

* the public API of a module is ``__all__`` if it defines one, otherwise the functions and
  classes defined in the module itself whose names do not start with ``_``;
* each public function and class, and each public method of such a class (plain,
  static and class methods defined in the class body; dataclass-generated methods and
  properties are not checked), needs a docstring with an ``Examples`` section that
  contains ``>>>``;
* a function or method that takes parameters other than ``self``/``cls`` also needs a
  ``Parameters`` section.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import pkgutil
import re

import casflex

# Known offenders the test skips. It is empty: every public name is complete. It was only
# a transition list (test_pending_entries_are_still_offenders fails for an entry that no
# longer offends, so it could only shrink); do not add names to it, fix the docstring.
PENDING: frozenset[str] = frozenset()

_EXAMPLES = re.compile(r"^Examples\n-{3,}\n", re.MULTILINE)
_PARAMETERS = re.compile(r"^Parameters\n-{3,}\n", re.MULTILINE)


def _public_api(module):
    """Yield ``(name, object)`` for the public functions and classes of ``module``."""
    names = getattr(module, "__all__", None)
    if names is None:
        names = [
            n
            for n, o in vars(module).items()
            if not n.startswith("_")
            and (inspect.isfunction(o) or inspect.isclass(o))
            and getattr(o, "__module__", None) == module.__name__
        ]
    for n in names:
        o = getattr(module, n)
        if (inspect.isfunction(o) or inspect.isclass(o)) and o.__module__ == module.__name__:
            yield n, o


def _dataclass_generated(cls, func):
    """True if ``func`` was written by the ``dataclasses`` decorator (compiled from a string)."""
    return dataclasses.is_dataclass(cls) and (
        func.__code__.co_filename == "<string>" or "__create_fn__" in func.__qualname__
    )


def _public_methods(cls):
    """Yield ``(name, function, is_static)`` for the public methods defined in ``cls``'s body.

    Plain, static and class methods count; properties and methods the dataclass decorator
    generated do not.
    """
    for n, raw in vars(cls).items():
        if n.startswith("_") or isinstance(raw, property):
            continue
        func = raw.__func__ if isinstance(raw, (staticmethod, classmethod)) else raw
        if not inspect.isfunction(func) or _dataclass_generated(cls, func):
            continue
        yield n, func, isinstance(raw, staticmethod)


def _takes_parameters(func, bound):
    """True if ``func`` takes parameters other than ``self``/``cls``."""
    params = list(inspect.signature(func).parameters.values())
    if bound and params:
        params = params[1:]
    return bool(params)


def _problems(qualname, obj, *, is_class=False, bound=False):
    """What ``obj``'s docstring lacks, as a list of messages (empty when it is complete)."""
    doc = inspect.cleandoc(obj.__doc__ or "")
    if not doc:
        return [f"{qualname}: no docstring"]
    out = []
    examples = _EXAMPLES.search(doc)
    if examples is None or ">>>" not in doc[examples.end():]:
        out.append(f"{qualname}: no 'Examples' section with '>>>'")
    if not is_class and _takes_parameters(obj, bound) and not _PARAMETERS.search(doc):
        out.append(f"{qualname}: takes parameters but has no 'Parameters' section")
    return out


@functools.cache
def _offenders():
    """Map qualified name -> list of problems, for the whole package (computed once)."""
    found: dict[str, list[str]] = {}
    modules = [casflex.__name__] + [
        m.name for m in pkgutil.walk_packages(casflex.__path__, casflex.__name__ + ".")
    ]
    for modname in modules:
        module = importlib.import_module(modname)
        for name, obj in _public_api(module):
            qual = f"{modname}.{name}"
            if inspect.isclass(obj):
                probs = _problems(qual, obj, is_class=True)
                for mname, func, static in _public_methods(obj):
                    mqual = f"{qual}.{mname}"
                    mprobs = _problems(mqual, func, bound=not static)
                    if mprobs:
                        found[mqual] = mprobs
            else:
                probs = _problems(qual, obj)
            if probs:
                found[qual] = probs
    return found


def test_checker_flags_incomplete_docstrings():
    def complete(x):
        """Double.

        Parameters
        ----------
        x : float

        Examples
        --------
        >>> complete(2)
        4
        """
        return 2 * x

    def no_example(x):
        """Double.

        Parameters
        ----------
        x : float

        Examples
        --------
        complete(2) is 4.
        """

    def no_parameters(x):
        """Double.

        Examples
        --------
        >>> no_parameters(2)
        """

    assert _problems("complete", complete) == []
    assert _problems("no_example", no_example) == ["no_example: no 'Examples' section with '>>>'"]
    assert _problems("no_parameters", no_parameters) == [
        "no_parameters: takes parameters but has no 'Parameters' section"
    ]
    assert _problems("undocumented", lambda: None) == ["undocumented: no docstring"]

    @dataclasses.dataclass
    class Point:
        x: float

        @property
        def norm(self):
            return abs(self.x)

        def scaled(self, k):
            return Point(k * self.x)

    assert [name for name, _, _ in _public_methods(Point)] == ["scaled"]


def test_public_api_has_numpydoc_examples():
    offenders = _offenders()
    new = {q: p for q, p in offenders.items() if q not in PENDING}
    lines = [msg for q in sorted(new) for msg in new[q]]
    assert not lines, (
        f"{len(new)} public callables lack a numpydoc docstring with an example:\n  "
        + "\n  ".join(lines)
    )


def test_pending_entries_are_still_offenders():
    fixed = sorted(PENDING - set(_offenders()))
    assert not fixed, "fixed, remove from PENDING in tests/test_docstrings.py: " + ", ".join(fixed)
