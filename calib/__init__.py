"""Calibration stage: mrcal board calibration and COLMAP target-free calibration of a
camera array into rig-frame cameramodels (``rt_cam_ref = T_cam_rig``), their reports,
exports and per-pixel rays. See docs/calibration.md.

Heavy dependencies (mrcal, OpenCV, pycolmap) are imported inside the functions.
"""

from .align import RigFit, fit_rig_frame, fit_similarity, rotation_angle
from .board_solve import (LENSMODEL_CHOICES, BoardCalibration, CameraStats, board_distance, board_rms_px,
                          calibrate_board, camera_graph, extrinsics_uncertainty, lens_rotation, lensmodel_name,
                          observation_residuals, state_covariance, uncertainty_grid, valid_region_contour)
from .colmap import ColmapCalibration, calibrate_colmap, reconstruct_images, write_colmap_report
from .colmap_text import (ColmapCamera, ColmapImage, colmap_to_mrcal, import_colmap_text, mrcal_to_colmap,
                          read_colmap_text, rig_config, write_colmap_text, write_rig_config)
from .detect import SKIP_REASONS, BoardObservations, Detection, detect_board, detect_session, sharpness
from .export import opencv_intrinsics, read_opencv_yaml, write_colmap_rig, write_kalibr_camchain, write_opencv_yaml
from .io import load_models, prepare_output_dir, write_cameramodel, write_corners_vnl, write_models
from .pipeline import EXPORT_FORMATS, METHODS, CalibrationRun, calibrate_session, export_calibration
from .rays import pixel_rays, read_ray_table, rig_rays, write_ray_table
from .synthetic import coverage_poses, predicted_extrinsics_sigma, project_board, synthetic_observations, truth_problem

__all__ = [
    # detection
    "SKIP_REASONS", "Detection", "BoardObservations", "detect_board", "detect_session", "sharpness",
    # mrcal board solve
    "LENSMODEL_CHOICES", "lensmodel_name", "camera_graph", "BoardCalibration", "CameraStats", "calibrate_board",
    "observation_residuals", "board_distance", "extrinsics_uncertainty", "state_covariance", "board_rms_px", "lens_rotation", "uncertainty_grid", "valid_region_contour",
    # rig frame
    "RigFit", "fit_rig_frame", "fit_similarity", "rotation_angle",
    # COLMAP target-free calibration
    "ColmapCalibration", "calibrate_colmap", "reconstruct_images", "write_colmap_report",
    # COLMAP text models and rig configs
    "ColmapCamera", "ColmapImage", "read_colmap_text", "colmap_to_mrcal", "mrcal_to_colmap", "import_colmap_text",
    "write_colmap_text", "rig_config", "write_rig_config",
    # exports
    "write_colmap_rig", "write_kalibr_camchain", "write_opencv_yaml", "read_opencv_yaml", "opencv_intrinsics",
    # files
    "prepare_output_dir", "write_cameramodel", "write_models", "load_models", "write_corners_vnl",
    # rays
    "pixel_rays", "rig_rays", "write_ray_table", "read_ray_table",
    # synthetic ground truth
    "synthetic_observations", "project_board", "coverage_poses", "truth_problem", "predicted_extrinsics_sigma",
    # the whole stage
    "METHODS", "EXPORT_FORMATS", "CalibrationRun", "calibrate_session", "export_calibration",
]
