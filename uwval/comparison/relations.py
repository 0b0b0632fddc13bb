"""evo's pose relations and the unit of each error: shared by APE (:mod:`.engine`) and RPE
(:mod:`.rpe`), in a module of their own so that a compare does not load the RPE code."""

from __future__ import annotations

#: evo's pose relations, and the unit of each error.
RELATION_UNITS = {
    "trans_part": "m",
    "rot_part": "none",
    "full": "none",
    "angle_deg": "deg",
    "angle_rad": "rad",
    "point_distance": "m",
    "point_distance_error_ratio": "%",
}
