"""A long SX function cut into consecutive pieces, for C code that compiles fast.

gcc's time on one C function grows faster than linearly with its length: the register
allocator works on the whole straight-line body (``-ftime-report`` of the model bundle:
LRA and IRA are ~55 % of the ``-O2`` compile). CasADi writes an SX function as one C
function, so a graph of 15 000 instructions becomes one body of 15 000 lines.

:func:`segmented` cuts the SX function's own instruction list (its algorithm, in
CasADi's evaluation order) into consecutive runs of at most ``max_instructions``
instructions. Each run becomes an SX function of the original inputs and of the values
that earlier runs computed and it reads (``live``), returning the values that later runs
read and the output nonzeros it writes. An MX function wires the runs together. Every
instruction is replayed with the same operation on the same operands, in the same order,
so the result is **bit-identical** to the original function in CasADi's VM and in C.
Inputs and constants a run needs are read or written again in that run rather than
passed along.

Examples
--------
>>> import casadi as ca
>>> x = ca.SX.sym("x", 3)
>>> y = x
>>> for k in range(40):
...     y = ca.sin(y) * 1.5 + ca.cos(y[[1, 2, 0]])
>>> f = ca.Function("f", [x], [y, ca.sumsqr(y)], ["x"], ["y", "s"])
>>> g = segmented(f, 100)
>>> len(pieces(g)) > 3, g.name_in(), g.name_out()
(True, ['x'], ['y', 's'])
>>> a, b = f([0.1, 0.2, 0.3]), g([0.1, 0.2, 0.3])
>>> bool((a[0] == b[0]).full().all() and float(a[1]) == float(b[1]))
True
"""

from __future__ import annotations

import casadi as ca

from casflex.errors import ModelError

__all__ = ["segmented", "pieces"]

#: default length of a piece [instructions]: gcc -O2 compiles pieces of this size at a
#: near-constant time per line (benchmarks/README_codegen.md, issue 17)
MAX_INSTRUCTIONS = 3000

_SPECIAL = (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_CALL)


def segmented(f: ca.Function, max_instructions: int = MAX_INSTRUCTIONS) -> ca.Function:
    """``f`` as an MX function calling consecutive pieces of its SX algorithm.

    Parameters
    ----------
    f : casadi.Function
        An SX function (``SXFunction``); any other function is returned unchanged.
    max_instructions : int
        Most instructions in one piece (>= 1). A function of at most that many
        instructions is returned unchanged.

    Returns
    -------
    casadi.Function
        Same name, ports and port names as ``f``; bit-identical results. Its pieces are
        SX functions named ``<name>_part<k>`` (:func:`pieces`).

    Raises
    ------
    casflex.errors.ModelError
        For ``max_instructions < 1``.

    Examples
    --------
    >>> x = ca.SX.sym("x", 2)
    >>> f = ca.Function("f", [x], [ca.sin(x[0]) * ca.cos(x[1]) + x[0] ** 2])
    >>> g = segmented(f, 2)
    >>> [p.name() for p in pieces(g)][:2], float(f([0.3, 0.4])) == float(g([0.3, 0.4]))
    (['f_part0', 'f_part1'], True)
    """
    if int(max_instructions) != max_instructions or max_instructions < 1:
        raise ModelError(f"max_instructions must be an integer >= 1; got {max_instructions}")
    if f.class_name() != "SXFunction" or f.n_instructions() <= max_instructions:
        return f
    n = f.n_instructions()
    ops = [f.instruction_id(k) for k in range(n)]
    ins = [f.instruction_input(k) for k in range(n)]
    outs = [f.instruction_output(k) for k in range(n)]
    calls = {k: None for k in range(n) if ops[k] == ca.OP_CALL}
    if calls:  # the called functions, from the instructions' own nodes
        nodes = f.instructions_sx()
        calls = {k: nodes[k].which_function() for k in calls}
    bounds = list(range(0, n, int(max_instructions))) + [n]
    runs = list(zip(bounds[:-1], bounds[1:], strict=True))

    # pass 1: what every run reads that an earlier run computed (by slot), what it exports
    origin = {}  # slot -> ("in", i, nz) | ("const", k) | ("run", r, slot)
    reads, exports = [], [dict() for _ in runs]  # exports[r]: slot -> position
    for r, (a, b) in enumerate(runs):
        written, need = set(), {}
        for k in range(a, b):
            src = ins[k] if ops[k] not in (ca.OP_INPUT, ca.OP_CONST) else []
            for s in src:
                if s not in written and s not in need:
                    need[s] = origin[s]
            dst = outs[k] if ops[k] != ca.OP_OUTPUT else []
            written.update(s for s in dst if s >= 0)
        for o in need.values():
            if o[0] == "run":
                exports[o[1]].setdefault(o[2], len(exports[o[1]]))
        reads.append(need)
        for k in range(a, b):
            op = ops[k]
            if op == ca.OP_INPUT:
                origin[outs[k][0]] = ("in", ins[k][0], ins[k][1])
            elif op == ca.OP_CONST:
                origin[outs[k][0]] = ("const", k)
            elif op != ca.OP_OUTPUT:
                for s in outs[k]:
                    if s >= 0:
                        origin[s] = ("run", r, s)

    # pass 2: one SX function per run, and the MX graph that calls them
    sx_in = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    mx_in = [ca.MX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    placed = []  # (output, nz) of every output nonzero, in the order the runs write them
    exported, written = [], []  # per run: its MX export vector and output nonzeros
    for r, (a, b) in enumerate(runs):
        # the values from earlier runs, grouped by run: one gather per earlier run
        live = sorted(((o[1], exports[o[1]][o[2]], s) for s, o in reads[r].items()
                       if o[0] == "run"))
        live_sym = ca.SX.sym("live", len(live))
        work = {s: v for (_, _, s), v in zip(live, ca.vertsplit(live_sym), strict=True)}
        for s, o in reads[r].items():
            if o[0] == "in":
                work[s] = sx_in[o[1]].nz[o[2]]
            elif o[0] == "const":
                work[s] = ca.SX(f.instruction_constant(o[1]))
        produced = []  # (output, nz, SX)
        for k in range(a, b):
            _replay(ops[k], ins[k], outs[k], k, f, calls, sx_in, work, produced)
        order = sorted(exports[r], key=exports[r].get)
        piece = ca.Function(f"{f.name()}_part{r}", [*sx_in, live_sym],
                            [ca.vertcat(*[work[s] for s in order]),
                             ca.vertcat(*[v for _, _, v in produced])],
                            [*f.name_in(), "live"], ["export", "written"])
        gathers = []
        for src in sorted({v[0] for v in live}):
            gathers.append(exported[src][[p for s_, p, _ in live if s_ == src]])
        res = piece(*mx_in, ca.vertcat(*gathers) if gathers else ca.MX(0, 1))
        exported.append(res[0])
        written.append(res[1])
        placed += [(o, nz) for o, nz, _ in produced]
    every = ca.vertcat(*written, ca.MX.zeros(1, 1))  # the last entry: a zero for unwritten ones
    where = {key: j for j, key in enumerate(placed)}
    outputs = [ca.MX(f.sparsity_out(i), every[[where.get((i, nz), len(placed))
                                                for nz in range(f.nnz_out(i))]])
               for i in range(f.n_out())]
    return ca.Function(f.name(), mx_in, outputs, f.name_in(), f.name_out())


def _replay(op, src, dst, k, f, calls, sx_in, work, produced):
    """Instruction ``k`` of ``f`` on the values in ``work`` (slot -> SX scalar)."""
    if op == ca.OP_INPUT:
        work[dst[0]] = sx_in[src[0]].nz[src[1]]
    elif op == ca.OP_CONST:
        work[dst[0]] = ca.SX(f.instruction_constant(k))
    elif op == ca.OP_OUTPUT:
        produced.append((dst[0], dst[1], work[src[0]]))
    elif op == ca.OP_CALL:
        fn = calls[k]
        args, at = [], 0
        for i in range(fn.n_in()):
            nnz = fn.nnz_in(i)
            args.append(ca.SX(fn.sparsity_in(i), ca.vertcat(*[work[s] for s in
                                                              src[at:at + nnz]])))
            at += nnz
        res = fn.call(args, False, True)  # a call node, as in f (never inlined)
        flat = [v for o in res for v in (o.nz[j] for j in range(o.nnz()))]
        for s, v in zip(dst, flat, strict=True):
            if s >= 0:
                work[s] = v
    elif len(src) == 1:
        work[dst[0]] = ca.SX.unary(op, work[src[0]])
    else:
        work[dst[0]] = ca.SX.binary(op, work[src[0]], work[src[1]])


def pieces(f: ca.Function) -> list[ca.Function]:
    """The pieces of a :func:`segmented` function, in calling order (``[]`` for any
    other function).

    Parameters
    ----------
    f : casadi.Function

    Returns
    -------
    list of casadi.Function

    Examples
    --------
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("f", [x], [ca.exp(ca.sin(x) + 1)])
    >>> [p.n_in() for p in pieces(segmented(f, 2))], pieces(f)
    ([2, 2, 2], [])
    """
    if f.class_name() != "MXFunction":
        return []
    found = []
    for k in range(f.n_instructions()):
        if f.instruction_id(k) == ca.OP_CALL:
            fn = f.instruction_MX(k).which_function()
            if fn.name().startswith(f.name() + "_part"):
                found.append(fn)
    return found

