"""The ``casflex`` command line.

Every verb lives in its own module under :mod:`casflex.commands` and exposes

``HELP``
    one-line description,
``add_arguments(parser)``
    adds the verb's arguments to an :class:`argparse.ArgumentParser`,
``run(args, log)``
    does the work and returns a JSON-serialisable ``dict`` (SI units). ``log`` is a
    callable that writes a human-readable line to stderr.

With ``--json`` the returned dict is printed as exactly one JSON object on stdout and
nothing else is written there; human-readable output and progress bars go to stderr.
Errors derived from :class:`casflex.errors.CasflexError` are reported in one line on
stderr with exit status 2.
"""

from __future__ import annotations

import importlib
import json
import sys
from collections.abc import Sequence

from casflex._json import jsonable
from casflex.commands.common import ArgumentParser
from casflex.errors import CasflexError

#: verb name -> module under casflex.commands
VERBS = {
    "modes": "modes",
    "sweep": "sweep",
    "shaper": "shaper",
    "check": "check",
    "accessibility": "accessibility",
    "simulate": "simulate",
    "codegen": "codegen",
    "design": "design",
    "plan": "plan",
    "identify": "identify",
    "calibrate": "calibrate",
}


def _available_verbs(only=None):
    verbs = {}
    for verb, module in VERBS.items():
        if only is not None and verb != only:
            continue
        try:
            verbs[verb] = importlib.import_module(f"casflex.commands.{module}")
        except ModuleNotFoundError as exc:  # verb not shipped yet in this build
            if exc.name != f"casflex.commands.{module}":
                raise
    return verbs


def build_parser(verb: str | None = None) -> ArgumentParser:
    """Return the :class:`argparse.ArgumentParser` of the ``casflex`` command.

    Parameters
    ----------
    verb : str, optional
        Register this verb alone: only its module (and what it imports) is loaded, which
        is what :func:`main` does when the command line names a verb. Default: every verb
        (``casflex --help`` lists them all).

    Examples
    --------
    >>> parser = build_parser()
    >>> parser.prog
    'casflex'
    >>> sorted(build_parser("modes")._subparsers._group_actions[0].choices)
    ['modes']
    """
    parser = ArgumentParser(
        prog="casflex",
        description="Modeling, estimation and control of flexible serial robot arms.",
    )
    from casflex import __version__

    parser.add_argument("--version", action="version", version=f"casflex {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    sub.required = True
    for name, module in _available_verbs(verb).items():
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.add_argument(
            "--json", action="store_true", help="print exactly one JSON object on stdout"
        )
        p.set_defaults(verb_module=module)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``casflex`` console script; returns the exit status.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments after ``casflex`` (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 2 after a :class:`casflex.errors.CasflexError` (reported in one line
        on stderr), 130 when interrupted.

    Examples
    --------
    >>> import contextlib, io, json
    >>> out = io.StringIO()
    >>> with contextlib.redirect_stdout(out):
    ...     status = main(["modes", "problems/arm2link.toml", "--modes", "2", "--json"])
    >>> result = json.loads(out.getvalue())
    >>> status, sorted(result), [round(w, 3) for w in result["omega"]]
    (0, ['frequency_hz', 'omega', 'q'], [8.307, 11.97])
    >>> main(["modes", "problems/arm2link.toml", "--modes", "0"])   # error on stderr
    2
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    # import only the named verb's module: the others' imports (scipy.optimize, the
    # identification and shaping packages...) cost a warm run more than its work
    verb = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(verb if verb in VERBS else None)
    args = parser.parse_args(argv)

    def log(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    try:
        result = args.verb_module.run(args, log)
    except CasflexError as exc:
        # one line whatever the message holds (a solver's report may span several)
        message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f"casflex {args.verb}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"casflex {args.verb}: interrupted", file=sys.stderr)
        return 130
    if args.json:
        sys.stdout.write(json.dumps(jsonable(result)) + "\n")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
