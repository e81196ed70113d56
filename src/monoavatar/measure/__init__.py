"""measure stage: tailor's measurements (girths, lengths) of a rest-pose body mesh, on the body
model under the clothes and on the clothed surface. Metres in, metres out."""

from monoavatar.measure.measurements import (
    MEASUREMENTS,
    PARTS,
    Measurement,
    MeasureSettings,
    Slicer,
    body_frame,
    body_under_clothes,
    face_parts,
    measure_mesh,
    transfer_parts,
    vertex_parts,
)
from monoavatar.measure.slicing import Section, girth, plane_basis, plane_section, vertical_hits

__all__ = [
    "MEASUREMENTS",
    "PARTS",
    "MeasureSettings",
    "Measurement",
    "Section",
    "Slicer",
    "body_frame",
    "body_under_clothes",
    "face_parts",
    "girth",
    "measure_mesh",
    "plane_basis",
    "plane_section",
    "transfer_parts",
    "vertex_parts",
    "vertical_hits",
]
