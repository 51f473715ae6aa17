"""The synthetic world: seeded scenes, a numba ray caster, trajectories, and rendered
light fields and camera-array sessions with exact ground truth.

Everything is deterministic given a seed. Radiance is Lambertian and
view-independent, so plenoptic brightness constancy holds exactly. See
docs/conventions.md for frames and units.
"""

from .boardrender import BoardRenderer
from .motion import frame_timestamps, frames_of, make_trajectory, smooth_trajectory, static_trajectory
from .raycast import TraceResult, trace_indexed, trace_outer, trace_rays
from .render import (CameraArrayRenderer, LightFieldRenderer, default_lightfield_grid, lightfield_face_rays,
                     mjpg_frame, quantize, render_lightfield)
from .scenes import (SCENE_NAMES, Scene, SphereGrid, TextureBuilder, Textures, make_scene, room_scene,
                     spheres_scene)
from .sessions import (board_poses, camera_groups, default_board_frames, scene_for_rig, synth_board_session,
                       synth_lightfield, synth_session, trajectory_for_rig, true_cameramodels,
                       write_lightfield_sequence)

__all__ = [
    # scenes
    "SCENE_NAMES", "Scene", "SphereGrid", "Textures", "TextureBuilder",
    "spheres_scene", "room_scene", "make_scene",
    # ray casting
    "trace_rays", "trace_outer", "trace_indexed", "TraceResult",
    # motion
    "frame_timestamps", "static_trajectory", "smooth_trajectory", "make_trajectory", "frames_of",
    # rendering
    "default_lightfield_grid", "lightfield_face_rays", "LightFieldRenderer", "render_lightfield",
    "CameraArrayRenderer", "BoardRenderer", "quantize", "mjpg_frame",
    # products on disk
    "scene_for_rig", "trajectory_for_rig", "true_cameramodels", "board_poses", "camera_groups",
    "default_board_frames", "write_lightfield_sequence", "synth_lightfield", "synth_session", "synth_board_session",
]
