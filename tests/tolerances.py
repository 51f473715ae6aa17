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
