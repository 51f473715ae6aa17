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
# plenoptic motion (tests/test_motion.py, analytic light fields, tiny grids)
MOTION_PURE_REL = 0.01        # relative error of the moving component of a pure motion
MOTION_PURE_LEAK = 0.05       # leakage into the other components, as a fraction of the step size
MOTION_COMBINED_REL = 0.02    # relative error per component of a combined motion, six faces
MOTION_COMBINED_REL_ONE_FACE = 0.06  # the same with one to three faces (t / ω coupling, narrow baseline)
MOTION_EXTRAPOLATION_ATOL = 5e-4  # Eq. 6 extrapolation of a textured plane's light field beyond the views (values 0.3-0.7; measured 5e-5, wrong-sign disparity 2e-2)
MOTION_DEPTH_VIEWS_ATOL = 2e-4  # warp blending the views along the disparity vs the moved plane's light field, 1.8 samples per view step (values 0.2-0.8; measured 1e-5, the plain blend 0.027)
MOTION_DEPTH_VIEWS_FAST_ATOL = 5e-3  # vectorised vs per-ray blend along the disparity, 0.23 deg rotation (the shift taken at the central view; measured max 2.8e-3, RMS 4.8e-4; the plain blend 0.027)
MOTION_DEPTH_VIEWS_FAST_RMS = 1e-3
MOTION_DEPTH_VIEWS_EXTRAPOLATION_ATOL = 1e-3  # Eq. 6 extrapolation with the blend along the edge along the disparity, aliased plane (measured 3.2e-4: 4-point shifts; the plain blend along the edge 0.019)
MOTION_DEPTH_VIEWS_SOLVE_GAIN = 1.5  # translation error without / with depth_views, textured plane at 1.8 samples per view step (measured 2.3)
MOTION_NOISE_EXTRAPOLATION_REL = 0.03  # |mean t-hat.t/|t|^2 - 1| over 4 draws, 6 faces 16x16 dirs, 1.6-view motion, noise 0.01 (measured 0.0075)
MOTION_SPHERES_REL = 0.05     # relative error per component with occluding spheres
MOTION_COV_RATIO_MIN = 0.4    # empirical std / predicted std under noise (10 seeds; measured 0.54-1.3)
MOTION_COV_RATIO_MAX = 2.0
MOTION_COV_RMS_MAX = 1.05     # RMS over axes and 12 draws of error / reported std, the room on six faces of 16 x 16 directions under noise 0.01 (measured 0.95 with 8-sample clusters and their jackknife, session 57; 1.12 with the 4-sample tiles as clusters, 1.25 without the jackknife too, session 56)
MOTION_COV_RMS_MIN = 0.8      # the same from below: the std not grossly conservative
MOTION_COV_RMS_MAX_IRLS = 1.35  # the same without the jackknife and with the IRLS weights' normal matrix in the sandwich (measured 1.45, the solver before session 56)
MOTION_JACKKNIFE_RTOL = 1e-10  # the tiles' leverage-scaled sandwich vs the brute-force leave-one-tile-out variance (float64 algebra; measured 1e-15)
MOTION_SLOPE_SUMS_RTOL = 1e-4  # the slope pass's normal sums (float32 per-ray arithmetic) vs numpy's Σ base ψ'(r) c cᵀ
MOTION_ARRAY_NOISE_STD_RATIO_MIN = 1.5   # errors / the residuals' (noise) std, resampled 3x3 rig of 64x48 px, 8 pairs (measured 1.77 / 1.65 with session 57's tile jackknife, 1.9 / 1.8 with session 56's ψ' sensitivity alone, 3.3 / 2.9 before: model error they do not show)
MOTION_ARRAY_STD_RATIO = (0.4, 2.0)    # errors / the reported std (noise + level change) there (measured 1.00 / 1.02 since session 57; 1.02 / 1.11 in session 56, 0.98 / 1.16 before)
DERIV_LINEAR_ATOL = 1e-4      # derivative of a linear light field (relative to its slope)
DERIV_SINE_REL_FS5 = 0.01     # fs5 derivative of a 0.5 rad/sample sinusoid, relative
MOTION_MODEL_WEIGHT_ATOL = 0.02  # model-validity weight in a patch of 3 s model error vs s² / (s² + 8.5 s²) (pooled noise: ~±0.01)
MOTION_MODEL_BUMP_GAIN = 0.6   # error with / without model_weight, model-error bump (measured 0.47)
MOTION_DEPTH_MEDIAN_REL = 0.02  # median relative depth error (Eq. 6-7) on confident rays, room sphere
FILTER_GAIN_ATOL = 1e-12     # derivative_gain of a filter pair vs its closed form
LINEAR_RHO_FS3_BIAS_MIN = 0.025  # median ρ̂ / ρ - 1 of a linear array without the gain, sinusoid of 1 rad/sample seen 0.72 samples apart view to view (fs3 / fs5 predicts 4.0 %)
LINEAR_RHO_GAIN_ATOL = 0.003  # median ρ̂ / ρ vs its prediction (fs3 / fs5 without the gain, 1 / fs5 with it) on that sinusoid
LINEAR_RHO_INT16_RTOL = 1e-4  # the solver's int16 ρ̂ divided by the gain (table, re-quantised) vs the float division (1 / 32767 of a view's max, R tabled to 1e-6)
# capture (tests/test_capture_*.py)
CAPTURE_JITTER_STD_REL = 0.15  # measured timestamp-jitter std of the mock vs [mock] jitter_ms (1200 draws)
CAPTURE_TIME_DRAW_STD_REL = 0.12  # std of capture_time_draw (30 sessions x 10 draws) vs the estimate's error over 300 jitter realisations, per kind of camera and place in the session (measured within 0.05; one std per camera: 0.65 at a slower camera's ends)
# calibration (tests/test_calib*.py; small rendered / synthetic board sessions)
CALIB_RENDERED_RMS_PX = 0.25          # [px] mrcal RMS residual on a rendered 320x240 board session
CALIB_RENDERED_POSITION_M = 0.002     # [m] solved vs true camera centres after a rigid alignment (8 board poses)
CALIB_RENDERED_ROTATION_DEG = 0.2     # [deg] solved vs true camera orientations after the same alignment
CALIB_RENDERED_PROJECTION_PX = 0.1    # [px] RMS mrcal.projection_diff (implied-rotation fit) vs the true model at the board distance (measured 0.025-0.071 pinhole, 0.008-0.024 real lens)
CALIB_EXACT_POSITION_M = 1e-5         # [m] noise-free synthetic observations: recovered centres
CALIB_EXACT_ROTATION_DEG = 1e-3       # [deg] noise-free: recovered orientations
CALIB_EXACT_REPROJ_PX = 1e-3          # [px] noise-free: RMS residual
CALIB_EXACT_PROJECTION_PX = 0.01      # [px] noise-free: RMS projection difference (no fit) inside the observed area
CALIB_MODEL_ROUNDTRIP_ATOL = 1e-9     # intrinsics / rt after a file or format round trip (relative to 1)
CALIB_COLMAP_TEXT_ATOL = 1e-8         # COLMAP text written with 12-15 significant digits
CALIB_RAY_REPROJ_PX = 1e-6            # [px] projecting o + s d of a pixel's ray back into its camera
CALIB_COLMAP_POSITION_M = 0.005       # [m] COLMAP target-free: camera centres vs truth (2x2 rig, 6 cm pitch)
CALIB_COLMAP_FOCAL_REL = 0.02         # COLMAP target-free: relative focal-length error
CALIB_SPLINED_POSITION_M = 0.005     # [m] noise-free but regularised splined solve (3 cameras, 18 poses): centres
# resampling (tests/test_resample*.py)
RESAMPLE_PUSHPULL_ATOL = 1e-5     # numba pull-push vs the numpy reference (float32, other summation order)
RESAMPLE_CONSTANT_ATOL = 1e-5     # a constant scene resampled (intensity units)
RESAMPLE_LINEAR_ATOL = 2e-5       # a light field linear in (x, y, u, v) where covered and the fit is determined (range ~0.3; float32)
RESAMPLE_DIRECT_PSNR_DB = 30.0    # [dB] irregular 3x3 rig (64x48 px) vs the grid rendered directly, at camera viewpoints where W > 0.5
RESAMPLE_MIDVIEW_PSNR_DB = 50.0   # [dB] a view half-way between cameras vs the mean of its two resampled neighbours
RESAMPLE_VIEWFILL_RMS = 0.01      # depth-aware view fill: RMS error of the views between cameras of a textured plane (range ~0.7; measured 0.0044, the depth-free blend 0.053)
RESAMPLE_VIEWFILL_DISPARITY_ATOL = 0.1  # [u-steps per x-step] median disparity the sweep finds on that plane (measured 0.036 off: sub-step parabola bias)
# end to end (tests/test_end_to_end.py)
E2E_STREAM_VS_STORE_ATOL = 1e-6   # on-the-fly resampling vs the same frame read back from a store (float32)
E2E_SMALL_RIG_MOTION_REL = 0.3    # median relative per-pair motion error, 3x3 rig of 64x48 px, 3 frames (measured 18%: tiny images; a sanity bound)
E2E_RUN_MOTION_REL = 0.6          # median relative per-pair error of `polycam run` on the tests' small rigs of 160x120 px, 12 board frames (session 42: 3x3 6.6% translation, centres 2.7 mm off, 33% before the corner refinement; a row of three 29%, centres 4.7 mm off; 6% with the true models)
# rig design study (tests/test_design.py)
DESIGN_RENDER_ATOL = 1e-6         # design renderer vs polycam.synth.render_lightfield on the same rays (float32)
DESIGN_LINEAR_SIGMA_REL = 0.15    # analytic noise propagation vs Monte Carlo of the same linear estimator (400 draws)
DESIGN_SCATTER_REL = 0.2          # predicted σ (and whitened covariance) vs the real solver's scatter over 32 noise draws (issue 8)
DESIGN_AMBIGUITY_MIN_CORR = 0.7   # |corr(t_i, w_j)| of a small-FOV array's reported rotation-translation ambiguity
E2E_DEMO_MOTION_REL = 0.25        # median relative per-pair error of `polycam demo` (mock5x5, calibrated models, room; measured 5.5% / 0.5%, session 1: 10.8% / 4.9%)
# HCI real light field (tests/test_hci.py; antinous, 8x8 pixel blocks)
HCI_SHIFT_T_ABS = 0.01            # [view spacings] |t − (1, 0, 0)| of the one-view shift along x (issue #3 target: 1%; measured ~1e-6)
HCI_SHIFT_R_MAX_RAD = 1e-4        # [rad] |r| of the same (true rotation 0; measured ~4e-9)
# depth and scale selection (tests/test_depth.py)
DEPTH_PLANE_MEDIAN_REL = 0.01     # median relative depth error on a textured fronto-parallel plane (kept rays)
DEPTH_LINEAR_PLANE_MEDIAN_REL = 0.003  # the same on a linear array (views 2 mm apart, the motion equations weigh in): measured 0.0008-0.0019 with the directional motion equation, 0.0037-0.0056 had the positional one (L_x read as 0) stayed
DEPTH_REFINED_PLANE_MEDIAN_REL = 0.005  # median relative depth error of refine_depth on a textured plane, views 1.2-3 samples of disparity apart (measured 0.0015-0.0038; Eq. 7 there 2.4-10 %)
DEPTH_SPHERES_MEDIAN_REL = 0.2    # median |range / traced - 1| of the confident half, unit spheres at 4 m, one face 5x5x48x48, single scale (measured 0.089: aliased directions; selected per face 0.066)
DEPTH_NEAR_SELECTED_REL = 0.03    # near plane with viewpoint-aliased texture: error at the selected scale (single scale ~12%)
DEPTH_BOUNDARY_BLED_MAX = 0.005   # fraction of the kept central-view rays > 25 % off, a textured half-plane before a textured plane (measured 0; 4.4 % ranked by Σa² x consistency)
DEPTH_CONFIDENCE_SPREAD_MAX = 1.6   # robust spread of (Z / Z_true − 1) √confidence on a noisy plane, within [1/1.6, 1.6] of 1 (measured 1.15–1.31 at σ = 0.005–0.05)
DEPTH_PNG_ATOL_M = 0.0005         # [m] 16-bit millimetre PNG vs the float depth (rounding)
DEPTH_PLY_ATOL = 1e-5             # [m] PLY coordinates (ASCII %.5f, binary float32) vs the points written
E2E_RUN_PAIR_DEPTH_REL = 0.3      # the same on a stereo pair of 160x120 px 5 cm apart (12 board frames), its middle view refined on the two cameras (measured 0.21, session 42; 0.17 before the corner refinement: the 2-camera calibration is 0.6-1.2 deg off; 0.076 with 25 board frames)
E2E_RUN_DEPTH_REL = 0.6           # median relative depth error vs the ray tracer, `polycam run` on the 160x120 test rigs (session 42: 3x3 6.0%, a row of three 25%: calibrations 2.7 / 4.7 mm off; the 3x3 37% before the corner refinement)
CALIB_UNCERTAINTY_DRAWS = 8           # noise draws comparing calib.extrinsics_uncertainty with the measured scatter
CALIB_CORNER_DRIFT_PX = 0.002        # [px per corner column] outward drift of the refined ChArUco corners (the test session: refined 0.0003, OpenCV's own 0.0039; the demo's views 0.016)
CALIB_REFINED_CORNER_GAIN = 0.9      # refined corners' RMS error against OpenCV's own (the test session: 0.171 against 0.229 px; the demo's views 0.113 against 0.151)
CALIB_DRAWS_FACTOR_REL = 1e-8        # L Lᵀ against the calibration covariance it factors (calib.draws.covariance_factor)
CALIB_UNCERTAINTY_RATIO = 1.6         # allowed factor between measured RMS pose error and mrcal's predicted sigma (8 draws x 2 cameras)
CALIB_SPLINED_BUNDLE_DEG = 0.01       # [deg] noise-free splined solve: spread of the per-camera rig-frame ray-bundle rotations vs truth
CALIB_SPLINED_RIG_DEG = 1.0           # [deg] the same bundles' common rotation (rig frame from the bundles' orientations; was 3.1 deg from the raw extrinsics)
MOTION_NORMAL_SUMS_RTOL = 1e-6  # fused-kernel normal matrix AᵀWA vs the numpy float64 coefficient matrix (float32 per-ray products and 16-ray sums: measured ~1e-7)
MOTION_SOLVE_RTOL = 1e-6        # solve_ray_motion (Jacobi-scaled eigen pseudo-inverse) vs np.linalg.solve of the same normal equations
CALIB_TRUTH_RESIDUAL_PX = 1e-6        # [px] residuals of calib.truth_problem (the exact projections at the true parameters)
CALIB_PREDICT_REL = 0.1               # predicted pose sigma at the truth vs at a noisy solve of the same poses (0.2 px)
VIEW_DISPARITY_REL = 0.1         # view_disparity of a textured plane vs Δx f / (Z Δu) (measured 0.1-8 %)
VIEW_DISPARITY_NOISY_REL = 0.3   # the same under 32 grey levels of noise, gated (measured +15 %; noise-free +10 %)
MOTION_WHITEN_GLS_RTOL = 1e-6   # whitened (banded Cholesky per axis) normal sums vs dense Aᵀ W^½ Σ⁻¹ W^½ A (measured 1.4e-7: the rows are float32; 2e-9 in float64)
MOTION_NOISE_WEIGHT_KEEP = 0.97  # share of pure-noise rays the noise-aware discontinuity weight keeps above 0.5 (99% quantile subtracted)
MOTION_WHITEN_VS_PLAIN = 2.0    # |error| of the whitened (GLS) estimate / the plain one, 7x7-view six-face test under noise (one draw)
MOTION_DEPTH_REGRESSOR_GAIN = 0.6  # RMS error of the Eq. 6 regressor ρ̂ L_u / that of the measured L_x vs the noise-free L_x (σ = 0.02, one face; measured 0.44)
MOTION_WARP_TAPS_GAIN = 0.5     # max warp error of a band-limited pattern with uv_taps n + 2 / with n (measured 0.37 for 4 → 6 rising to 0.43 for 14 → 16)
MOTION_DEPTH_RHO_DENOISED = 0.03  # |mean ρ̂ / ρ − 1| with L_u noise of a quarter of its signal energy, ρ̂ denominator less the noise (measured +0.006; uncorrected −0.21)
MOTION_DEPTH_RHO_RTOL = 1e-5     # ρ̂ L_u of the Eq. 6 kernel (depth_rho) vs the numpy depth_regularise, relative to max |L_x| (float32 sums; measured 3e-7)
MOTION_DEPTH_POOL_GAIN = 0.9     # RMS error of the Eq. 6 regressors with ρ̂ pooled over the views / without (9 x 9 views, noise 0.05; measured 0.81)
MOTION_DEPTH_RHO_POOLED_RTOL = 1e-4  # the same with ρ̂ pooled over the views (the kernel pools its int16 ρ̂: 1.5e-5 of each view's max; measured 2e-5)
MOTION_DEPTH_RHO_FLIPS = 1e-3    # share of valid rays whose keep / replace decision differs between the two (threshold ties in float32; measured 0)
MOTION_W_LAG_REL = 1e-5        # estimate with the solver's lagged confidences W (re-warps keep the warped W) vs fresh ones, relative to each component of the motion (random 0.5 / 1 W; measured 7e-7)
MOTION_W_PAIR_REL = 5e-4       # estimate with W0 W1 at each ray's own sample vs W1 warped, relative to each component (random 0.5 / 1 W, one face; measured 4.9e-5, six faces 2e-6)
MOTION_WARP_SOURCE_UNITS = 1.0   # warp of the int16 warp source vs the float32 warp, in source units (half a unit x the stencil gain, <= 1.93 for 6 x 6 Lagrange taps; measured 0.48)
MOTION_SCALED_VIEWS_RTOL = 1.6e-5  # int16 scaled views (polycam.eq5): rounding error relative to the view's max |value| (half a step of 1/32767, plus float32 rounding)
MOTION_INT16_WEIGHTS_REL = 1e-4  # normal sums with int16 base weights (units of 1/32767) vs float32 weights, relative to the largest |sum| (measured: see the test)
RESAMPLE_VIEWFILL_OFFGRID_GAIN = 2.0   # view fill from cameras ~0.15 view steps off their views (textured plane): RMS error with offsets from the grid indices / from the camera centres, at least (measured 0.0142 / 0.0046 = 3.1)
RESAMPLE_ROW_ACROSS_GAIN = 1.5     # a row of cameras re-centred along the row only / across it too: RMS of the camera views (textured plane, 0.15-step offsets; measured 0.0099 / 0.0049 = 2.0)
MOTION_NOISE_SIGMA_REL = 0.05  # sensor-noise sigma from second differences of 3x3 or 5x5 cameras x 32x32 directions (two frames; 0.5-1.5 % expected)
DERIV_NOISE_VAR_REL = 0.05     # predicted vs measured variance of the derivatives of white noise (9x9x64x64 per frame; measured within 1.6 %)
# ρ̂ pooled over the views (tests/test_rho_pool.py, synthetic ρ fields)
RHO_POOL_GAIN_MAX = 0.1        # median share g of a ray's own ρ̂ kept where 49 views see one depth through noise 1.5x ρ
RHO_POOL_VAR_REL = 0.25        # |mean reported var(ρ̃) / mean squared error − 1| (measured 0.18: τ²'s own noise is not counted)
RHO_POOL_KEEP_REL = 0.5        # RMS change of ρ̂ where the views see different depths, in units of its noise
RHO_POOL_VAR_CORRELATED_REL = 0.5  # the same with noise shared by 3 x 3 neighbouring views (measured 0.32: q underestimates)

# plenoptic sampling: the finest level the motion solver uses (tests/test_motion.py)
MOTION_VIEW_DISPARITY_RTOL = 0.25  # measured disparity per view step against f Δx / (Z Δu) over the centre view (measured +10 %)

# a camera image's sensor noise from the image alone (tests/test_image_noise.py, 8-bit)
IMAGE_NOISE_RTOL = 0.05        # estimate vs √(σ² + 1/12) grey levels, rendered 320x240 images, σ ≥ 2 (measured within 2.5 %; the
                               # cube's clipped test image −3.6 %, −7.5 % without leaving the clipped blocks out)
IMAGE_NOISE_LOW_RTOL = 0.2     # the same at σ = 1, where the chosen blocks' weak texture adds (measured +1 to +9 %; 160x120 room
                               # cameras +16 %); a session's 160x120 cameras at σ = 2 and its resampled samples' noise, predicted vs measured
IMAGE_NOISE_REAL_RTOL = 0.06   # real photos with σ = 2, 4 added: estimate vs √(σ0² + σ²) (measured within 1.6 %; 4.2 % at σ = 1)
