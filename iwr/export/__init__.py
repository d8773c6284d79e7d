"""Exports of a calibrated robot for the software that drives it (``iwr export``, docs/cli.md):
the hexapod for LinuxCNC ``genhexkins`` (a HAL file), as plain JSON and as a table of leg
corrections over a grid of poses; the carriage as URDF."""

from .hexapod import (
    FRAMES,
    TableWritten,
    data_frame,
    effects_note,
    genhexkins_hal,
    hexapod_dict,
    hexapod_readings,
    interpolation_error,
    leg_correction_table,
    pose_grid,
    write_genhexkins_hal,
    write_hexapod_json,
    write_leg_corrections,
)
from .urdf import BASE_LINK, HEXAPOD_LINK, carriage_urdf, link_names, write_carriage_urdf

__all__ = ["BASE_LINK", "FRAMES", "HEXAPOD_LINK", "TableWritten", "carriage_urdf", "data_frame",
           "effects_note", "genhexkins_hal", "hexapod_dict", "hexapod_readings",
           "interpolation_error", "leg_correction_table", "link_names", "pose_grid",
           "write_carriage_urdf", "write_genhexkins_hal", "write_hexapod_json",
           "write_leg_corrections"]
