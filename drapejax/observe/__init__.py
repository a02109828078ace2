"""Observations of a drape: hard and soft renderers, descriptors, comparison metrics and the
observation types (``types``: one class per kind of observation, found through ``REGISTRY``)."""

from .descriptors import (
    HEIGHT_THRESHOLDS_MM,
    describe,
    describe_mesh,
    drape_coefficient,
    fold_amplitudes,
    fold_count,
    fold_peaks,
    hem_heights_from_height_map,
    inspect,
    projected_area_m2,
    rim_spectrum,
)
from .metrics import (
    align_rotation_z,
    aligned_iou,
    dc_difference,
    iou,
    mean_abs_curvature,
    mean_curvature,
    mean_relative_curvature_difference,
    mean_vertex_displacement_mm,
    relative_curvature_level_difference,
    rotate_about_axis,
    rotate_image,
    sample_surface,
    scan_distance_mm,
    spectral_distance,
)
from .render import (
    CAMERA_DISTANCE_M,
    EXTENT_M,
    boundary_curve,
    boundary_loops,
    depth_views,
    height_map,
    pixel_centres,
    point_cloud_mesh,
    point_cloud_views,
    rasterize_max,
    rim_profile,
    silhouette,
    view_axes,
)
from .soft import soft_depth_views, soft_height_map, soft_rim_profile, soft_silhouette
from .types import REGISTRY, AbstractObservation, CoreObservation, HeightMap, Silhouette, WarpHarmonic, register

__all__ = [
    "HEIGHT_THRESHOLDS_MM", "describe", "describe_mesh", "drape_coefficient", "fold_amplitudes",
    "fold_count", "fold_peaks", "hem_heights_from_height_map", "inspect", "projected_area_m2",
    "rim_spectrum", "align_rotation_z", "aligned_iou", "dc_difference", "iou", "mean_curvature",
    "mean_abs_curvature", "relative_curvature_level_difference",
    "mean_relative_curvature_difference", "mean_vertex_displacement_mm", "rotate_image",
    "rotate_about_axis", "sample_surface", "scan_distance_mm", "spectral_distance",
    "CAMERA_DISTANCE_M", "EXTENT_M", "boundary_curve", "boundary_loops", "depth_views",
    "height_map", "pixel_centres", "point_cloud_mesh", "point_cloud_views", "rasterize_max", "rim_profile",
    "silhouette", "view_axes",
    "soft_depth_views", "soft_height_map", "soft_rim_profile", "soft_silhouette",
    "REGISTRY", "AbstractObservation", "CoreObservation", "HeightMap", "Silhouette", "WarpHarmonic", "register",
]
