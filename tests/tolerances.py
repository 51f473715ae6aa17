"""Every numeric tolerance the tests use, in one place (kornia's testing/base.py idea).

Each name says what is compared and in which unit.
"""

GEOMETRY_ATOL = 1e-9          # rotations / transforms round trips (dimensionless, m)
TUM_POSITION_ATOL = 1e-8      # [m] after a TUM write/read round trip (9 decimals written)
TUM_ROTATION_ATOL = 1e-8      # rotation-matrix entries after a TUM round trip
LIGHTFIELD_ATOL = 0.0         # store round trip of float32 samples is exact
RENDER_PROJECTION_PX = 0.05   # [px] mrcal.project of a rendered hit vs the pixel it came from
BOARD_POINTS_ATOL = 1e-7      # [m] Board.object_points vs OpenCV's float32 getChessboardCorners
BOARD_CORNER_PX = 0.05        # [px] detected corner in a rendered board vs its H_image_board mapping
GRID_RAY_ATOL = 1e-12         # ray origins [m] / unit directions of LightFieldGrid vs closed form
RENDER_SHIFT_ATOL = 0.0       # light field after an exact one-sample translation vs the shifted samples (exact)
RENDER_CONSTANCY_ATOL = 1e-5  # radiance of one world ray traced from two rig poses (float32 directions)
RENDER_SUPERSAMPLE_ATOL = 1e-6  # k x k supersampled sample vs the mean of k^2 shifted renders
SYNTH_BACKGROUND_MAX = 0.03   # fraction of sky seen on any cube face of the spheres scene
SYNTH_STEP_RTOL = 1e-9        # RMS per-frame step of a smooth trajectory vs the requested step
SYNTH_BOARD_CORNER_MAX_PX = 0.75  # [px] worst ChArUco corner detected in a rendered 480x360 view vs mrcal.project
SYNTH_BOARD_CORNER_RMS_PX = 0.35  # [px] RMS of the same
SYNTH_BOARD_DETECTED_MIN = 0.75   # fraction of the board's corners detected in each rendered view
