"""Modal quantities over the configuration space: normalisation, tracking, tables."""

from casflex.modal.tables import ModalTable, build_table, shape_joints  # noqa: F401
from casflex.modal.tracking import correlation, mac, track, track_grid  # noqa: F401
