"""The EKF plant of a model with ``kinematics="exact"`` (issue 19).

The plant is tabulated from the model's own modal rows (``dddelta``), expanded in Δ and
stored as B-splines over the provider's shape joints times Fourier series in the other
joints. The exact kinematics' own modal block ``M_δδ(q, 0)`` (``modal_mass="kinematic"``,
its default) depends on the elbow angle through the rods' kinematics; on a provider
without the elbow as a shape joint the rows are then rational in its cosine and no
Fourier series holds them (measured: the plant's check error 0.38 against 1.7e-5 for the
truncated model, two modes frozen at one configuration). That case is refused with a
ModelError naming the joint and the two ways out; ``modal_mass="first_order"`` (M_δδ(q, 0)
= I) is accepted.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.estimation import tabulate_plant
from casflex.model import FlexibleModel, PointwiseProvider

Q = np.array([0.0, 0.3, -0.8])


def test_exact_modal_block_on_a_fourier_joint_is_refused(arm):
    """A pointwise provider has no shape joints: the elbow is a Fourier joint of the plant,
    and the exact model's modal block changes with it by ~0.3 (of 1): refused before any
    tabulation, the message naming q3 and the options."""
    provider = PointwiseProvider(arm, Q, count=1)
    model = FlexibleModel(arm, provider, gravity=None, kinematics="exact")
    with pytest.raises(ModelError, match=r"changes with q3 .*modal_mass='first_order'"):
        tabulate_plant(model, cache_dir=False)
