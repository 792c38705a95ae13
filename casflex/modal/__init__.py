"""Modal quantities over the configuration space: normalisation, tracking, tables."""

from casflex.modal.integrals import configuration_quantities, quantity_shapes  # noqa: F401
from casflex.modal.normalize import (  # noqa: F401
    mass_normalize,
    modal_mass_matrix,
    modal_stiffness_matrix,
)
from casflex.modal.tables import ModalTable, build_table, shape_joints  # noqa: F401
from casflex.modal.tracking import correlation, mac, track, track_grid  # noqa: F401
