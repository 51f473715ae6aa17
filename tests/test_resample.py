"""Resampling core: automatic grid, splat geometry, pull-push, per-frame resampling.

Small rigs (a few cameras of a few dozen pixels) with rotated, distorted true models,
so each test runs in well under a second once numba's cache is warm.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from polycam.cameras import T_rig_cam_of
from polycam.errors import InputError
from polycam.lightfield import FACE_NAMES, Axis, LightFieldGrid
from polycam.rig import load_rig
from polycam.synth import true_cameramodels
from resample import (KernelOptions, ResampleOptions, Resampler, auto_grid, build_geometry, push_pull,
                      push_pull_reference, ray_samples)
from resample.geometry import camera_layout
from resample.pushpull import pyramid_schedule
from tolerances import (RESAMPLE_CONSTANT_ATOL, RESAMPLE_LINEAR_ATOL, RESAMPLE_PUSHPULL_ATOL, RESAMPLE_VIEWFILL_DISPARITY_ATOL,
                        RESAMPLE_VIEWFILL_OFFGRID_GAIN, RESAMPLE_VIEWFILL_RMS, RESAMPLE_ROW_ACROSS_GAIN)


def _lens(tmp_path: Path) -> Path:
    """A distorting lens (OPENCV4, barrel) for the rig files."""
    import mrcal

    p = tmp_path / "lens.cameramodel"
    mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV4", np.array([100.0, 100.0, 79.5, 59.5, -0.12, 0.02, 0.001, -0.001])),
                      imagersize=np.array([160, 120])).write(str(p))
    return p


def _grid_rig(tmp_path: Path, rows=3, cols=3, width=40, height=30, pitch=0.02, lens=True, extra=""):
    lens_line = f'lens = "{_lens(tmp_path)}"\n' if lens else ""
    p = tmp_path / "rig.toml"
    p.write_text(f"""[rig]
name = "small"
[defaults]
driver = "mock"
width = {width}
height = {height}
fps = 30
fov_deg = 60
{lens_line}
[grid]
rows = {rows}
cols = {cols}
pitch = {pitch}
{extra}""")
    return load_rig(p)


def _models(tmp_path, rot_deg=2.0, **kw):
    rig = _grid_rig(tmp_path, **kw)
    return rig, true_cameramodels(rig, seed=4, perturb_rotation_deg=rot_deg, perturb_focal_frac=0.01)


def _sample_coords(models, grid):
    """Per camera: (H, W) arrays of the face-0 light-field coordinates (x, y, u, v) of its pixels."""
    from polycam.cameras import camera_rays

    out = {}
    fc = grid.faces[0]
    R = np.asarray(fc.R_rig_face)
    for cam, m in models.items():
        r = camera_rays(m)
        o = r.origins @ R
        d = r.directions @ R
        s = (fc.z_pi - o[..., 2]) / d[..., 2]
        out[cam] = (o[..., 0] + s * d[..., 0], o[..., 1] + s * d[..., 1],
                    fc.f * d[..., 0] / d[..., 2], fc.f * d[..., 1] / d[..., 2])
    return out


def _grid_coords(grid):
    ys, xs, vs, us = np.meshgrid(grid.y.values, grid.x.values, grid.v.values, grid.u.values, indexing="ij")
    return xs[None], ys[None], us[None], vs[None]


# ----------------------------------------------------------------------------- grid


def test_auto_grid_puts_viewpoints_at_and_between_the_cameras(tmp_path):
    rig, models = _models(tmp_path, rows=3, cols=4)
    g = auto_grid(models)
    assert [f.name for f in g.faces] == ["+z"]
    assert (g.y.count, g.x.count) == (5, 7)                 # 2 steps per camera interval
    np.testing.assert_allclose(g.x.step, 0.01, rtol=1e-6)
    np.testing.assert_allclose([g.x.min, g.x.max], [-0.03, 0.03], atol=1e-9)
    assert abs(g.faces[0].z_pi) < 1e-9
    fx = np.median([m.intrinsics()[1][0] for m in models.values()])
    np.testing.assert_allclose(g.faces[0].f, fx)            # one (u, v) step = one pixel
    assert g.u.step == pytest.approx(1.0) and g.v.step == pytest.approx(1.0)
    # the directions cover the cameras' fields of view: about the image size
    assert 40 <= g.u.count <= 40 * 1.5 and 30 <= g.v.count <= 30 * 1.5
    g2 = auto_grid(models, uv_step_px=2.0, xy_oversample=1)
    assert (g2.y.count, g2.x.count) == (3, 4) and g2.u.step == pytest.approx(1.0)
    assert g2.faces[0].f == pytest.approx(g.faces[0].f / 2)


def _three_way_rig(tmp_path):
    p = tmp_path / "cube.toml"
    cams = []
    for name, rot in [("front", [0, 0, 0]), ("right", [0, math.pi / 2, 0]), ("back", [0, math.pi, 0])]:
        cams.append(f'[[camera]]\nid = "{name}"\nposition = [0.0, 0.0, 0.0]\nrotation = {rot}\n')
    p.write_text('[rig]\nname = "three"\n[defaults]\ndriver = "mock"\nwidth = 32\nheight = 24\nfps = 30\n'
                 'fov_deg = 60\n' + "\n".join(cams))
    return true_cameramodels(load_rig(p))


def test_auto_grid_uses_one_face_per_viewing_direction(tmp_path):
    models = _three_way_rig(tmp_path)
    g = auto_grid(models)
    assert [f.name for f in g.faces] == [n for n in FACE_NAMES if n in ("+z", "+x", "-z")]
    assert max(abs(g.u.min), abs(g.u.max)) <= g.faces[0].f + 1      # at most 45 deg per face
    assert (g.x.count, g.y.count) == (1, 1)                         # one viewpoint


def test_cameras_looking_three_ways_fill_three_faces(tmp_path):
    """Each camera feeds the face it looks into (and its neighbours where its field of view
    crosses the face boundary); every face gets the constant back."""
    models = _three_way_rig(tmp_path)
    grid = auto_grid(models)
    rs = Resampler(models, grid)
    r = rs.resample({c: np.full((24, 32), 0.3, np.float32) for c in models})
    np.testing.assert_allclose(r.L, 0.3, atol=RESAMPLE_CONSTANT_ATOL)
    for k, face in enumerate(grid.faces):
        assert np.mean(r.W[k] > 0.5) > 0.2, face.name
        assert rs.geometry.w0[k].sum() > 0


# ----------------------------------------------------------------------------- pull-push


@pytest.mark.parametrize("schedule", ["xy-first", "isotropic"])
@pytest.mark.parametrize("shape", [(1, 9, 9, 12, 14), (2, 4, 5, 7, 6), (1, 1, 1, 5, 5), (1, 2, 1, 1, 3)])
def test_pushpull_matches_the_reference(rng, shape, schedule):
    w0 = rng.uniform(0, 2, shape).astype(np.float32) * (rng.uniform(size=shape) > 0.6)
    if shape[1] * shape[2] > 2:
        w0[:, 1::2, :] = 0.0            # views without data (skipped by the finest pull)
    x0 = rng.uniform(size=(*shape, 3)).astype(np.float32)
    for x in (x0, x0[..., 0]):
        a = push_pull(x, w0, schedule=schedule)
        b = push_pull_reference(x, w0, schedule=schedule)
        assert np.max(np.abs(a.L - b.L)) <= RESAMPLE_PUSHPULL_ATOL
        assert np.max(np.abs(a.W - b.W)) <= RESAMPLE_PUSHPULL_ATOL


def test_pushpull_fills_holes_with_low_confidence(rng):
    shape = (1, 5, 5, 16, 16)
    w0 = np.zeros(shape, np.float32)
    w0[:, ::2, ::2, 4:12, 4:12] = 2.0                    # data at "camera" viewpoints, central directions
    x0 = np.where(w0 > 0, 0.25, 0).astype(np.float32)
    r = push_pull(x0, w0)
    assert np.all(np.isfinite(r.L)) and np.all((r.W >= 0) & (r.W <= 1))
    np.testing.assert_allclose(r.L, 0.25, atol=RESAMPLE_CONSTANT_ATOL)   # a constant fills as itself
    assert np.all(r.W[w0 > 0] == 1.0)
    holes = w0 == 0
    assert np.all(r.W[holes] <= 0.5)                     # attenuation 0.5 per level
    # deeper holes (farther from the data) have less confidence
    assert r.W[0, 1, 1, 0, 0] < r.W[0, 1, 1, 8, 8] <= 0.5
    assert np.all(push_pull(x0, np.zeros(shape, np.float32)).W == 0.0)   # no data at all: W = 0


def test_pyramid_schedule_halves_views_first():
    s = pyramid_schedule((1, 9, 9, 64, 48))
    assert s[:4] == [(1, 2)] * 4 and all(a == (3, 4) for a in s[4:]) and len(s) == 4 + 6
    assert pyramid_schedule((1, 1, 1, 1, 1)) == []
    with pytest.raises(ValueError):
        pyramid_schedule((1, 2, 2, 2, 2), "nope")


# ----------------------------------------------------------------------------- geometry and frames


def test_every_pixel_lands_on_its_own_ray(tmp_path):
    """A sample's fractional indices, mapped back through the grid, give the pixel's ray."""
    from polycam.cameras import camera_rays

    _, models = _models(tmp_path)
    grid = auto_grid(models)
    lay = camera_layout(models)
    smp = ray_samples(models, grid, lay, margin=0.0)
    o = np.concatenate([camera_rays(models[c]).origins.reshape(-1, 3) for c in lay.ids])[smp.pixel]
    d = np.concatenate([camera_rays(models[c]).directions.reshape(-1, 3) for c in lay.ids])[smp.pixel]
    fc = grid.faces[0]
    x = grid.x.min + smp.coord[:, 1] * grid.x.step
    y = grid.y.min + smp.coord[:, 0] * grid.y.step
    u = grid.u.min + smp.coord[:, 3] * grid.u.step
    v = grid.v.min + smp.coord[:, 2] * grid.v.step
    p = np.stack([x, y, np.full_like(x, fc.z_pi)], 1) @ np.asarray(fc.R_rig_face).T
    dd = np.stack([u, v, np.full_like(u, fc.f)], 1) @ np.asarray(fc.R_rig_face).T
    dd /= np.linalg.norm(dd, axis=1, keepdims=True)
    np.testing.assert_allclose(dd, d, atol=1e-9)
    # the light-field ray's origin lies on the camera ray
    off = p - o
    np.testing.assert_allclose(np.linalg.norm(np.cross(off, d), axis=1), 0, atol=1e-9)


def test_constant_scene_gives_a_constant_light_field(tmp_path):
    _, models = _models(tmp_path)
    grid = auto_grid(models)
    rs = Resampler(models, grid)
    frame = {c: np.full((30, 40), 97, np.uint8) for c in models}
    r = rs.resample(frame)
    np.testing.assert_allclose(r.L, 97 / 255, atol=RESAMPLE_CONSTANT_ATOL)
    assert np.all((r.W >= 0) & (r.W <= 1)) and r.W.max() == 1.0
    # 16-bit and colour inputs are normalised the same way
    rs3 = Resampler(models, grid, channels=3)
    frame16 = {c: np.full((30, 40, 3), 97 * 257, np.uint16) for c in models}
    r3 = rs3.resample(frame16)
    assert r3.L.shape == (*grid.shape, 3)
    np.testing.assert_allclose(r3.L, 97 / 255, atol=RESAMPLE_CONSTANT_ATOL)
    np.testing.assert_array_equal(r3.W, r.W)


@pytest.mark.parametrize("z_pi, radius_xy", [(0.0, 1.0), (0.05, 2.0)])
def test_a_linear_light_field_is_reproduced_exactly_where_covered(tmp_path, z_pi, radius_xy):
    """L = a + b . (x, y, u, v) sampled by rotated, distorted cameras comes back exactly
    wherever a cell has full weight and its samples pin the fit down. With the focal plane
    5 cm ahead of the cameras each camera's samples slant through (x, y), so the fit is
    genuinely 4-D (and needs the wider kernel to see two cameras)."""
    _, models = _models(tmp_path, rows=3, cols=3)
    g0 = auto_grid(models)
    fc = g0.faces[0]
    grid = LightFieldGrid.cube(["+z"], f=fc.f, z_pi=z_pi, x=g0.x, y=g0.y, u=g0.u, v=g0.v)
    coef = np.array([0.31, 2.0, -1.5, 0.004, 0.003])       # per metre (x, y), per grid pixel (u, v)

    def field(x, y, u, v):
        return coef[0] + coef[1] * x + coef[2] * y + coef[3] * u + coef[4] * v

    frame = {c: field(*xyuv).astype(np.float32) for c, xyuv in _sample_coords(models, grid).items()}
    kernel = KernelOptions(radius_xy=radius_xy)
    rs = Resampler(models, grid, options=ResampleOptions(kernel=kernel))
    r = rs.resample(frame)
    truth = field(*_grid_coords(grid))
    covered = (r.W == 1.0) & rs.geometry.determined      # full weight of its own, fit pinned down
    assert covered.mean() > 0.15
    err = np.abs(r.L - truth)[covered]
    assert err.max() <= RESAMPLE_LINEAR_ATOL, err.max()
    # plain splatting (no local-linear correction) is not exact: the test has teeth
    rs0 = Resampler(models, grid, options=ResampleOptions(kernel=KernelOptions(radius_xy=radius_xy, linear=False)))
    assert np.abs(rs0.resample(frame).L - truth)[covered].max() > 10 * RESAMPLE_LINEAR_ATOL


def test_holes_get_low_confidence_and_w_is_a_confidence(tmp_path):
    _, models = _models(tmp_path)
    g0 = auto_grid(models)
    # widen the directions far beyond the cameras' fields of view: a ring of holes
    wide = Axis(g0.u.min - 20, g0.u.max + 20, g0.u.count + 40)
    grid = LightFieldGrid.cube(["+z"], f=g0.faces[0].f, z_pi=0.0, x=g0.x, y=g0.y, u=wide, v=g0.v)
    rs = Resampler(models, grid)
    frame = {c: np.full((30, 40), 0.6, np.float32) for c in models}
    r = rs.resample(frame)
    assert np.all((r.W >= 0) & (r.W <= 1))
    holes = rs.geometry.w0 == 0
    assert holes[..., :15].all() and holes[..., -15:].all()
    assert np.all(r.W[holes] <= 0.5)
    assert np.median(r.W[~holes]) > 0.9
    np.testing.assert_allclose(r.L, 0.6, atol=RESAMPLE_CONSTANT_ATOL)


def test_missing_cameras_use_a_geometry_of_the_cameras_present(tmp_path, rng):
    _, models = _models(tmp_path)
    grid = auto_grid(models)
    frame = {c: rng.uniform(size=(30, 40)).astype(np.float32) for c in models}
    rs = Resampler(models, grid)
    part = dict(frame)
    part["cam04"] = None
    r = rs.resample(part)
    assert r.cameras == tuple(c for c in models if c != "cam04")
    sub = {c: m for c, m in models.items() if c != "cam04"}
    ref = Resampler(sub, grid).resample({c: frame[c] for c in sub})
    np.testing.assert_array_equal(r.L, ref.L)
    np.testing.assert_array_equal(r.W, ref.W)
    with pytest.raises(InputError):
        rs.resample({c: None for c in models})
    with pytest.raises(InputError):
        rs.resample({"cam00": np.zeros((5, 5), np.uint8)})


def test_geometry_rows_are_normalised(tmp_path):
    _, models = _models(tmp_path)
    geo = build_geometry(models, auto_grid(models))
    S = geo.to_scipy()
    rows = np.asarray(S.sum(axis=1)).ravel()
    reached = np.diff(geo.indptr) > 0
    np.testing.assert_allclose(rows[reached], 1.0, atol=1e-5)
    assert np.all(rows[~reached] == 0) and geo.linear_fraction > 0.9
    assert np.array_equal(reached.reshape(geo.w0.shape), geo.w0 > 0)


def test_splat_is_the_sparse_product_and_zero_elsewhere(tmp_path, rng):
    """The splat (which visits only the rows with entries) is the CSR product, also into a
    used buffer and after pickling (the list of those rows is not pickled)."""
    import pickle

    from resample import splat

    _, models = _models(tmp_path)
    geo = build_geometry(models, auto_grid(models))
    x = rng.uniform(size=geo.layout.num_pixels).astype(np.float32)
    ref = (geo.to_scipy() @ x).reshape(geo.w0.shape)
    out = np.full(geo.w0.size, 7.0, np.float32)
    np.testing.assert_allclose(splat(geo, x, out=out), ref, atol=RESAMPLE_CONSTANT_ATOL)
    geo2 = pickle.loads(pickle.dumps(geo))
    assert "nonempty_rows" not in geo2.__dict__
    np.testing.assert_array_equal(splat(geo2, x), splat(geo, x))
    x3 = np.repeat(x[:, None], 3, axis=1)
    np.testing.assert_array_equal(splat(geo, x3)[..., 2], splat(geo, x))


# ----------------------------------------------------------------------------- depth-aware view fill


def _plane_lightfield(grid, delta):
    """A textured fronto-parallel plane: L(iy, ix, iv, iu) = g(iu + δ ix, iv + δ r_y iy) with a
    disparity of δ u-steps per x-step (two incommensurate gratings: no repeat within the sweep)."""
    F, Ny, Nx, Nv, Nu = grid.shape
    r_y = (grid.y.step / grid.x.step) * (grid.u.step / grid.v.step)
    iy, ix, iv, iu = np.meshgrid(np.arange(Ny), np.arange(Nx), np.arange(Nv), np.arange(Nu), indexing="ij")
    a = iu + delta * ix
    b = iv + delta * r_y * iy
    return _plane_texture(a, b)[None].astype(np.float32)


def _plane_texture(a, b):
    """The plane tests' texture at (a, b) [u-steps, v-steps of the reference view]."""
    return 0.5 + 0.2 * np.sin(0.55 * a + 0.21 * b) + 0.15 * np.sin(0.43 * b - 0.17 * a + 1.0)


def _plane_seen_from(grid, delta, pos, height, step):
    """(Nv, Nu): the plane of :func:`_plane_lightfield` seen from a camera centre at fractional view
    position ``pos`` (iy, ix) [view steps of ``step`` m] and ``height`` [m] above the focal plane:
    each direction (u, v) crosses the plane at pos − height (tan_v, tan_u) / step."""
    iv, iu = np.meshgrid(np.arange(grid.v.count), np.arange(grid.u.count), indexing="ij")
    f = grid.faces[0].f
    px = pos[1] - height * grid.u.values[iu] / f / step
    py = pos[0] - height * grid.v.values[iv] / f / step
    return _plane_texture(iu + delta * px, iv + delta * (grid.u.step / grid.v.step) * py)


def test_view_fill_plan_on_an_auto_grid(tmp_path):
    """Views between cameras are filled: half-way views from the two cameras either side,
    centre views from the four around them; camera views are never targets."""
    _, models = _models(tmp_path)
    grid = auto_grid(models)
    rs = Resampler(models, grid)
    plan = rs.fill_plan()
    assert (grid.y.count, grid.x.count) == (5, 5)
    assert len(plan) == 25 - 9
    for (f, j, i), src, off, w in zip(plan.targets, plan.sources, plan.offsets, plan.weights):
        assert not (j % 2 == 0 and i % 2 == 0)
        assert np.all(src % 2 == 0)
        assert len(src) == (4 if (j % 2 and i % 2) else 2)
        np.testing.assert_array_equal(off, src - [j, i])
        assert math.isclose(float(w.sum()), 1.0, rel_tol=1e-6)
    assert plan.disparities[0] < 0 < plan.disparities[-1]
    assert rs.cameras_on_focal_plane()
    # cameras 5 cm behind the focal plane: a grid view is a patchwork of cameras, no fill
    fc = grid.faces[0]
    off = LightFieldGrid.cube(["+z"], f=fc.f, z_pi=0.05, x=grid.x, y=grid.y, u=grid.u, v=grid.v)
    rs_off = Resampler(models, off)
    assert not rs_off.cameras_on_focal_plane() and len(rs_off.fill_plan()) == 0


def test_view_fill_plan_with_cameras_off_the_views(tmp_path):
    """Camera centres 1.5 mm (0.15 view steps) off the nominal positions: the splat kernel's
    tail gives the views beside a camera full weight from its pixels, but only the view
    nearest each camera counts as measured; all the others are filled from depth."""
    from resample import ViewFillOptions
    from resample.viewfill import RECENTRE_SOURCES, camera_heights, camera_positions, camera_views

    rig = _grid_rig(tmp_path)
    models = true_cameramodels(rig, seed=4, perturb_position_m=0.0015, perturb_rotation_deg=2.0,
                               perturb_focal_frac=0.01)
    grid = auto_grid(models)
    assert (grid.y.count, grid.x.count) == (5, 5)
    T = np.stack([T_rig_cam_of(m) for m in models.values()])
    views = camera_views(grid, T[:, :3, 3], T[:, :3, 2])
    expected = np.zeros((1, 5, 5), bool)
    expected[0, ::2, ::2] = True
    np.testing.assert_array_equal(views, expected)
    rs = Resampler(models, grid)
    w = rs._clamped(rs.geometry)
    leaked = np.mean(w >= 1.0, axis=(3, 4))[~expected]
    assert leaked.max() > ViewFillOptions().target_coverage     # without camera_views some would be kept
    plan = rs.fill_plan()
    assert sorted(plan.targets) == [(0, j, i) for j in range(5) for i in range(5) if j % 2 or i % 2]
    pos = camera_positions(grid, T[:, :3, 3], T[:, :3, 2])
    np.testing.assert_array_equal(~np.isnan(pos[..., 0]), expected)
    # by default the camera views are re-centred onto their views first (each matched against the
    # camera views around it, from its centre), and the views between are filled from the grid views
    assert sorted(plan.recentre.targets) == [(0, j, i) for j in range(0, 5, 2) for i in range(0, 5, 2)]
    assert max(len(src) for src in plan.recentre.sources) == 1 + RECENTRE_SOURCES     # itself and the nearest
    heights = camera_heights(grid, T[:, :3, 3], T[:, :3, 2])
    for (f, j, i), src, off, shift in zip(plan.recentre.targets, plan.recentre.sources, plan.recentre.offsets,
                                          plan.recentre.shifts):
        assert tuple(src[0]) == (j, i) and np.all(off[0] == 0)
        np.testing.assert_allclose(off[1:], pos[f, src[1:, 0], src[1:, 1]] - pos[f, j, i])
        np.testing.assert_allclose(shift, [*(pos[f, j, i] - [j, i]), heights[f, j, i]])
    for (f, j, i), src, off in zip(plan.targets, plan.sources, plan.offsets):
        np.testing.assert_array_equal(off, src - [j, i])
    np.testing.assert_array_equal(rs.camera_positions(), np.where(expected[..., None], np.indices((5, 5)).transpose(1, 2, 0)[None], np.nan))
    # without re-centring, the sources' offsets are measured from their camera centres (0.15 view steps off)
    rs_keep = Resampler(models, grid, options=ResampleOptions(fill=ViewFillOptions(recentre=False)))
    plan = rs_keep.fill_plan()
    assert plan.recentre is None
    np.testing.assert_array_equal(rs_keep.camera_positions(), pos)
    off_grid = []
    for (f, j, i), src, off in zip(plan.targets, plan.sources, plan.offsets):
        np.testing.assert_allclose(off, pos[f, src[:, 0], src[:, 1]] - [j, i])
        off_grid.append(np.abs(off - (src - [j, i])).max())
    assert max(off_grid) > 0.05


def test_view_fill_recovers_the_views_of_a_plane():
    """Camera views at even (x, y) indices of a plane's light field; the views between are
    filled along the disparity (found by the sweep) and match the truth, where the
    depth-free blend of the neighbours does not."""
    from resample import ViewFillOptions, fill_views, plan_view_fill

    axis = Axis(0.0, 0.04, 5)
    grid = LightFieldGrid.cube(["+z"], f=100.0, z_pi=0.0, x=axis, y=axis, u=Axis(-48, 47, 96), v=Axis(-40, 39, 80))
    delta = 1.7                     # u-steps per x-step: depth f step_x / delta = 0.59 m
    truth = _plane_lightfield(grid, delta)
    cam = np.zeros(grid.shape, bool)
    cam[:, ::2, ::2] = True
    opts = ViewFillOptions(min_depth=0.4)   # sweeps disparities up to 2.5 u-steps per x-step
    plan = plan_view_fill(grid, cam.astype(np.float32), opts)
    assert len(plan) == 16
    # what pull-push would leave between the cameras: the depth-free blend
    L = np.where(cam, truth, 0).astype(np.float32)
    L[:, ::2, 1::2] = 0.5 * (truth[:, ::2, 0:-1:2] + truth[:, ::2, 2::2])
    L[:, 1::2] = 0.5 * (L[:, 0:-1:2] + L[:, 2::2])
    blend = L.copy()
    W = np.where(cam, 1.0, 0.25).astype(np.float32)
    disp = np.zeros(grid.shape, np.float32)
    L6 = np.ascontiguousarray(L[..., None])
    fill_views(L6, W, plan, opts, disparity_out=disp)
    inner = np.zeros(grid.shape, bool)
    inner[..., 8:-8, 8:-8] = True        # sources stay inside their views
    tgt = inner & ~cam
    err = np.abs(L6[..., 0] - truth)[tgt]
    err_blend = np.abs(blend - truth)[tgt]
    assert np.sqrt(np.mean(err ** 2)) <= RESAMPLE_VIEWFILL_RMS, np.sqrt(np.mean(err ** 2))
    assert np.sqrt(np.mean(err_blend ** 2)) > 4 * RESAMPLE_VIEWFILL_RMS        # the test has teeth
    np.testing.assert_allclose(np.median(disp[tgt]), delta, atol=RESAMPLE_VIEWFILL_DISPARITY_ATOL)
    np.testing.assert_array_equal(L6[..., 0][cam], truth[cam])                  # camera views untouched


def test_view_fill_refines_where_the_sources_are_two_view_steps_away():
    """Cameras every 4th view (4 views per camera spacing, as polycam run takes for a row of
    cameras): the half-way views' sources are 2 steps away, so the fill refines the sweep's
    disparity by default (far_sources), closer to the truth; with cameras every 2nd view it does not."""
    from resample import ViewFillOptions, fill_views, plan_view_fill
    from resample.viewfill import far_sources

    axis = Axis(0.0, 0.08, 9)
    grid = LightFieldGrid.cube(["+z"], f=100.0, z_pi=0.0, x=axis, y=Axis(0.0, 0.0, 1), u=Axis(-48, 47, 96),
                               v=Axis(-40, 39, 80))
    delta = 0.85                    # u-steps per x-step (3.4 per camera spacing)
    truth = _plane_lightfield(grid, delta)
    cam = np.zeros(grid.shape, bool)
    cam[:, :, ::4] = True
    plan = plan_view_fill(grid, cam.astype(np.float32), ViewFillOptions(min_depth=0.4))
    assert far_sources(plan) and len(plan) == 6
    every2 = np.zeros(grid.shape, bool)
    every2[:, :, ::2] = True
    assert not far_sources(plan_view_fill(grid, every2.astype(np.float32), ViewFillOptions(min_depth=0.4)))
    W = np.where(cam, 1.0, 0.25).astype(np.float32)
    inner = np.zeros(grid.shape, bool)
    inner[..., 8:-8, 12:-12] = True
    tgt = inner & ~cam
    err, derr = {}, {}
    for refine in (None, False):
        opts = ViewFillOptions(min_depth=0.4, refine=refine)
        L6 = np.ascontiguousarray(np.where(cam, truth, 0.5).astype(np.float32)[..., None])
        disp = np.zeros(grid.shape, np.float32)
        fill_views(L6, W, plan_view_fill(grid, cam.astype(np.float32), opts), opts, disparity_out=disp)
        err[refine] = float(np.sqrt(np.mean((L6[..., 0] - truth)[tgt] ** 2)))
        derr[refine] = float(np.median(np.abs(disp[tgt] - delta)))
    # the disparity 3x closer (measured 0.0075 against 0.025 u-steps per x-step); the plane's smooth
    # texture hides it in the filled values (RMS 0.0034 either way)
    assert derr[None] < derr[False] / 2 and err[None] < 1.1 * err[False], (err, derr)


def test_view_fill_finds_both_cameras_however_many_views_lie_between_them():
    """Cameras every 6th view (6 views per camera spacing, a row): the default search radius is the
    sources' spacing, so every view between two cameras is filled from both, along the disparity,
    close to the truth; a fixed radius of 3 leaves every view but the half-way one with one source
    (the other 4–5 views away), unplanned, and the pull-push's depth-free blend they then keep is far off."""
    from resample import ViewFillOptions, fill_views, plan_view_fill
    from resample.viewfill import MIN_FILL_RADIUS, source_spacing

    grid = LightFieldGrid.cube(["+z"], f=100.0, z_pi=0.0, x=Axis(0.0, 0.12, 13), y=Axis(0.0, 0.0, 1),
                               u=Axis(-48, 47, 96), v=Axis(-40, 39, 80))
    delta = 0.4                     # u-steps per x-step (2.4 per camera spacing)
    truth = _plane_lightfield(grid, delta)
    cam = np.zeros(grid.shape, bool)
    cam[:, :, ::6] = True
    assert source_spacing(cam[0, :, :, 0, 0]) == 6 and MIN_FILL_RADIUS == 3
    inner = np.zeros(grid.shape, bool)
    inner[..., 8:-8, 12:-12] = True
    err, planned = {}, {}
    for radius in (None, 3):
        opts = ViewFillOptions(min_depth=0.4, max_radius=radius)
        plan = plan_view_fill(grid, cam.astype(np.float32), opts)
        planned[radius] = sorted(i for _, _, i in plan.targets)
        pp = push_pull(np.where(cam, truth, 0.0).astype(np.float32)[..., None], cam.astype(np.float32))
        L, W = np.ascontiguousarray(pp.L), np.ascontiguousarray(pp.W)   # the resampler's order: pull-push first
        fill_views(L, W, plan, opts)
        err[radius] = float(np.sqrt(np.mean((L[..., 0] - truth)[inner & ~cam] ** 2)))
    assert planned[None] == [1, 2, 3, 4, 5, 7, 8, 9, 10, 11]
    assert planned[3] == [3, 9]                                  # the others: one camera within 3 views
    assert err[None] < 0.25 * err[3], err


def _plane_grid_with_cameras():
    """The plane tests' grid (5 x 5 views 1 cm apart, f = 100, 80 x 96 directions) and the
    (F, Ny, Nx, Nv, Nu) mask of its camera views (every second view)."""
    axis = Axis(0.0, 0.04, 5)
    grid = LightFieldGrid.cube(["+z"], f=100.0, z_pi=0.0, x=axis, y=axis, u=Axis(-48, 47, 96), v=Axis(-40, 39, 80))
    cam = np.zeros(grid.shape, bool)
    cam[:, ::2, ::2] = True
    return grid, cam


def test_view_fill_from_cameras_off_the_views():
    """Cameras ~0.15 view steps off their grid views (a real rig): each camera view holds
    the plane seen from the camera centre. Measured from the centres
    (``camera_positions``), the filled views match the truth at the grid views; measured
    from the grid indices (the camera view taken as seen from the grid view) they are
    off by the disparity times the offset."""
    from resample import ViewFillOptions, fill_views, plan_view_fill

    grid, cam = _plane_grid_with_cameras()
    delta = 1.7
    rng = np.random.default_rng(11)
    pos = np.full((1, 5, 5, 2), np.nan)
    for j in range(0, 5, 2):
        for i in range(0, 5, 2):
            pos[0, j, i] = (j, i) + rng.normal(scale=0.15, size=2)
    iv, iu = np.meshgrid(np.arange(80), np.arange(96), indexing="ij")

    def plane_view(py, px):     # the plane of _plane_lightfield seen from fractional view (py, px)
        return _plane_texture(iu + delta * px, iv + delta * py)

    truth = _plane_lightfield(grid, delta)
    L = truth.copy()
    for j in range(0, 5, 2):
        for i in range(0, 5, 2):
            L[0, j, i] = plane_view(*pos[0, j, i])
    W = np.where(cam, 1.0, 0.25).astype(np.float32)
    opts = ViewFillOptions(min_depth=0.4, recentre=False)
    inner = np.zeros(grid.shape, bool)
    inner[..., 8:-8, 8:-8] = True
    rms = {}
    for name, kw in (("centres", {"camera_positions": pos}), ("indices", {"camera_views": cam[..., 0, 0]})):
        plan = plan_view_fill(grid, cam.astype(np.float32), opts, **kw)
        assert len(plan) == 16
        L6 = np.ascontiguousarray(L[..., None])
        fill_views(L6, W, plan, opts)
        rms[name] = float(np.sqrt(np.mean((L6[..., 0] - truth)[inner & ~cam] ** 2)))
        np.testing.assert_array_equal(L6[..., 0][cam], L[cam])           # camera views untouched
        if name == "centres":
            for (f, j, i), src, off in zip(plan.targets, plan.sources, plan.offsets):
                np.testing.assert_allclose(off, pos[f, src[:, 0], src[:, 1]] - [j, i])
    assert rms["centres"] <= RESAMPLE_VIEWFILL_RMS, rms
    assert rms["indices"] >= RESAMPLE_VIEWFILL_OFFGRID_GAIN * rms["centres"], rms


def test_view_fill_recentres_cameras_off_their_views_and_off_the_plane():
    """Cameras ~0.15 view steps off their grid views and ~1 mm off the focal plane (a real rig):
    a camera view holds the plane seen from the camera centre, each direction (u, v) crossing the
    focal plane at (x, y) − h (u, v) / f. Re-centred along the sweep's disparity (the default with
    positions), the camera views match the plane at their grid views, and so do the views filled
    from them; kept as measured, the camera views are off by the disparity times the offset."""
    from resample import ViewFillOptions, fill_views, plan_view_fill
    from resample.viewfill import data_positions

    grid, cam = _plane_grid_with_cameras()
    axis = grid.x
    delta = 1.7
    rng = np.random.default_rng(12)
    pos = np.full((1, 5, 5, 2), np.nan)
    height = np.full((1, 5, 5), np.nan)
    truth = _plane_lightfield(grid, delta)
    L = truth.copy()
    for j in range(0, 5, 2):
        for i in range(0, 5, 2):
            pos[0, j, i] = (j, i) + rng.normal(scale=0.15, size=2)
            height[0, j, i] = rng.normal(scale=0.001)
            L[0, j, i] = _plane_seen_from(grid, delta, pos[0, j, i], height[0, j, i], axis.step)
    W = np.where(cam, 1.0, 0.25).astype(np.float32)
    inner = np.zeros(grid.shape, bool)
    inner[..., 8:-8, 8:-8] = True
    rms_cam, rms_fill = {}, {}
    for recentre in (True, False):
        opts = ViewFillOptions(min_depth=0.4, recentre=recentre)
        plan = plan_view_fill(grid, cam.astype(np.float32), opts, camera_positions=pos, camera_heights=height)
        assert len(plan) == 16 and (len(plan.recentre) == 9 if recentre else plan.recentre is None)
        L6 = L[..., None].copy()
        fill_views(L6, W, plan, opts)
        rms_cam[recentre] = float(np.sqrt(np.mean((L6[..., 0] - truth)[inner & cam] ** 2)))
        rms_fill[recentre] = float(np.sqrt(np.mean((L6[..., 0] - truth)[inner & ~cam] ** 2)))
        moved = data_positions(plan, pos)
        np.testing.assert_array_equal(moved[cam[..., 0, 0]], np.argwhere(cam[0, ..., 0, 0]) if recentre
                                      else pos[cam[..., 0, 0]])
    assert rms_cam[True] <= RESAMPLE_VIEWFILL_RMS and rms_fill[True] <= RESAMPLE_VIEWFILL_RMS, (rms_cam, rms_fill)
    assert rms_cam[False] >= RESAMPLE_VIEWFILL_OFFGRID_GAIN * rms_cam[True], rms_cam


def test_view_fill_recentres_a_row_of_cameras_across_the_row():
    """A row of cameras (one view along y) ~0.15 view steps off their views along the row and across
    it, ~1 mm off the focal plane: the offsets across the row count in steps along it
    (``view_steps``), and the re-centring moves the camera views across the row too, onto the row's
    views; kept as measured they are off by the disparity times the offsets."""
    from resample import ViewFillOptions, fill_views, plan_view_fill
    from resample.viewfill import camera_positions, view_steps

    g2, _ = _plane_grid_with_cameras()
    row = LightFieldGrid.cube(["+z"], f=100.0, z_pi=0.0, x=Axis(0.0, 0.08, 9), y=Axis(0.0, 0.0, 1), u=g2.u, v=g2.v)
    assert view_steps(row) == (0.01, 0.01)
    # a centre 2 mm across the row is 0.2 steps off the row's one view
    at = camera_positions(row, np.array([[0.041, 0.002, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(at[0, 0, 4], [0.2, 4.1])
    delta = 1.7
    truth = _plane_lightfield(row, delta)            # the row's views at y = 0
    rng = np.random.default_rng(5)
    cam = np.zeros(row.shape, bool)
    cam[:, :, ::4] = True
    pos = np.full((1, 1, 9, 2), np.nan)
    height = np.full((1, 1, 9), np.nan)
    L = truth.copy()
    for i in (0, 4, 8):
        pos[0, 0, i] = (0.0, i) + rng.normal(scale=0.15, size=2)
        height[0, 0, i] = rng.normal(scale=0.001)
        L[0, 0, i] = _plane_seen_from(row, delta, pos[0, 0, i], height[0, 0, i], 0.01)
    W = np.where(cam, 1.0, 0.25).astype(np.float32)
    inner = np.zeros(row.shape, bool)
    inner[..., 8:-8, 8:-8] = True
    on_row = pos.copy()
    on_row[..., 0] = np.where(np.isnan(pos[..., 0]), np.nan, 0.0)      # the offsets across the row dropped
    rms = {}
    for name, recentre, p in (("recentred", True, pos), ("kept", False, pos), ("along the row only", True, on_row)):
        opts = ViewFillOptions(min_depth=0.4, recentre=recentre)
        plan = plan_view_fill(row, cam.astype(np.float32), opts, camera_positions=p, camera_heights=height)
        assert len(plan) == 6 and (len(plan.recentre) == 3 if recentre else plan.recentre is None)
        L6 = L[..., None].copy()
        fill_views(L6, W, plan, opts)
        rms[name] = float(np.sqrt(np.mean((L6[..., 0] - truth)[inner & cam] ** 2)))
    assert rms["recentred"] <= RESAMPLE_VIEWFILL_RMS, rms
    assert rms["kept"] >= RESAMPLE_VIEWFILL_OFFGRID_GAIN * rms["recentred"], rms
    assert rms["along the row only"] >= RESAMPLE_ROW_ACROSS_GAIN * rms["recentred"], rms


def test_view_fill_options_and_colour(tmp_path):
    """view_fill="pushpull" leaves the depth-free blend; the depth fill works channel by
    channel on colour frames (grey repeated into RGB gives the grey result) and keeps W."""
    _, models = _models(tmp_path)
    grid = auto_grid(models)
    rng = np.random.default_rng(3)
    frame = {c: rng.integers(0, 256, (30, 40), dtype=np.uint8) for c in models}
    r_pp = Resampler(models, grid, options=ResampleOptions(view_fill="pushpull")).resample(frame)
    r = Resampler(models, grid).resample(frame)
    r3 = Resampler(models, grid, channels=3).resample(frame)
    np.testing.assert_array_equal(r.W, r_pp.W)
    cam = np.zeros(grid.shape, bool)
    cam[:, ::2, ::2] = True
    np.testing.assert_array_equal(r.L[cam], r_pp.L[cam])
    assert np.abs(r.L - r_pp.L)[~cam].max() > 1e-3
    for k in range(3):   # (float rounding may break a tie between two disparities differently)
        assert np.mean(np.abs(r3.L[..., k] - r.L) > RESAMPLE_CONSTANT_ATOL) < 1e-3
    # re-filling the holes of the camera views too: measured samples stay, grey and colour agree
    from resample import ViewFillOptions

    holes = ResampleOptions(fill=ViewFillOptions(holes=True))
    rh = Resampler(models, grid, options=holes).resample(frame)
    rh3 = Resampler(models, grid, channels=3, options=holes).resample(frame)
    keep = cam & (r.W > 0.5)
    np.testing.assert_array_equal(rh.L[keep], r.L[keep])
    assert np.abs(rh.L - r.L)[cam & (r.W <= 0.5)].max() > 1e-3
    for k in range(3):
        assert np.mean(np.abs(rh3.L[..., k] - rh.L) > RESAMPLE_CONSTANT_ATOL) < 1e-3
    # cameras 1.5 mm off their views: re-centred (the default), grey and colour agree, and the camera
    # views move; with recentre=False they stay as the push-pull left them
    rig = _grid_rig(tmp_path)
    moved = true_cameramodels(rig, seed=4, perturb_position_m=0.0015, perturb_rotation_deg=2.0, perturb_focal_frac=0.01)
    g_moved = auto_grid(moved)
    rc, rc3 = Resampler(moved, g_moved).resample(frame), Resampler(moved, g_moved, channels=3).resample(frame)
    kept = Resampler(moved, g_moved, options=ResampleOptions(fill=ViewFillOptions(recentre=False))).resample(frame)
    pp = Resampler(moved, g_moved, options=ResampleOptions(view_fill="pushpull")).resample(frame)
    np.testing.assert_array_equal(kept.L[cam], pp.L[cam])
    assert np.abs(rc.L - kept.L)[cam & (rc.W > 0.5)].max() > 1e-3
    for k in range(3):
        assert np.mean(np.abs(rc3.L[..., k] - rc.L) > RESAMPLE_CONSTANT_ATOL) < 1e-3
    with pytest.raises(ValueError):
        ResampleOptions(view_fill="bogus")


def test_grey_blend_matches_the_general_blend():
    """The grey blend's shortcuts (two passes; sources beside, above or below the target read
    along one row or column) give the general blend's result, with sources reaching off their views and
    confidences of 0 included."""
    from resample.viewfill import _blend, _blend_grey, _blend_scratch

    rng = np.random.default_rng(5)
    Nv, Nu = 23, 31
    X = rng.random((3, 3, Nv, Nu)).astype(np.float32)
    A = rng.random((3, 3, Nv, Nu)).astype(np.float32)
    A[A < 0.2] = 0.0
    d = rng.uniform(-3.0, 4.0, (Nv, Nu)).astype(np.float32)
    unreached = 0
    for src in ([[1, 0], [1, 2]], [[0, 1], [2, 1]], [[0, 0], [0, 2], [2, 0], [2, 2]], [[1, 0], [0, 1], [2, 2]], [[1, 2], [2, 2]]):
        src = np.array(src, np.int64)
        S = src.shape[0]
        off = (src - 1).astype(np.float64)
        sw = rng.uniform(0.5, 1.0, S).astype(np.float32)
        sw /= sw.sum()
        out = np.full((Nv, Nu, 1), -1.0, np.float32)
        _blend(X[..., None], A, src, S, off[:, 0].copy(), off[:, 1].copy(), sw, 1.3, d, out,
               np.empty(Nu, np.float32), np.empty((Nu, 1), np.float32))
        out_g = np.full((Nv, Nu), -1.0, np.float32)
        _blend_grey(X, A, src, S, off[:, 0].copy(), off[:, 1].copy(), sw, 1.3, d, out_g, _blend_scratch(Nu))
        np.testing.assert_allclose(out_g, out[..., 0], atol=RESAMPLE_CONSTANT_ATOL)
        unreached += int(np.sum(out_g == -1.0))
    assert unreached > 0                    # some samples reach no source and keep their value
