"""Numerical breakdown of the TMM becomes one clear ModelError (issue 13, part 3).

The robots are built from the loaded Table 8 arm with values set behind the bounds, so the
load-time plausibility bounds of ``casflex.robot`` never see them: these tests exercise
the TMM's own checks.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

import casflex.commands.modes as modes_command
from casflex.cli import main
from casflex.errors import CasflexError, ModelError
from casflex.robot import load
from casflex.tmm import build_chain, count_below, modes, natural_frequencies, sweep_frequencies

ARM = "problems/arm2link.toml"


def unchecked(obj, **changes):
    """A copy of the frozen dataclass ``obj`` with ``changes`` set behind its
    ``__post_init__`` plausibility bounds (tests/test_faults.py tests those): the TMM's own
    checks must hold for values a bug, not a robot file, brings in."""
    new = copy.copy(obj)
    for key, value in changes.items():
        object.__setattr__(new, key, value)
    return new


def patched(robot, link_name, **changes):
    """``robot`` with ``changes`` applied to one link; ``material_E`` etc. patch the material."""
    links = []
    for link in robot.links:
        if link.name == link_name:
            material = {k[9:]: v for k, v in changes.items() if k.startswith("material_")}
            section = {k[8:]: v for k, v in changes.items() if k.startswith("section_")}
            rest = {k: v for k, v in changes.items()
                    if not k.startswith(("material_", "section_"))}
            if material:
                rest["material"] = unchecked(link.material, **material)
            if section:
                rest["section"] = unchecked(link.section, **section)
            link = unchecked(link, **rest)
        links.append(link)
    return dataclasses.replace(robot, links=tuple(links))


@pytest.fixture(scope="module")
def arm():
    return load(ARM)


def test_huge_modulus_is_a_model_error_naming_q_link_and_quantity(arm):
    # E = 1e40 Pa on link 1: its axial stiffness is ~1e34 times the bending stiffness of
    # link 2, beyond double precision; before the check every frequency came out ~0
    robot = patched(arm, "link1", material_E=1e40)
    with pytest.raises(ModelError) as info:
        natural_frequencies(robot, [0.0, 0.3, -0.7], count=5)
    text = str(info.value)
    assert "\n" not in text
    assert "q = [ 0. ,  0.3, -0.7] rad" in text
    assert "link 'link1' (DH row 3)" in text and "stiffness ratio of 1.39e+34" in text


def test_huge_modulus_on_both_links_is_caught_too(arm):
    # torsion (G unchanged) is now far softer than bending and tension
    robot = patched(patched(arm, "link1", material_E=1e40), "link2", material_E=1e40)
    with pytest.raises(ModelError, match="TMM ill-conditioned"):
        modes(robot, [0.0, 0.0, 0.0], count=5)


def test_silently_wrong_before_now_an_error(arm):
    # link 2 stiffened 3e11-fold (stiffness ratio 2.9e16): the third frequency came out
    # 25 % off the stiff limit without a word; now it is refused
    robot = patched(arm, "link2", material_E=69e9 * 3e11)
    with pytest.raises(ModelError, match="stiffness ratio of 2.87e"):
        natural_frequencies(robot, [0.0, 0.0, 1.0], count=5)


def test_stiff_but_resolvable_link_converges_to_the_stiff_limit(arm):
    # below the limit (ratio 9.5e13 and 9.5e11) the frequencies converge to the stiff-link
    # limit: a 100-fold stiffer link 2 moves them by O(1/E) ~ 1e-9 relative, plus the
    # round-off of the root search (rtol 1e-12 on well-conditioned chains)
    w8 = natural_frequencies(patched(arm, "link2", material_E=69e9 * 1e7), [0, 0, 1.0], count=5)
    w9 = natural_frequencies(patched(arm, "link2", material_E=69e9 * 1e9), [0, 0, 1.0], count=5)
    np.testing.assert_allclose(w9, w8, rtol=1e-7)


def test_sweep_names_the_configuration(arm):
    robot = patched(arm, "link2", material_E=1e40)
    qs = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ModelError, match=r"TMM ill-conditioned at q = \[0\., 0\., 0\.\] rad"):
        sweep_frequencies(robot, qs, 3)


def test_mode_near_zero_is_refused_by_the_static_probe(arm):
    # a tip body of 1e20 kg on 1 m aluminium links: modes far below 1e-6 of the lowest beam
    # frequency; the Wittrick–Williams count at the probe names where they come from
    from casflex.robot import TipBody
    robot = patched(arm, "link2", tip=unchecked(TipBody(), mass=1e20))
    with pytest.raises(ModelError) as info:
        natural_frequencies(robot, [0.0, 0.0, 1.0], count=3)
    text = str(info.value)
    assert "Wittrick–Williams count finds 3 natural frequencies below" in text
    assert "link 'link2'" in text


def test_near_zero_spring_names_the_spring(arm):
    robot = patched(arm, "link1", joint_stiffness=1e-20)
    with pytest.raises(ModelError, match=r"spring of link 'link1' \(DH row 3\).*1e-20 N m/rad"):
        natural_frequencies(robot, [0.0, 0.0, 1.0], count=3)


def test_zero_bending_stiffness_names_the_beam(arm):
    # Ix = 0: a beam without bending stiffness, its field matrix singular (and NaN)
    robot = patched(arm, "link2", section_Ix=0.0)
    with pytest.raises(ModelError) as info:
        natural_frequencies(robot, [0.0, 0.0, 0.0], count=3)
    text = str(info.value)
    assert "beam of link 'link2' (DH row 4)" in text
    assert "EIx = 0 N m^2" in text and "singular" in text and "Ix = 0 m^4" in text


def test_singular_joint_spring_names_the_spring(arm):
    # a spring of zero stiffness has an infinite compliance M/k: a singular element
    robot = patched(arm, "link1", joint_stiffness=0.0)
    with pytest.raises(ModelError) as info:
        natural_frequencies(robot, [0.0, 0.0, 0.0], count=3)
    text = str(info.value)
    assert "spring of link 'link1' (DH row 3)" in text
    assert "stiffness = 0 N m/rad" in text


def test_cli_modes_exit_2_one_line_on_breakdown(arm, monkeypatch, capsys):
    # the CLI's loader is replaced so that load-time bounds cannot be what rejects it
    robot = patched(arm, "link1", material_E=1e40)
    monkeypatch.setattr(modes_command, "load", lambda path: robot)
    assert main(["modes", ARM, "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "TMM ill-conditioned" in lines[0] and "link1" in lines[0]


def test_cli_modes_exit_2_for_the_file(tmp_path, capsys):
    # the reproducer of the issue as a file: whichever check rejects it (load-time bounds
    # or the TMM), it is one line and exit 2, never frequencies of 0
    text = open(ARM).read().replace("E = 69.0e9", "E = 1e40", 1)
    path = tmp_path / "e40.toml"
    path.write_text(text)
    assert main(["modes", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert len(captured.err.strip().splitlines()) == 1


def test_breakdown_is_a_casflex_error(arm):
    robot = patched(arm, "link1", material_E=1e40)
    with pytest.raises(CasflexError):
        modes(robot, [0.0, 0.0, 0.0], count=2)


def test_stiff_beam_counts_zero_at_low_frequency(arm):
    # a clamped structure has no natural frequency near 0; for a stiff beam at a low ω the
    # clamped-clamped count's 1 - cosh·cos rounds to 0 (β⁴/6 < eps), which used to give -½
    # per bending plane and a negative count
    chain = build_chain(patched(arm, "link1", material_E=69e13), [0.0, 0.0, 0.0])
    assert count_below(chain, [1e-9, 1e-6, 1e-3]).tolist() == [0, 0, 0]


@pytest.mark.parametrize("q", [[0.0, 0.0, 0.0], [0.4, -1.1, 2.5], [-2.0, 0.7, -0.3]])
def test_healthy_arm_unchanged_by_the_checks(arm, q):
    # the checks fire only on breakdown: the bundled arm solves as before, its lowest
    # frequency far above the static probe (here: the reference FE's 8.31 rad/s at q = 0
    # is checked in test_tmm.py; this only asserts the solve goes through and is positive)
    w = natural_frequencies(arm, q, count=5)
    assert w.shape == (5,) and np.all(w > 1.0)
