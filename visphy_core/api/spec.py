"""Scene specifications, for dataset, engine, model and metric plugins: the 2D and 3D spec
schemas with their geometry helpers (`visphy_core.spec.spec2d`, `visphy_core.spec.spec3d`) and
the replay payloads the reference programs draw from (`visphy_core.spec.replay`)."""

from __future__ import annotations

from visphy_core.spec.replay import fill, payload_from, replay_payload
from visphy_core.spec.spec2d import (
    CATEGORIES,
    PHYRE_PROFILE,
    WALL_IDS,
    category_of,
    local_polygons,
    shape_area_centroid,
    transform_points,
    validate_spec,
)
from visphy_core.spec.spec3d import (
    FLOOR_ID,
    IDENTITY_QUAT,
    PROFILE_3D,
    PROFILE_NAME,
    RED_RGB,
    body_mass,
    bounding_radius,
    box_corners,
    category_of_3d,
    local_hull_points,
    primitive_volume,
    quat_from_axis_angle,
    quat_to_matrix,
    shape_parts,
    transform_points_3d,
    validate_spec_3d,
    wedge_vertices,
)
from visphy_core.spec.validation import contact_table

__all__ = [
    "body_mass", "bounding_radius", "box_corners", "CATEGORIES", "category_of", "category_of_3d",
    "contact_table", "fill", "FLOOR_ID", "IDENTITY_QUAT", "local_hull_points", "local_polygons",
    "payload_from", "PHYRE_PROFILE", "primitive_volume", "PROFILE_3D", "PROFILE_NAME",
    "quat_from_axis_angle", "quat_to_matrix", "RED_RGB", "replay_payload", "shape_area_centroid",
    "shape_parts", "transform_points", "transform_points_3d", "validate_spec", "validate_spec_3d",
    "WALL_IDS", "wedge_vertices",
]
