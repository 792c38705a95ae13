"""Whether a chain can be solved in double precision, and messages that say where not.

The transfer-matrix method multiplies and condenses matrices whose entries span the
stiffnesses of every element. Two things break it without any error from numpy:

* an element whose stiffness or mass is zero, negative or not finite (its transfer matrix
  is singular or NaN);
* beams whose stiffnesses are too far apart: the chain product and the stiffness
  condensation lose every digit, and the roots come out anywhere (``E = 1e40`` gave all
  frequencies near 0). The spread is measured unit-free as the squared ratio of the beams'
  highest and lowest clamped–free frequencies (tension, torsion, bending).

:func:`check_chain` refuses both before the root search; the root search itself checks
its counts and determinants (:mod:`casflex.tmm.solve`) and uses :func:`describe` and
:func:`stiffness_spread` for its messages.
"""

from __future__ import annotations

import functools

import numpy as np

from casflex.errors import ModelError
from casflex.tmm.chain import Chain, Element

__all__ = ["check_chain"]

#: Largest ratio of the beams' stiffnesses (squared frequency spread) the TMM accepts. On
#: the Table 8 arm with link 2 stiffened, the frequencies stay within 4e-9 of the stiff
#: limit up to a ratio of 9.5e15 and are off by 25 % at 2.9e16 (the chain product loses
#: every digit); physical robots stay below 1e10 (a slenderness L/r of 2e5).
MAX_STIFFNESS_RATIO = 1e15


def format_q(q) -> str:
    """Joint variables for messages."""
    return np.array2string(np.asarray(q, dtype=float), precision=6, separator=", ")


def lowest_beam_frequency(beam: Element) -> float:
    """Lowest clamped–free frequency of one beam alone in bending, torsion or tension [rad/s]."""
    P = beam.params
    try:  # Section and Material are frozen dataclasses: the same beam again is a lookup
        return _lowest_frequency(P["section"], P["material"], P["length"])
    except TypeError:  # unhashable parameters
        return _lowest_frequency.__wrapped__(P["section"], P["material"], P["length"])


@functools.lru_cache(maxsize=256)
def _lowest_frequency(sec, mat, L):
    with np.errstate(all="ignore"):
        bending = (1.875 / L) ** 2 * np.sqrt(mat.E * min(sec.Ix, sec.Iy) / (mat.rho * sec.A))
        torsion = np.pi / (2.0 * L) * np.sqrt(mat.G * sec.J / (mat.rho * sec.Ip))
        axial = np.pi / (2.0 * L) * np.sqrt(mat.E / mat.rho)
    finite = [float(w) for w in (bending, torsion, axial) if np.isfinite(w) and w > 0.0]
    return min(finite) if finite else np.inf


def describe(element: Element) -> str:
    """The parameters of an element that set its stiffness and inertia, for messages."""
    P = element.params
    if element.kind == "beam":
        mat, sec = P["material"], P["section"]
        return (f"E = {mat.E:g} Pa, G = {mat.G:g} Pa, rho = {mat.rho:g} kg/m^3, "
                f"A = {sec.A:g} m^2, Ix = {sec.Ix:g} m^4, Iy = {sec.Iy:g} m^4, "
                f"J = {sec.J:g} m^4, L = {P['length']:g} m")
    if element.kind == "body":
        return f"mass = {P['mass']:g} kg, inertia = {np.asarray(P['inertia']).tolist()} kg m^2"
    if element.kind == "spring":
        return f"stiffness = {P['stiffness']:g} N m/rad"
    return f"offset = {np.linalg.norm(P['r']):g} m"


def stiffness_spread(chain: Chain) -> tuple[float, str]:
    """(ratio, text): how far apart the beams' stiffnesses are, from their frequencies."""
    rows = []
    for b in chain.beams:
        mat, L = b.params["material"], b.params["length"]
        with np.errstate(all="ignore"):
            rows += [(lowest_beam_frequency(b), b.label),
                     (float(np.pi / (2.0 * L) * np.sqrt(mat.E / mat.rho)), b.label)]
    rows = [r for r in rows if np.isfinite(r[0]) and r[0] > 0.0]
    if not rows:
        return 1.0, "no beam has a finite frequency"
    (lo, lo_at), (hi, hi_at) = min(rows), max(rows)
    ratio = (hi / lo) ** 2
    return ratio, (f"the beams' clamped-free frequencies span {lo:.3g} rad/s ({lo_at}) to "
                   f"{hi:.3g} rad/s in tension ({hi_at}), a stiffness ratio of {ratio:.3g}")


def _check_element(element, q):
    """Stiffnesses and masses finite and > 0 (≥ 0 for bodies), else a singular matrix."""
    P, values, body = element.params, {}, element.kind == "body"
    with np.errstate(all="ignore"):
        if element.kind == "beam":
            sec, mat = P["section"], P["material"]
            values = {"EA": (mat.E * sec.A, "N"), "EIx": (mat.E * sec.Ix, "N m^2"),
                      "EIy": (mat.E * sec.Iy, "N m^2"), "GJ": (mat.G * sec.J, "N m^2"),
                      "rho A": (mat.rho * sec.A, "kg/m"), "rho Ip": (mat.rho * sec.Ip, "kg m")}
        elif element.kind == "spring":
            values = {"stiffness": (P["stiffness"], "N m/rad")}
        elif body:
            values = {"mass": (P["mass"], "kg"),
                      "inertia": (float(np.sum(np.abs(P["inertia"]))), "kg m^2")}
    for name, (value, unit) in values.items():
        if not (np.isfinite(value) and (value >= 0.0 if body else value > 0.0)):
            raise ModelError(
                f"TMM breakdown at q = {format_q(q)} rad: the {element.label} has {name} = "
                f"{value:g} {unit}: its transfer matrix is singular or not finite (it must be "
                f"finite and {'≥ 0' if body else '> 0'}; {describe(element)})")


def check_chain(chain: Chain) -> None:
    """Refuse a chain the TMM cannot solve in double precision, naming where and why.

    Parameters
    ----------
    chain : Chain
        From :func:`casflex.tmm.build_chain`.

    Raises
    ------
    casflex.errors.ModelError
        An element with a zero, negative or non-finite stiffness or mass (a singular or
        NaN transfer matrix), or beams whose stiffnesses span more than
        ``MAX_STIFFNESS_RATIO`` (1e15): the message names the configuration, the element
        (kind, link, DH row) and the quantity.

    Examples
    --------
    >>> import copy, dataclasses
    >>> from casflex.robot import load
    >>> from casflex.tmm import build_chain
    >>> arm = load("problems/arm2link.toml")
    >>> check_chain(build_chain(arm, [0.0, 0.0, 0.0]))   # the Table 8 arm: fine
    >>> # E = 1e40 is refused by Material itself; set it behind the check, as a bug could
    >>> material, stiff = copy.copy(arm.links[2].material), copy.copy(arm.links[2])
    >>> object.__setattr__(material, "E", 1e40)
    >>> object.__setattr__(stiff, "material", material)
    >>> robot = dataclasses.replace(arm, links=(*arm.links[:2], stiff, arm.links[3]))
    >>> try:
    ...     check_chain(build_chain(robot, [0.0, 0.0, 0.0]))
    ... except ModelError as exc:
    ...     print(str(exc)[:80])
    TMM ill-conditioned at q = [0., 0., 0.] rad: the beams' clamped-free frequencies
    """
    for element in chain.elements:
        _check_element(element, chain.q)
    ratio, spread = stiffness_spread(chain)
    if ratio > MAX_STIFFNESS_RATIO:
        raise ModelError(
            f"TMM ill-conditioned at q = {format_q(chain.q)} rad: {spread}, above the "
            f"{MAX_STIFFNESS_RATIO:g} that double precision resolves in the chain product; "
            "check E, G, rho and the section of that link")
