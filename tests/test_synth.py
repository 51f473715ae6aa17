"""The synthetic world (polycam.synth): determinism, agreement with mrcal and the
light-field geometry, brightness constancy, scene coverage, board detectability,
and the files the session / light-field writers produce."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from polycam.cameras import T_rig_cam_of, camera_rays, pixel_grid
from polycam.geometry import T_from_Rt, T_from_rt, T_inverse, r_from_R
from polycam.lightfield import Axis, LightFieldGrid
from polycam.rays import RayBundle
from polycam.rig import load_rig
from polycam.synth import (CameraArrayRenderer, SphereGrid, board_poses, default_lightfield_grid,
                           lightfield_face_rays, make_trajectory, quantize, render_lightfield, room_scene,
                           smooth_trajectory, spheres_scene, static_trajectory, synth_board_session,
                           synth_lightfield, synth_session, trace_outer, trace_rays, true_cameramodels)
from polycam.trajectory import read_tum

from conftest import mock_grid_rig_text, shared_data
from tolerances import (MOTION_NOISE_SIGMA_REL, RENDER_CONSTANCY_ATOL, RENDER_PROJECTION_PX, RENDER_SHIFT_ATOL,
                        RENDER_SUPERSAMPLE_ATOL, SYNTH_BACKGROUND_MAX, SYNTH_BOARD_CORNER_MAX_PX,
                        SYNTH_BOARD_CORNER_RMS_PX, SYNTH_BOARD_DETECTED_MIN, SYNTH_STEP_RTOL)

BOARD_TOML = """[board]
type = "charuco"
squares = [5, 7]
square_length = 0.04
marker_length = 0.03
dictionary = "DICT_5X5_100"
"""


def _rig_file(tmp_path: Path, body: str, name: str = "rig.toml") -> Path:
    p = tmp_path / name
    p.write_text(body)
    return p


def _small_rig(tmp_path: Path, width=32, height=24, lens: Path | None = None, extra: str = ""):
    lens_line = f'lens = "{lens}"\n' if lens is not None else ""
    return load_rig(_rig_file(tmp_path, f"""[rig]
name = "tiny"
[defaults]
driver = "mock"
width = {width}
height = {height}
fps = 30
fov_deg = 70
{lens_line}
[[camera]]
id = "cam00"
position = [0.0, 0.0, 0.0]
[[camera]]
id = "cam01"
position = [0.05, 0.01, 0.0]
rotation = [0.0, 0.3, 0.05]
{extra}"""))


def _tiny_grid(faces=("+z",), n_uv=8, fov_half=30.0) -> LightFieldGrid:
    # Power-of-two x/y spacing: rig translations by one step are exact in binary.
    xy = Axis(-0.5, 0.5, 5)
    du = 2 * fov_half / n_uv
    uv = Axis(-fov_half + du / 2, fov_half - du / 2, n_uv)
    return LightFieldGrid.cube(list(faces), f=60.0, z_pi=0.5, x=xy, y=xy, u=uv, v=uv)


# ----------------------------------------------------------------------------- scenes, determinism


def test_scene_builders_are_seeded():
    a, b, c = spheres_scene(6.0, seed=4), spheres_scene(6.0, seed=4), spheres_scene(6.0, seed=5)
    for name in ("sphere_centres", "sphere_texture"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.textures.waves, b.textures.waves)
    assert not np.array_equal(a.sphere_centres[:10], c.sphere_centres[:10])
    r1, r2, r3 = room_scene(4.0, seed=1), room_scene(4.0, seed=1), room_scene(4.0, seed=2)
    np.testing.assert_array_equal(r1.box_lo, r2.box_lo)
    np.testing.assert_array_equal(r1.textures.waves, r2.textures.waves)
    assert not np.array_equal(r1.textures.waves, r3.textures.waves)


def test_spheres_start_at_distance():
    D = 5.0
    sc = spheres_scene(D, seed=0)
    near = np.linalg.norm(sc.sphere_centres, axis=1) - sc.sphere_radii
    assert near.min() >= D - 1e-9
    fwd = spheres_scene(D, seed=0, faces="forward")
    cosang = fwd.sphere_centres[:, 2] / np.linalg.norm(fwd.sphere_centres, axis=1)
    assert cosang.min() >= math.cos(math.radians(70.0)) - 1e-12


def test_spheres_too_far_for_the_horizon_is_one_line(tmp_path):
    """Unit spheres filling the horizon grow as the distance squared: 2000 m would need ~8e7 of them
    (the command ran for hours); beyond MAX_SPHERES it is an InputError naming the distance that fits,
    and `polycam synth lightfield` says so in one line, exit 1, nothing written."""
    import subprocess
    import sys

    from polycam.errors import InputError
    from polycam.synth.scenes import MAX_SPHERES

    with pytest.raises(InputError, match=r"2000 m needs .*at most 1,000,000: a distance up to about 22\d m"):
        spheres_scene(2000.0)
    assert len(spheres_scene(200.0, faces="forward").sphere_radii) < MAX_SPHERES     # the forward cone fits
    out = tmp_path / "far.zarr"
    res = subprocess.run([sys.executable, "-m", "polycam.cli", "synth", "lightfield", "--distance", "2000",
                          "--faces", "+z", "--frames", "2", "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 1 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "2000 m needs" in res.stderr and not out.exists() and not Path(str(out) + ".partial").exists()


def test_session_is_deterministic(tmp_path):
    rig = _small_rig(tmp_path, extra='[mock]\nscene = "room"\nnoise = 0.01\n')
    kw = dict(frames=2, supersample=1, perturb_position_m=0.001, perturb_rotation_deg=0.1,
              perturb_focal_frac=0.01)
    synth_session(rig, tmp_path / "a", seed=7, **kw)
    synth_session(rig, tmp_path / "b", seed=7, **kw)
    synth_session(rig, tmp_path / "c", seed=8, **kw)

    def pngs(d):
        return {p.relative_to(d): p.read_bytes() for p in sorted(d.rglob("*.png"))}

    a, b, c = pngs(tmp_path / "a"), pngs(tmp_path / "b"), pngs(tmp_path / "c")
    assert len(a) == 4 and a == b
    assert (tmp_path / "a" / "groundtruth.tum").read_text() == (tmp_path / "b" / "groundtruth.tum").read_text()
    assert [a[k] != c[k] for k in a] == [True] * 4


# ----------------------------------------------------------------------------- ray caster


def test_grid_traversal_matches_brute_force(rng):
    """The uniform-grid DDA finds exactly the hits of testing every sphere."""
    import dataclasses

    sc = spheres_scene(3.0, seed=2, thickness=3.0)
    brute = dataclasses.replace(sc, grid=SphereGrid.empty())
    n = 4000
    o = rng.uniform(-2.0, 2.0, size=(n, 3))
    o[: n // 2] = 0.0
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = RayBundle(o, d, "world")
    g, b = trace_rays(sc, rays), trace_rays(brute, rays)
    np.testing.assert_array_equal(g.primitive, b.primitive)
    np.testing.assert_array_equal(g.distance, b.distance)
    np.testing.assert_array_equal(g.radiance, b.radiance)
    assert np.all((g.radiance >= 0) & (g.radiance <= 1))


@pytest.mark.parametrize("specular", [0.0, 0.5])
def test_radiance_depends_only_on_the_ray(rng, specular):
    """Brightness constancy: one world ray traced from two rig poses, and from origins
    moved along itself, has one radiance; with a view-dependent highlight too (a static
    scene's light field is a function of the ray, Lambertian or not)."""
    import dataclasses

    sc = dataclasses.replace(room_scene(4.0, seed=3), specular=specular, shininess=8.0)
    n = 3000
    o_w = rng.uniform(-0.5, 0.5, size=(n, 3))
    d_w = rng.normal(size=(n, 3))
    d_w /= np.linalg.norm(d_w, axis=1, keepdims=True)
    base = trace_rays(sc, RayBundle(o_w, d_w, "world"))
    for T_world_rig in (T_from_rt(np.array([0.1, -0.2, 0.3, 0.2, 0.1, -0.4])),
                        T_from_rt(np.array([-1.0, 0.5, 2.0, -0.3, 0.6, 0.1]))):
        T_rig_world = T_inverse(T_world_rig)
        rays_rig = RayBundle(o_w, d_w, "world").transformed(T_rig_world, "rig")
        res = trace_rays(sc, rays_rig, T_world_rig)
        assert np.abs(res.radiance - base.radiance).max() <= RENDER_CONSTANCY_ATOL
    # slide each origin a random part of the way towards its hit
    s = rng.uniform(0.0, 0.9, size=n) * base.distance
    moved = trace_rays(sc, RayBundle(o_w + s[:, None] * d_w, d_w, "world"))
    assert np.abs(moved.radiance - base.radiance).max() <= RENDER_CONSTANCY_ATOL


def test_specular_highlight_is_the_phong_term_and_depends_on_the_view(rng):
    """Scene.specular adds k · max(0, r · v)^shininess to each hit (r the light mirrored about
    the normal facing the ray, v = −d), so one surface point reads differently from two
    viewpoints, where the Lambertian scene reads the same."""
    import dataclasses

    lamb = spheres_scene(3.0, seed=2)
    k, shin = 0.4, 6.0
    spec = dataclasses.replace(lamb, specular=k, shininess=shin)
    n = 4000
    o = np.zeros((n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b = trace_rays(lamb, RayBundle(o, d, "world")), trace_rays(spec, RayBundle(o, d, "world"))
    hit = (a.primitive >= 0) & (a.primitive < lamb.sphere_radii.shape[0])
    assert hit.mean() > 0.5
    P = o[hit] + a.distance[hit, None] * d[hit]
    nrm = (P - lamb.sphere_centres[a.primitive[hit]]) / lamb.sphere_radii[a.primitive[hit], None]
    nrm *= -np.sign(np.sum(nrm * d[hit], axis=1))[:, None]          # the side facing the ray
    lam = nrm @ lamb.light

    def phong(dirs):
        c = -np.sum((2.0 * lam[:, None] * nrm - lamb.light) * dirs, axis=1)
        return np.where((lam > 0) & (c > 0), k * np.maximum(c, 0.0) ** shin, 0.0)

    assert np.abs((b.radiance[hit] - a.radiance[hit]) - phong(d[hit])).max() < RENDER_CONSTANCY_ATOL
    assert phong(d[hit]).max() > 0.2                                  # some rays see a highlight
    # the same points from a viewpoint 0.3 m away (rays that reach them unoccluded)
    o2 = np.array([0.3, 0.0, 0.0])
    d2 = P - o2
    dist2 = np.linalg.norm(d2, axis=1)
    d2 /= dist2[:, None]
    a2 = trace_rays(lamb, RayBundle(np.broadcast_to(o2, d2.shape), d2, "world"))
    b2 = trace_rays(spec, RayBundle(np.broadcast_to(o2, d2.shape), d2, "world"))
    seen = np.abs(a2.distance - dist2) < 1e-6
    assert seen.mean() > 0.5
    assert np.abs(a2.radiance[seen] - a.radiance[hit][seen]).max() < 1e-4            # Lambertian: one value
    assert np.abs((b2.radiance - a2.radiance)[seen] - phong(d2)[seen]).max() < RENDER_CONSTANCY_ATOL
    assert np.abs(b2.radiance[seen] - b.radiance[hit][seen]).max() > 0.02            # highlight: per view


@pytest.mark.parametrize("face", ["+z", "-x"])
def test_lightfield_translation_shifts_samples(face):
    """Moving the rig by exactly one x (or y) spacing along the face's x (y) axis
    reproduces the neighbouring viewpoint's samples."""
    sc = spheres_scene(4.0, seed=1)
    grid = _tiny_grid((face,))
    R = grid.faces[0].R_rig_face
    L0 = render_lightfield(sc, grid, np.eye(4), supersample=2)
    Lx = render_lightfield(sc, grid, T_from_Rt(np.eye(3), grid.x.step * R[:, 0]), supersample=2)
    Ly = render_lightfield(sc, grid, T_from_Rt(np.eye(3), grid.y.step * R[:, 1]), supersample=2)
    assert np.abs(Lx[:, :, :-1] - L0[:, :, 1:]).max() <= RENDER_SHIFT_ATOL
    assert np.abs(Ly[:, :-1] - L0[:, 1:]).max() <= RENDER_SHIFT_ATOL
    assert np.abs(L0[:, :, :-1] - L0[:, :, 1:]).max() > 0.01     # and the views do differ


def test_supersampling_is_a_box_filter_over_the_uv_cell():
    sc = spheres_scene(4.0, seed=1)
    grid = _tiny_grid(("+z",))
    L = render_lightfield(sc, grid, supersample=2)
    du, dv = grid.u.step, grid.v.step
    acc = np.zeros_like(L, dtype=np.float64)
    for ou in (-du / 4, du / 4):
        for ov in (-dv / 4, dv / 4):
            g = LightFieldGrid(grid.faces, grid.x, grid.y, Axis(grid.u.min + ou, grid.u.max + ou, grid.u.count),
                               Axis(grid.v.min + ov, grid.v.max + ov, grid.v.count))
            acc += render_lightfield(sc, g, supersample=1)
    assert np.abs(acc / 4 - L).max() <= RENDER_SUPERSAMPLE_ATOL


def _uv_grown(grid: LightFieldGrid, n: int) -> LightFieldGrid:
    """``grid`` with n more samples of the same step on each side of u and v."""
    def grow(a: Axis) -> Axis:
        return Axis(a.min - n * a.step, a.max + n * a.step, a.count + 2 * n)
    return LightFieldGrid(grid.faces, grid.x, grid.y, grow(grid.u), grow(grid.v))


def test_psf_border_samples_see_the_scene_beyond_the_border():
    """With an optics PSF the samples at the (u, v) border are those of a wider grid:
    the lens blurs the scene, not the finished image with a padded edge."""
    sc = spheres_scene(4.0, seed=1)
    grid = _tiny_grid(("+z",), n_uv=12)
    L = render_lightfield(sc, grid, supersample=2, psf=0.7)
    wide = render_lightfield(sc, _uv_grown(grid, 3), supersample=2, psf=0.7)
    assert np.abs(L - wide[..., 3:-3, 3:-3]).max() <= RENDER_SUPERSAMPLE_ATOL
    assert np.abs(L - render_lightfield(sc, grid, supersample=2)).max() > 0.01   # it does blur


def test_psf_is_a_gaussian_before_the_box_filter():
    """A sample is the Gaussian-weighted sum of the sub-sample rays around it (dense 1-D
    kernels here), averaged over its own k x k sub-samples."""
    sc = spheres_scene(4.0, seed=1)
    grid = _tiny_grid(("+z",), n_uv=6)
    k, psf = 2, 0.6
    L = render_lightfield(sc, grid, supersample=k, psf=psf)
    pad = math.ceil(4 * psf) + 1
    n = (grid.u.count + 2 * pad) * k
    wide = _uv_grown(grid, pad)
    fine_axis = Axis(wide.u.min + (0.5 / k - 0.5) * grid.u.step, wide.u.max + (0.5 - 0.5 / k) * grid.u.step, n)
    fine = render_lightfield(sc, LightFieldGrid(grid.faces, grid.x, grid.y, fine_axis, fine_axis), supersample=1)
    r = int(4 * psf * k + 0.5)                      # scipy's truncation at 4 std
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / (psf * k)) ** 2)
    g /= g.sum()
    G = np.zeros((grid.u.count, n))                 # sample i <- fine j: box of the cell's k, then g
    for i in range(grid.u.count):
        for c in range((i + pad) * k, (i + pad + 1) * k):
            G[i, c - r:c + r + 1] += g / k
    ref = np.einsum("ia,yxab,jb->yxij", G, fine[0].astype(np.float64), G)
    assert np.abs(L[0] - ref).max() <= RENDER_SUPERSAMPLE_ATOL


def test_psf_before_the_pixels_removes_the_aliasing_a_digital_blur_keeps():
    """Gaussian ⊗ box converges with the sub-samples; blurring the box-filtered samples keeps
    the aliased part of texture finer than a sample (spheres at 8 m, 3 deg per sample)."""
    from scipy.ndimage import gaussian_filter1d

    sc = spheres_scene(8.0, seed=1)
    grid = _tiny_grid(("+z",), n_uv=24, fov_half=36.0)
    ref = render_lightfield(sc, grid, supersample=16, psf=0.8)
    coarse = render_lightfield(sc, grid, supersample=8, psf=0.8)
    box = render_lightfield(sc, _uv_grown(grid, 4), supersample=8)     # the same rays, box only
    digital = gaussian_filter1d(gaussian_filter1d(box, 0.8, axis=3), 0.8, axis=4)[..., 4:-4, 4:-4]
    err_psf, err_digital = (float(np.sqrt(np.mean((a - ref) ** 2))) for a in (coarse, digital))
    assert err_psf < 0.5 * err_digital                # measured 0.0014 against 0.0043


def test_lightfield_face_rays_match_grid():
    grid = _tiny_grid(("+z", "-y"))
    for k in range(2):
        o, d = lightfield_face_rays(grid, k, 1)
        ref = grid.face_rays(k)
        np.testing.assert_allclose(o, ref.origins[:, :, 0, 0].reshape(-1, 3), atol=1e-12)
        dn = d[:, 0] / np.linalg.norm(d[:, 0], axis=1, keepdims=True)
        np.testing.assert_allclose(dn, ref.directions[0, 0].reshape(-1, 3), atol=1e-6)


def test_spheres_fill_the_horizon_on_all_faces():
    sc = spheres_scene(8.0, seed=0)
    grid = default_lightfield_grid("all", views=1, directions=24)
    for k, face in enumerate(grid.faces):
        o, d = lightfield_face_rays(grid, k, 1)
        sky = np.mean(trace_outer(sc, o, d, np.eye(4)).primitive == -1)
        assert sky <= SYNTH_BACKGROUND_MAX, (face.name, sky)


# ----------------------------------------------------------------------------- cameras


@pytest.mark.parametrize("lens", ["cam0.opencv8.cameramodel", "cam1.splined.cameramodel"])
def test_rendered_hits_project_onto_their_pixels(tmp_path, lens):
    """Where a pixel's central ray hits the scene, mrcal.project through the true model
    (world → rig → camera) lands on that pixel."""
    import mrcal

    lens_path = shared_data("mrcal-models") / lens
    if not lens_path.is_file():
        pytest.skip(f"{lens_path} not found")
    rig = _small_rig(tmp_path, 40, 30, lens=lens_path)
    models = true_cameramodels(rig, seed=3, perturb_position_m=0.003, perturb_rotation_deg=0.5,
                               perturb_focal_frac=0.02)
    T_world_rig = T_from_rt(np.array([0.05, -0.1, 0.02, 0.1, -0.05, 0.2]))
    renderer = CameraArrayRenderer(rig, models, room_scene(4.0, seed=3), supersample=1)
    for cam_id, m in models.items():
        dist, prim = renderer.distances(cam_id, T_world_rig)
        assert np.all(np.isfinite(dist)) and np.all(prim >= 0)
        W, H = m.imagersize()
        q = pixel_grid(int(W), int(H))[:, :, 0]
        rays = camera_rays(m, q)
        p_world = (rays.origins + dist[..., None] * rays.directions) @ T_world_rig[:3, :3].T + T_world_rig[:3, 3]
        T_cam_world = T_inverse(T_rig_cam_of(m)) @ T_inverse(T_world_rig)
        p_cam = p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        err = np.linalg.norm(mrcal.project(p_cam, *m.intrinsics()) - q, axis=-1)
        assert err.max() <= RENDER_PROJECTION_PX


def test_all_cameras_in_one_call_match_per_camera_renders(tmp_path):
    rig = _small_rig(tmp_path)
    r = CameraArrayRenderer(rig, None, room_scene(4.0, seed=1), supersample=2)
    T = T_from_rt(np.array([0.01, 0.02, -0.03, 0.1, 0.0, 0.05]))
    both = r.render(T)
    for cam in rig.cameras:
        assert both[cam.id].shape == (cam.height, cam.width)
        np.testing.assert_array_equal(both[cam.id], r.render_camera(cam.id, T))


def test_true_models_are_perturbed_and_seeded(tmp_path):
    rig = _small_rig(tmp_path)
    nominal = true_cameramodels(rig, seed=1)
    a = true_cameramodels(rig, seed=1, perturb_position_m=0.002, perturb_rotation_deg=0.3, perturb_focal_frac=0.01)
    b = true_cameramodels(rig, seed=1, perturb_position_m=0.002, perturb_rotation_deg=0.3, perturb_focal_frac=0.01)
    for cam in rig.cameras:
        np.testing.assert_array_equal(a[cam.id].rt_cam_ref(), b[cam.id].rt_cam_ref())
        np.testing.assert_allclose(T_rig_cam_of(nominal[cam.id]), cam.T_rig_cam, atol=1e-12)
        dT = T_inverse(T_rig_cam_of(nominal[cam.id])) @ T_rig_cam_of(a[cam.id])
        assert 1e-4 < np.linalg.norm(dT[:3, 3]) < 0.02
        assert 1e-4 < np.linalg.norm(r_from_R(dT[:3, :3])) < math.radians(3.0)
        assert a[cam.id].intrinsics()[1][0] != nominal[cam.id].intrinsics()[1][0]


def test_quantize():
    x = np.array([-0.1, 0.0, 0.5, 1.0, 1.2])
    np.testing.assert_array_equal(quantize(x, 8), [0, 0, 128, 255, 255])
    assert quantize(x, 16).dtype == np.uint16 and quantize(x, 16)[3] == 65535
    with pytest.raises(ValueError):
        quantize(x, 8, noise=0.1)


# ----------------------------------------------------------------------------- motion


def test_smooth_trajectory_steps_and_determinism():
    tr = smooth_trajectory(40, step_t=0.01, step_r_deg=0.5, fps=20.0, seed=3)
    np.testing.assert_array_equal(tr.T_world_rig[0], np.eye(4))
    assert np.all(np.diff(tr.timestamps_ns) == 50_000_000)
    rel = tr.relative()
    st = np.linalg.norm(rel[:, :3, 3], axis=1)
    sr = np.linalg.norm(r_from_R(rel[:, :3, :3]), axis=1)
    assert math.sqrt(np.mean(st**2)) == pytest.approx(0.01, rel=SYNTH_STEP_RTOL)
    assert math.sqrt(np.mean(sr**2)) == pytest.approx(math.radians(0.5), rel=SYNTH_STEP_RTOL)
    assert st.std() > 0 and sr.std() > 0
    np.testing.assert_array_equal(tr.T_world_rig, smooth_trajectory(40, step_t=0.01, step_r_deg=0.5,
                                                                    fps=20.0, seed=3).T_world_rig)
    assert not np.array_equal(tr.T_world_rig, smooth_trajectory(40, step_t=0.01, step_r_deg=0.5,
                                                                fps=20.0, seed=4).T_world_rig)
    st = static_trajectory(3)
    np.testing.assert_array_equal(st.T_world_rig, np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(ValueError):
        make_trajectory("wobbly", 3)


# ----------------------------------------------------------------------------- files on disk


def test_session_files_and_ground_truth(tmp_path):
    from polycam.session import open_session

    rig = _small_rig(tmp_path, extra='[mock]\nscene = "room"\nmotion = "smooth"\nstep_t = 0.02\n')
    out = synth_session(rig, tmp_path / "s", frames=3, seed=2, supersample=1, bit_depth=16,
                        perturb_position_m=0.002, perturb_rotation_deg=0.2, perturb_focal_frac=0.01)
    s = open_session(out)
    assert s.status == "complete" and len(s) == 3
    img = s.read_frame(1)["cam01"]
    assert img.dtype == np.uint16 and img.shape == (24, 32)
    gt = s.groundtruth()
    ref = smooth_trajectory(3, step_t=0.02, step_r_deg=0.2, fps=30.0, seed=2)
    np.testing.assert_allclose(gt.T_world_rig, ref.T_world_rig, atol=1e-8)
    calib = s.calibration()
    true = true_cameramodels(rig, seed=2, perturb_position_m=0.002, perturb_rotation_deg=0.2,
                             perturb_focal_frac=0.01)
    for cam in rig.cameras:
        np.testing.assert_allclose(calib[cam.id].rt_cam_ref(), true[cam.id].rt_cam_ref(), atol=1e-9)
    # the images are the true models' renders
    renderer = CameraArrayRenderer(rig, true, room_scene(4.0, seed=2), supersample=1)
    expect = quantize(renderer.render_camera("cam01", ref.T_world_rig[1]), 16)
    np.testing.assert_array_equal(img, expect)


def test_unsynchronised_cameras(tmp_path):
    # sync_spread_ms: each camera captures at its own constant offset (within the spread), its image is
    # the scene at that moment and its timestamp says so; the frames' times and the ground truth stay
    from polycam.session import open_session, sync_warning
    from polycam.trajectory import pose_at

    rig = _small_rig(tmp_path, extra='[mock]\nscene = "room"\nmotion = "smooth"\nstep_t = 0.02\n')
    out = synth_session(rig, tmp_path / "s", frames=3, seed=2, supersample=1, bit_depth=16, sync_spread_ms=12.0)
    s = open_session(out)
    offsets = s.cam_timestamps - s.timestamps_ns[:, None]
    assert np.all(offsets == offsets[0]) and np.all(np.abs(offsets) <= 12_000_000) and np.ptp(offsets[0]) > 1e6
    ref = smooth_trajectory(3, step_t=0.02, step_r_deg=0.2, fps=30.0, seed=2, start_ns=12_000_000)
    np.testing.assert_array_equal(s.timestamps_ns, ref.timestamps_ns)
    np.testing.assert_allclose(s.groundtruth().T_world_rig, ref.T_world_rig, atol=1e-8)
    renderer = CameraArrayRenderer(rig, true_cameramodels(rig, seed=2), room_scene(4.0, seed=2), supersample=1)
    k = rig.ids.index("cam01")
    t = int(s.cam_timestamps[1, k])
    np.testing.assert_array_equal(s.read_frame(1)["cam01"],
                                  quantize(renderer.render_camera("cam01", pose_at(ref, t)), 16))
    assert not np.allclose(pose_at(ref, t), ref.T_world_rig[1])
    # before the first frame and after the last the rig's motion goes on (not its first or last step)
    motion = smooth_trajectory(3, step_t=0.02, step_r_deg=0.2, fps=30.0, seed=2, start_ns=12_000_000, margin=1)
    f, k = (0, int(np.argmin(offsets[0]))) if offsets[0].min() < 0 else (2, int(np.argmax(offsets[0])))
    t = int(s.cam_timestamps[f, k])
    assert not np.allclose(pose_at(motion, t), pose_at(ref, t), atol=1e-7)
    np.testing.assert_array_equal(s.read_frame(f)[rig.ids[k]],
                                  quantize(renderer.render_camera(rig.ids[k], pose_at(motion, t)), 16))
    assert "not synchronised" in sync_warning(s) and s.capture_spread_ns()[0] == np.ptp(offsets[0])
    # without the spread: one time per frame, no warning
    s0 = open_session(synth_session(rig, tmp_path / "s0", frames=2, seed=2, supersample=1))
    assert not s0.capture_spread_ns().any() and sync_warning(s0) == ""


def test_timestamp_jitter(tmp_path):
    # timestamp_jitter_ms: each image's timestamp is its capture time plus seeded Gaussian jitter, its
    # image unchanged; the session's capture times take the jitter out, so synchronised cameras with
    # jittery timestamps read as synchronised; with a spread, the phases survive the jitter
    from polycam.session import open_session, sync_warning

    rig = _small_rig(tmp_path, extra='[mock]\nscene = "room"\nmotion = "smooth"\nstep_t = 0.02\n')
    kw = dict(frames=31, seed=2, supersample=1, bit_depth=16)       # one CAPTURE_OFFSET_FRAMES window
    calls: dict[str, list] = {"s0": [], "sj": []}
    s0 = open_session(synth_session(rig, tmp_path / "s0", progress=lambda d, t: calls["s0"].append(d), **kw))
    sj = open_session(synth_session(rig, tmp_path / "sj", timestamp_jitter_ms=1.5,
                                    progress=lambda d, t: calls["sj"].append(d), **kw))
    assert calls["s0"] == calls["sj"] == list(range(1, 32))        # a progress step per frame either way
    start = 7_500_000                                               # TIMESTAMP_JITTER_MARGIN stds
    np.testing.assert_array_equal(sj.timestamps_ns - start, s0.timestamps_ns)
    for f in (0, 30):
        for cam in rig.ids:
            np.testing.assert_array_equal(sj.read_frame(f)[cam], s0.read_frame(f)[cam])
    jitter = (sj.cam_timestamps - sj.timestamps_ns[:, None]) / 1e6
    assert 1.0 < np.std(jitter) < 2.0 and np.median(np.ptp(jitter, axis=1)) > 1.0
    assert sync_warning(sj) == "" and np.median(sj.capture_spread_ns()) < 1_000_000
    assert 0.3e6 < sj.jitter_spread_ns() < 1.0e6                   # 1.25 x 1.5 ms / sqrt(31) x 1.13 (2 cameras)
    assert 1.0e6 < sj.timestamp_jitter_ns() < 2.0e6 and s0.timestamp_jitter_ns() == 0.0
    # a short session: the capture times keep part of the jitter, which alone spreads five cameras' by
    # ~2.9 ms here; that is not taken for unsynchronised cameras
    (tmp_path / "row.toml").write_text(mock_grid_rig_text("row", 32, 24, rows=1, cols=5))
    short = open_session(synth_session(load_rig(tmp_path / "row.toml"), tmp_path / "short", frames=9, seed=2,
                                       supersample=1, timestamp_jitter_ms=3.0))
    assert np.median(short.capture_spread_ns()) > 1.5e6 and sync_warning(short) == ""
    sp = open_session(synth_session(rig, tmp_path / "sp", timestamp_jitter_ms=1.0, sync_spread_ms=12.0, **kw))
    phase = (sp.capture_times_ns() - sp.timestamps_ns[:, None]).astype(float)
    true = (open_session(synth_session(rig, tmp_path / "sp0", sync_spread_ms=12.0, **kw)).cam_timestamps
            - sp.timestamps_ns[:, None] + 5_000_000)                   # the same phases, 5 ms later start
    assert np.abs(phase - true).max() < 1.0e6 < np.abs(sp.cam_timestamps - sp.timestamps_ns[:, None] - true).max()
    assert "not synchronised" in sync_warning(sp)


def test_trajectory_margin():
    # margin: poses of the same motion before and after the frames, the frames' own unchanged
    from polycam.geometry import r_from_R
    from polycam.synth import frames_of

    tr = smooth_trajectory(6, step_t=0.01, step_r_deg=0.5, seed=3, start_ns=5_000)
    wide = smooth_trajectory(6, step_t=0.01, step_r_deg=0.5, seed=3, start_ns=5_000, margin=2)
    assert len(wide) == 10 and np.array_equal(wide.T_world_rig[2], np.eye(4))
    core = frames_of(wide, 2)
    np.testing.assert_array_equal(core.T_world_rig, tr.T_world_rig)
    np.testing.assert_array_equal(core.timestamps_ns, tr.timestamps_ns)
    np.testing.assert_allclose(np.diff(wide.timestamps_ns[:3]), 1e9 / 30, atol=1)     # the frame clock's
    steps = np.array([np.r_[S[:3, 3], r_from_R(S[:3, :3])] for S in
                      (np.linalg.inv(a) @ b for a, b in zip(wide.T_world_rig[:-1], wide.T_world_rig[1:]))])
    change = np.linalg.norm(np.diff(steps, axis=0), axis=1)        # smooth: each step near its neighbours,
    assert change.max() < 0.5 * np.linalg.norm(steps, axis=1).min()  # beyond the frames as within them,
    assert max(change[:2].max(), change[-2:].max()) < 1.5 * change[2:-2].max()              # not held still
    assert np.linalg.norm(steps[0] - steps[2]) > 1e-6 and np.linalg.norm(steps[-1] - steps[-3]) > 1e-6
    still = make_trajectory("static", 2, margin=1, start_ns=40_000_000)
    assert len(still) == 4 and still.timestamps_ns[0] == 40_000_000 - 33_333_333
    with pytest.raises(ValueError, match="margin"):
        smooth_trajectory(3, margin=-1)


def test_pose_between_frames():
    from polycam.trajectory import pose_at

    tr = smooth_trajectory(4, step_t=0.01, step_r_deg=0.5, seed=3, start_ns=5_000)
    for i, t in enumerate(tr.timestamps_ns):
        np.testing.assert_allclose(pose_at(tr, t), tr.T_world_rig[i], atol=1e-12)
    mid = pose_at(tr, 0.5 * (tr.timestamps_ns[1] + tr.timestamps_ns[2]))
    d1, d2 = (np.linalg.norm(mid[:3, 3] - tr.T_world_rig[j][:3, 3]) for j in (1, 2))
    assert abs(d1 - d2) < 0.1 * (d1 + d2)                     # half-way along the step
    before = pose_at(tr, tr.timestamps_ns[0] - 1e7)            # extrapolated with the first step
    assert 0 < np.linalg.norm(before[:3, 3]) < 0.01


def test_lightfield_store_and_ground_truth(tmp_path):
    from polycam.lfstore import open_lightfield

    grid = _tiny_grid(("+z", "+x"), n_uv=6)
    out = synth_lightfield(tmp_path / "lf.zarr", grid=grid, scene="spheres", distance=4.0, frames=2, seed=1,
                           supersample=1, step_t=0.02, step_r_deg=0.5)
    lf = open_lightfield(out)
    assert len(lf) == 2 and lf.grid.shape == grid.shape
    gt = lf.groundtruth()
    ref = smooth_trajectory(2, step_t=0.02, step_r_deg=0.5, fps=30.0, seed=1)
    np.testing.assert_allclose(gt.T_world_rig, ref.T_world_rig, atol=1e-8)
    np.testing.assert_array_equal(lf.frame(1), render_lightfield(spheres_scene(4.0, seed=1), grid,
                                                                  ref.T_world_rig[1], supersample=1))



@pytest.mark.parametrize("bit_depth", [None, 8])
def test_lightfield_store_with_sensor_noise(tmp_path, bit_depth):
    """``synth_lightfield(noise=, bit_depth=)`` (``polycam synth lightfield --noise --bit-depth``):
    seeded Gaussian noise on the rendered samples, rounded to the 8-bit lattice when asked
    (and then clipped to [0, 1]); the motion solver measures that noise (with the rounding's
    1/12 step² on 8-bit frames)."""
    from polycam.lfstore import open_lightfield
    from polycam.motion_weights import frame_noise_variance

    grid = default_lightfield_grid("+z", directions=32)        # views 1 cm apart: smooth across them
    sigma = 2.0 / 255.0
    kw = dict(grid=grid, scene="spheres", distance=4.0, frames=2, seed=1, supersample=1, step_t=0.02,
              step_r_deg=0.5, noise=sigma, bit_depth=bit_depth)
    lf = open_lightfield(synth_lightfield(tmp_path / "lf.zarr", **kw))
    again = open_lightfield(synth_lightfield(tmp_path / "again.zarr", **kw))
    ref = smooth_trajectory(2, step_t=0.02, step_r_deg=0.5, fps=30.0, seed=1)
    clean = render_lightfield(spheres_scene(4.0, seed=1), grid, ref.T_world_rig[1], supersample=1)
    L0, L1 = lf.frame(0), lf.frame(1)
    np.testing.assert_array_equal(L1, again.frame(1))              # seeded
    q2 = 0.0
    if bit_depth == 8:
        np.testing.assert_allclose(L1 * 255.0, np.rint(L1 * 255.0), atol=1e-4)
        assert L1.min() >= 0.0 and L1.max() <= 1.0
        q2 = (1.0 / 255.0) ** 2 / 12.0
    inside = (clean > 3 * sigma) & (clean < 1 - 3 * sigma)         # no clipping there
    expected = math.sqrt(sigma ** 2 + q2)
    assert np.std((L1 - clean)[inside]) == pytest.approx(expected, rel=MOTION_NOISE_SIGMA_REL)
    measured = math.sqrt(frame_noise_variance(L0, L1, grid))
    assert measured == pytest.approx(expected, rel=MOTION_NOISE_SIGMA_REL)


def test_board_session_is_detectable(tmp_path):
    """A rendered ChArUco board is found by OpenCV with its corners where mrcal projects them."""
    import cv2
    import mrcal

    from polycam.board import load_board
    from polycam.session import open_session

    board = load_board(_rig_file(tmp_path, BOARD_TOML, "board.toml"))
    rig = load_rig(_rig_file(tmp_path, """[rig]
name = "one"
[defaults]
width = 480
height = 360
fov_deg = 60
[[camera]]
id = "cam00"
position = [0.0, 0.0, 0.0]
[[camera]]
id = "cam01"
position = [0.04, 0.0, 0.0]
"""))
    out = synth_board_session(rig, tmp_path / "b", board=board, frames=3, seed=5, supersample=2,
                              perturb_position_m=0.001, perturb_rotation_deg=0.2, perturb_focal_frac=0.005)
    s = open_session(out)
    poses = read_tum(out / "board_poses.tum")
    assert len(poses) == 3 and (out / "board.toml").is_file()
    np.testing.assert_allclose(poses.T_world_rig, board_poses(board, s.calibration(), 3, seed=5,
                                                              cam_ids=["cam00", "cam01"]), atol=1e-8)
    detector = cv2.aruco.CharucoDetector(board.cv2_board())
    P = board.object_points()
    for i in range(3):
        for cam_id, m in s.calibration().items():
            corners, ids, _, _ = detector.detectBoard(s.read_frame(i)[cam_id])
            aimed = cam_id == ("cam00", "cam01")[i % 2]      # the pose was chosen to fit this view
            assert ids is not None
            assert len(ids) >= (SYNTH_BOARD_DETECTED_MIN * board.num_corners if aimed else 4)
            T_cam_board = T_inverse(T_rig_cam_of(m)) @ poses.T_world_rig[i]
            q = mrcal.project(P @ T_cam_board[:3, :3].T + T_cam_board[:3, 3], *m.intrinsics())
            err = np.linalg.norm(corners.reshape(-1, 2) - q[ids.ravel()], axis=1)
            assert err.max() <= SYNTH_BOARD_CORNER_MAX_PX
            assert math.sqrt(np.mean(err**2)) <= SYNTH_BOARD_CORNER_RMS_PX


def test_board_poses_are_varied_and_in_view(tmp_path):
    from polycam.board import load_board

    board = load_board(_rig_file(tmp_path, BOARD_TOML, "board.toml"))
    rig = _small_rig(tmp_path, 320, 240)
    models = true_cameramodels(rig)
    poses = board_poses(board, models, 12, seed=1, tilt_deg=40.0)
    tilt = np.degrees(np.arccos(np.clip(poses[:, 2, 2], -1, 1)))     # board z vs rig z
    assert tilt.max() > 20.0 and tilt.max() < 60.0
    assert np.ptp(poses[:, 0, 3]) > 0.05 and np.all(poses[:, 2, 3] > 0.1)


def _two_face_rig(tmp_path, fov_deg: float, second: str, height: int = 240):
    """Two faces of a cube rig, two 320 x ``height`` cameras each, 3 cm apart: +z and ``second`` (+x or +y)."""
    rot = {"+x": "[0.0, 1.5707963268, 0.0]", "+y": "[-1.5707963268, 0.0, 0.0]"}[second]
    axis = {"+x": (1, 0, 0), "+y": (0, 1, 0)}[second]
    cams = []
    for k, (face, r, n) in enumerate((("pz", "[0.0, 0.0, 0.0]", (0, 0, 1)), (second, rot, axis))):
        side = np.cross(n, (0, 1, 0) if second == "+x" or k == 0 else (1, 0, 0))
        for j in range(2):
            p = 0.05 * np.asarray(n, float) + (j - 0.5) * 0.03 * side
            cams.append(f'[[camera]]\nid = "f{k}_{j}"\nposition = [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]\n'
                        f"rotation = {r}\n")
    return load_rig(_rig_file(tmp_path, f"""[rig]
name = "two_faces"
[defaults]
width = 320
height = {height}
fov_deg = {fov_deg}
""" + "\n".join(cams)))


def test_board_poses_bridge_faces_that_look_apart(tmp_path, repo):
    """Cameras looking through two faces of a cube (as rigs/cube6x3x3.toml's: 90 deg lenses on 4:3
    images, so +z and +y leave a 16 deg gap between their views): every third board frame is held
    across the faces' common edge, and both faces' cameras detect it (what ties the faces together in
    a board calibration); a board too small to be read across the edge gets a clear error instead;
    the nested cube's default session has bridge frames for each of its 12 edges."""
    import cv2

    from polycam.board import load_board
    from polycam.errors import InputError
    from polycam.session import open_session
    from polycam.synth import camera_groups, default_board_frames

    poster = load_board(repo / "rigs" / "boards" / "charuco_7x9.toml")
    rig = _two_face_rig(tmp_path, 90.0, "+y")
    models = true_cameramodels(rig, seed=3)
    assert camera_groups(models) == [["f0_0", "f0_1"], ["f1_0", "f1_1"]]
    out = synth_board_session(rig, tmp_path / "b", board=poster, frames=6, seed=3)
    s = open_session(out)
    detector = cv2.aruco.CharucoDetector(poster.cv2_board())
    for i in range(6):
        seen = {}
        for cam_id in s.calibration():
            _, ids, _, _ = detector.detectBoard(s.read_frame(i)[cam_id])
            seen[cam_id] = 0 if ids is None else len(ids)
        per_face = [max(seen["f0_0"], seen["f0_1"]), max(seen["f1_0"], seen["f1_1"])]
        if i % 3 == 2:                                  # a bridge: read by both faces
            assert min(per_face) >= 8, (i, seen)
        else:                                           # aimed at one camera: read there
            assert max(per_face) >= 8, (i, seen)
    a4 = load_board(_rig_file(tmp_path, BOARD_TOML, "board.toml"))
    with pytest.raises(InputError, match="large enough"):
        board_poses(a4, models, 3, seed=3)
    cube = true_cameramodels(load_rig(repo / "rigs" / "cube6x3x3.toml"))
    assert len(camera_groups(cube)) == 6 and default_board_frames(cube) == 144
    assert default_board_frames(models) == 25 and default_board_frames(true_cameramodels(_small_rig(tmp_path))) == 25


def test_pattern_scene_is_refused(tmp_path):
    from polycam.errors import InputError

    rig = _small_rig(tmp_path, extra='[mock]\nscene = "pattern"\n')
    with pytest.raises(InputError, match="pattern"):
        synth_session(rig, tmp_path / "s", frames=1)
