"""Generate casflex/shaping/ei_fit_table.npz: 2-D Chebyshev fits of the damped EI family.

For every kind (EI, two-hump, three-hump EI) the exact damped shaper
(``ei_family_normalised(..., method="solve")``, continuation in ζ from the undamped form)
is computed on a tensor grid of Chebyshev nodes in ζ on ``[0, zeta_max]`` and in
``vtol**power`` on ``[vtol_min**power, vtol_max**power]`` (the undamped closed forms are
smooth in ``vtol`` for EI, in ``vtol**(1/3)`` for two-hump and ``vtol**(1/2)`` for
three-hump EI). The box of each kind is where the exact solve stays on one smooth branch:
three-hump EI folds (no solution) at ζ ≈ 0.13 for vtol = 0.2 and bends sharply towards
ζ = 0.2 at vtol = 0.1; two-hump EI bends sharply towards ζ = 0.2 at vtol = 0.2 (its fit
on ζ <= 0.15 missed by 1.5e-7, on ζ <= 0.1 it meets 1e-11). The fit is
checked against the exact solve at points between the nodes (the box's corners and edges
and 60 seeded random points) before anything is written; a kind whose fit errs by more
than 1e-10 is left out (the exact solve is used for it).

Usage: ``python tools/gen_ei_fit.py [--check] [--kinds ei ei2 ei3]`` (``--check`` only
reports the fit error; ``--kinds`` refits those kinds and keeps the others' stored fit).
"""

from __future__ import annotations

import argparse
import math
import pathlib

import numpy as np
from numpy.polynomial import chebyshev

from casflex.shaping.ei_family import ei_family_normalised

#: kind -> (zeta_max, vtol_min, vtol_max, power of vtol, nodes in ζ, nodes in vtol)
BOXES = {
    "ei": (0.2, 0.01, 0.2, 1.0, 20, 12),
    "ei2": (0.1, 0.01, 0.2, 1.0 / 3.0, 22, 20),
    "ei3": (0.12, 0.01, 0.1, 0.5, 24, 16),
}
TARGET = pathlib.Path(__file__).resolve().parent.parent / "casflex/shaping/ei_fit_table.npz"


def exact(kind, zeta, vtol):
    tau, amp = ei_family_normalised(kind, zeta, vtol, method="solve")
    return np.concatenate([amp, tau[1:]])


def to_box(kind, x, y):
    """Chebyshev coordinates (x, y) in [-1, 1]² -> (ζ, vtol)."""
    zmax, vmin, vmax, p, _, _ = BOXES[kind]
    g0, g1 = vmin**p, vmax**p
    return 0.5 * (x + 1.0) * zmax, (g0 + 0.5 * (y + 1.0) * (g1 - g0)) ** (1.0 / p)


def nodes(n):
    return np.cos(math.pi * (np.arange(n) + 0.5) / n)


def fit(kind):
    _, _, _, _, nz, nv = BOXES[kind]
    xs, ys = nodes(nz), nodes(nv)
    values = np.array([[exact(kind, *to_box(kind, x, y)) for y in ys] for x in xs])
    # tensor Chebyshev interpolation: along ζ, then along vtol
    vz = chebyshev.chebvander(xs, nz - 1)
    vv = chebyshev.chebvander(ys, nv - 1)
    coeffs = np.einsum("ai,bj,abk->ijk", np.linalg.inv(vz).T, np.linalg.inv(vv).T, values)
    rng = np.random.default_rng(14)
    checks = [(x, y) for x in (-1.0, 0.0, 1.0) for y in (-1.0, 0.0, 1.0)]
    checks += [tuple(p) for p in rng.uniform(-1.0, 1.0, (60, 2))]
    err = 0.0
    for x, y in checks:
        got = np.einsum("i,ijk,j->k", chebyshev.chebvander(x, nz - 1)[0],
                        coeffs, chebyshev.chebvander(y, nv - 1)[0])
        err = max(err, float(np.max(np.abs(got - exact(kind, *to_box(kind, x, y))))))
    return coeffs, err


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="report the fit error only")
    parser.add_argument("--kinds", nargs="*", default=list(BOXES), help="kinds to fit")
    args = parser.parse_args(argv)
    tables = {}
    for kind in args.kinds:
        coeffs, err = fit(kind)
        zmax, vmin, vmax, p, nz, nv = BOXES[kind]
        print(f"{kind}: zeta <= {zmax}, {vmin} <= vtol <= {vmax}: max |fit - exact| "
              f"off the nodes = {err:.2e}")
        if err > 1e-10:  # V errs by about as much: 1e-10 keeps it well inside 1e-9
            print(f"  left out: {err:.2e} > 1e-10 (ei_family_normalised solves there)")
            continue
        tables[f"{kind}_coefficients"] = coeffs
        tables[f"{kind}_box"] = np.array([zmax, vmin, vmax, p])
    if not args.check:
        # kinds not refitted keep their stored fit (--kinds refits some of them)
        kept = {}
        if TARGET.is_file():
            with np.load(TARGET) as old:
                kept = {name: np.array(old[name]) for name in old.files
                        if name.split("_")[0] not in args.kinds}
        np.savez(TARGET, **kept, **tables)
        print(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
