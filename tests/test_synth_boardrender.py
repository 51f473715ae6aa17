"""The fast board-session renderer (polycam.synth.BoardRenderer): the same images as tracing
the whole scene with polycam.synth.CameraArrayRenderer, including boards hidden
behind scene objects and boards leaving the image."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polycam.board import load_board
from polycam.geometry import R_from_r, T_from_Rt
from polycam.rig import load_rig
from polycam.synth import BoardRenderer, CameraArrayRenderer, board_poses, room_scene, true_cameramodels

from test_calib import BOARD, LENS


def _setup(tmp: Path, n_objects: int):
    (tmp / "board.toml").write_text(BOARD)
    board = load_board(tmp / "board.toml")
    lens = f'lens = "{LENS}"\n' if LENS.is_file() else ""
    (tmp / "rig.toml").write_text(f"[rig]\nname = \"t\"\n[defaults]\nwidth = 96\nheight = 72\nfov_deg = 65\n{lens}"
                                  "[grid]\nrows = 1\ncols = 2\npitch = 0.04\n")
    rig = load_rig(tmp / "rig.toml")
    models = true_cameramodels(rig, seed=3, perturb_position_m=0.001, perturb_rotation_deg=0.3)
    scene = room_scene(4.0, seed=3, n_spheres=n_objects, n_boxes=n_objects)
    image, H_image_board = board.render(40, 0.5)
    m = (image.shape[1] - board.cols * 40) / 2.0 / (40 / board.square_length)
    bw, bh = board.size_m
    poses = board_poses(board, models, 4, seed=3, fill=(0.5, 1.5), spread=0.9, min_visible=0.5, tilt_deg=60.0)
    scene, rect = scene.with_image_rect(image, poses[0], (-m, bw + m, -m, bh + m), np.asarray(H_image_board)[:2])
    return rig, models, scene, rect, poses


def test_board_renderer_equals_the_ray_tracer(tmp_path):
    """Close boards (partly outside the views) in the empty room: identical images."""
    rig, models, scene, rect, poses = _setup(tmp_path, 0)
    T_world_rig = np.eye(4)
    fast = BoardRenderer(rig, models, scene, rect, T_world_rig, supersample=2)
    slow = CameraArrayRenderer(rig, models, scene, supersample=2)
    for T in poses:
        a = fast.render(T)
        b = slow.render(T_world_rig, scene.with_rect_pose(rect, T))
        assert 0.0 < fast.mixed_fraction < 0.1            # only the board's outline is traced
        for cam in a:
            np.testing.assert_array_equal(a[cam], b[cam])


def test_board_renderer_behind_objects_and_moved_rig(tmp_path):
    """Boards far away among the room's objects (one hidden behind them), seen from a moved rig: identical."""
    rig, models, scene, rect, poses = _setup(tmp_path, 5)
    T_world_rig = T_from_Rt(R_from_r(np.array([0.02, -0.05, 0.01])), np.array([0.1, -0.05, 0.2]))
    fast = BoardRenderer(rig, models, scene, rect, T_world_rig, supersample=2)
    slow = CameraArrayRenderer(rig, models, scene, supersample=2)
    for k in range(3):
        T = T_from_Rt(R_from_r(np.array([0.3, 0.2 * k, 0.1])), np.array([-0.8 + 0.4 * k, -0.6, 2.5 + 0.5 * k]))
        a = fast.render(T)
        b = slow.render(T_world_rig, scene.with_rect_pose(rect, T))
        for cam in a:
            np.testing.assert_array_equal(a[cam], b[cam])
