"""How fit_model_terms holds, reuses and resumes its sample points (issue 21, session 9).

References:
- tests/data/term_fits_s8.npz: the coefficients of two small fits computed by the
  session-8 code (commit 24a3e7a, points held in a dict per point), stored with their
  SHA-256. The points are now held in preallocated arrays over the grid and the
  coefficients formed term by term; the same arithmetic must give the same bits.
- the mass normalisation is done once per point now, and the TMM's Brent search has
  shed rotations that do not change its determinant (roots move by up to 1e-12 relative
  on arm2link): the fit may differ from the stored one only by round-off. When the
  storage changed (this session) the fit with the session-8 double normalisation
  (reproduced here by handing the quantity function a copy of the normalised modes) was
  bit-identical to the stored one on the session-8 TMM; that comparison is no longer
  possible bit for bit, and the double-normalised fit is held to the same round-off.
"""

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal import TERM_FLOOR, TERM_TARGET, fit_model_terms, term_scales
from casflex.modal.normalize import mass_normalize
from casflex.modal.tables import default_quantities
from casflex.model.build import sensor_quantities
from casflex.robot import load
from casflex.tmm import modes

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "term_fits_s8.npz"
REFERENCE_SHA256 = "ab8b30332eb27b89881423f1cb41b9a5dd4c51b9ffb0c0bc1609eaa218004b1b"
BOX = [(-0.5, 0.5), (0.2, 0.6)]


def normalized_twice(robot, q, shapes):
    """default_quantities on a copy: the copy is not recognised as normalised, so it is
    normalised a second time, as the session-8 code did."""
    return default_quantities(robot, q, dataclasses.replace(shapes))


def _reference():
    assert hashlib.sha256(REFERENCE.read_bytes()).hexdigest() == REFERENCE_SHA256
    with np.load(REFERENCE) as data:
        return {k: data[k] for k in data.files}


def _fits(quantities=None, **smooth_options):
    arm = load("problems/arm2link.toml")
    smooth = fit_model_terms(arm, 1, joints=(1, 2), box=BOX, basis="smooth",
                             start_degree=4, max_degree=8, refine="worst", processes=1,
                             quantities=quantities, **smooth_options)
    eigen = fit_model_terms(dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.6))),
                            2, start_degree=4, max_degree=16, processes=1,
                            quantities=quantities)
    return {"smooth": smooth, "eigen": eigen}


def _check(fits, reference):
    for tag, fit in fits.items():
        assert list(fit.degrees) == reference[f"{tag}.degrees"].tolist()
        assert fit.info["points"] == int(reference[f"{tag}.points"])
        names = {k.split(".", 1)[1] for k in reference if k.startswith(tag + ".")}
        assert set(fit.coefficients) == names - {"degrees", "points"}
        for name, coef in fit.coefficients.items():
            ref = reference[f"{tag}.{name}"]
            if ref.size:
                # one normalisation fewer (or the TMM's round-off) moves each sample by a
                # few ulp; a coefficient sums at most 45 of them: 1e-14 of the peak is ~20x
                # the 5e-16 seen
                assert np.abs(coef - ref).max() <= 1e-14 * np.abs(ref).max(), (tag, name)


def test_the_fits_equal_the_session_8_code_with_its_double_normalisation():
    """Same arithmetic, other storage: the same fit to round-off (see the module's
    docstring for why no longer bit for bit). The smooth fit leaves ``gauge`` at its
    default, which is now the reference gauge the stored fit asked for."""
    fits = _fits(quantities=normalized_twice)
    assert fits["smooth"].info["gauge"] == "reference"
    assert fits["eigen"].info["gauge"] == "neighbour"
    _check(fits, _reference())


def test_normalising_once_changes_the_fits_by_round_off_only():
    _check(_fits(), _reference())


def test_mass_normalize_gives_its_own_output_back_and_normalises_anything_else():
    robot = load("problems/arm2link.toml")
    raw = modes(robot, [0.0, 0.0, 0.5], count=2)
    once = mass_normalize(robot, raw)
    assert mass_normalize(robot, once) is once
    copy = dataclasses.replace(once)
    again = mass_normalize(robot, copy)
    assert again is not copy  # not recognised: normalised again, to round-off the same
    assert np.abs(again.displacement - once.displacement).max() <= (
        1e-14 * np.abs(once.displacement).max())
    assert mass_normalize(robot, once, points=24) is not once  # another quadrature


def test_a_checkpointed_fit_resumes_without_solving_its_points_again(tmp_path):
    arm = load("problems/arm2link.toml")
    options = dict(joints=(1, 2), box=BOX, basis="smooth", start_degree=4, max_degree=8,
                   refine="worst", processes=1, checkpoint=tmp_path)
    first = fit_model_terms(arm, 1, **options)
    assert first.info["resumed_points"] == 0
    # the reference field's 5 x 5 points are solved again; the 20 others are read back
    second = fit_model_terms(arm, 1, **options)
    assert second.info["resumed_points"] == first.info["points"] - 25 == 20
    for name, coef in first.coefficients.items():
        assert np.array_equal(second.coefficients[name], coef), name
    files = sorted(tmp_path.glob("points-*.npz"))
    files[0].write_bytes(files[0].read_bytes()[:100])  # a damaged file is not used
    third = fit_model_terms(arm, 1, **options)
    assert third.info["resumed_points"] < 20
    for name, coef in first.coefficients.items():
        assert np.array_equal(third.coefficients[name], coef), name
    with pytest.raises(ModelError, match="checkpoint"):
        fit_model_terms(arm, 1, basis="eigen", checkpoint=tmp_path)


def with_round_off_axial_strain(robot, q, shapes):
    """The sensor quantities with an axial strain that is round-off of the curvature's
    size: ~1e-16 of it, and as rough as round-off (it does not decay with the degree)."""
    values = sensor_quantities(robot, q, shapes, points=((3, 0.5),))
    noise = 1e-16 * np.sin(1e6 * float(q[2]) + np.arange(values["point_curvature"].size))
    values["point_axial_strain"] = noise.reshape(values["point_curvature"].shape)[..., 0]
    return values


def test_a_term_zero_to_round_off_does_not_stop_the_fit_converging():
    """A term that is zero but for round-off (the axial strain of bending modes at a
    sensor: session 8 saw coefficients of 8e-21 read as a relative error of 0.029) must
    not keep the fit from converging: its error is measured against its family's scale
    (the sensor values, ~1 here), not against its own round-off peak."""
    arm = dataclasses.replace(load("problems/arm2link.toml"),
                              joint_limits=(None, None, (0.2, 0.6)))
    fit = fit_model_terms(arm, 1, quantities=with_round_off_axial_strain, start_degree=4,
                          max_degree=16, processes=1)
    axial = fit.coefficients["point_axial_strain"]
    own_tail = 2.0 * np.abs(axial[-2:]).max() / np.abs(axial).max()
    assert own_tail > TERM_TARGET  # what the estimate read before the floor
    assert fit.info["converged"] and fit.degrees == (8,)  # as without that term
    assert fit.info["estimate"]["point_axial_strain"] < 1e-6


def test_term_scales_floor_a_term_by_its_family_only():
    peaks = {"point_u": 0.3, "point_curvature": 1.0, "point_axial_strain": 1e-22,
             "point_twist_rate": 2e-5, "C1": 1e-30, "sample_u": 2.0}
    s = term_scales(peaks)
    assert s["point_axial_strain"] == TERM_FLOOR * 1.0
    assert s["point_twist_rate"] == 2e-5  # small but real: its own peak
    assert s["C1"] == 1e-30  # its own family: no floor from the others
    assert s["sample_u"] == 2.0 and s["point_u"] == 0.3
