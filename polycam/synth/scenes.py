"""Synthetic scenes as data: primitives, textures and lighting in numpy arrays.

A :class:`Scene` is what the ray caster (:mod:`polycam.synth.raycast`) traces:

- spheres (centres, radii) with a band-limited solid texture each, indexed by a
  uniform grid (:class:`SphereGrid`, CSR cell lists) when there are many;
- axis-aligned boxes, seen from outside (objects) or from inside (a room);
- rectangles with a procedural or an image texture (calibration boards);
- a sky: a smooth function of the world direction, seen where nothing is hit.

Radiance is Lambertian and view-independent: ``albedo * (ambient + diffuse *
max(0, n . l))`` with a static directional light ``l`` and the normal ``n`` of the
side facing the viewer, so a surface point has one radiance from every
viewpoint (plenoptic brightness constancy holds exactly). Values are in [0, 1].

Solid textures are ``albedo = clip(base + contrast * g(S))`` with
``S = sum_k a_k cos(w_k . p + phi_k)`` normalised to unit variance and
``g(S) = sharp S / sqrt(1 + (sharp S)^2)``, a soft threshold into (-1, 1) that
turns the waves into blobs with soft edges (``g(S) = S`` for ``sharp = 0``); ``p`` is the point
in the sphere's own frame (centre at 0), in world coordinates for boxes, and in
the rectangle's (s, t, 0) coordinates for rectangles.

Scene builders (all seeded and reproducible; world frame = rig frame at frame 0,
camera convention x right, y down, z forward):

- :func:`spheres_scene`: the paper's Sect. 5 scene, unit spheres filling the horizon
  in all directions (or forward only) from distance ``D``;
- :func:`room_scene`: a textured box room with spheres and boxes 1-4 m ahead;
- :meth:`Scene.with_image_rect`: add a textured plane (calibration board).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = [
    "Textures",
    "SphereGrid",
    "Scene",
    "TextureBuilder",
    "spheres_scene",
    "MAX_SPHERES",
    "room_scene",
    "make_scene",
    "SCENE_NAMES",
]

SCENE_NAMES = ("spheres", "spheres-forward", "room")

# Salts that give every random component of a scene its own stream.
_SALT_LAYOUT, _SALT_TEXTURE, _SALT_SKY = 11, 12, 13


@dataclass(frozen=True)
class Textures:
    """All textures of a scene, packed for the ray caster. T textures, W waves, P pixels."""

    kind: np.ndarray
    """(T,) int32: 0 = solid waves, 1 = image."""
    param: np.ndarray
    """(T, 4) float64: ``base, contrast, sharp, 0`` (solid textures)."""
    wave_start: np.ndarray
    """(T + 1,) int64: waves of texture i are ``wave_start[i]:wave_start[i + 1]``."""
    waves: np.ndarray
    """(5, W) float64, one wave per column: rows ``kx, ky, kz`` [rad per unit of p] (wave
    vector), ``phi`` [rad] (phase), ``a`` (amplitude; normalised so S has unit variance
    per texture). Structure-of-arrays so the caster's wave loop vectorises."""
    img_start: np.ndarray
    """(T,) int64: offset of image i in ``img_data`` (row-major)."""
    img_shape: np.ndarray
    """(T, 2) int64: image height, width [px] (0, 0 for solid textures)."""
    img_data: np.ndarray
    """(P,) float32 in [0, 1]: all image pixels."""

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @property
    def max_waves(self) -> int:
        """Most waves of any one texture."""
        return int(np.diff(self.wave_start).max()) if len(self) else 0


class TextureBuilder:
    """Accumulates textures and packs them into :class:`Textures`."""

    def __init__(self, base: Textures | None = None):
        self._kind: list[int] = []
        self._param: list[tuple[float, float, float, float]] = []
        self._waves: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._images: list[np.ndarray | None] = []
        if base is not None:
            for i in range(len(base)):
                self._kind.append(int(base.kind[i]))
                self._param.append(tuple(float(v) for v in base.param[i]))
                a, b = base.wave_start[i], base.wave_start[i + 1]
                self._waves.append((base.waves[:3, a:b].T, base.waves[3, a:b], base.waves[4, a:b]))
                if base.kind[i] == 1:
                    h, w = base.img_shape[i]
                    s = base.img_start[i]
                    self._images.append(base.img_data[s:s + h * w].reshape(h, w))
                else:
                    self._images.append(None)

    def waves(self, rng: np.random.Generator, *, base: float, contrast: float,
              octaves: list[tuple[int, float, float]], sharp: float = 0.0, decay: float = 1.0) -> int:
        """Add a solid texture; returns its index.

        octaves: list of ``(count, k_min, k_max)``: ``count`` waves with random
            directions and wave numbers uniform in ``[k_min, k_max]`` [rad per unit].
            Octave ``o`` gets relative amplitude ``decay ** o``.
        """
        ks, phis, amps = [], [], []
        for o, (count, kmin, kmax) in enumerate(octaves):
            dirs = rng.normal(size=(count, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            mags = rng.uniform(kmin, kmax, size=count)
            ks.append(dirs * mags[:, None])
            phis.append(rng.uniform(0.0, 2.0 * np.pi, size=count))
            amps.append(rng.uniform(0.5, 1.0, size=count) * decay**o)
        k = np.concatenate(ks)
        phi = np.concatenate(phis)
        a = np.concatenate(amps)
        a *= math.sqrt(2.0 / float(np.sum(a * a)))     # unit variance of S
        self._kind.append(0)
        self._param.append((float(base), float(contrast), float(sharp), 0.0))
        self._waves.append((k, phi, a))
        self._images.append(None)
        return len(self._kind) - 1

    def image(self, img: np.ndarray) -> int:
        """Add an image texture (H, W) float in [0, 1] (uint8 is scaled by 1/255); returns its index."""
        img = np.asarray(img)
        if img.ndim != 2:
            raise ValueError("image texture must be (H, W) grey")
        if img.dtype == np.uint8:
            img = img.astype(np.float32) / 255.0
        elif img.dtype == np.uint16:
            img = img.astype(np.float32) / 65535.0
        self._kind.append(1)
        self._param.append((0.5, 0.0, 0.0, 0.0))
        self._waves.append((np.zeros((0, 3)), np.zeros(0), np.zeros(0)))
        self._images.append(np.ascontiguousarray(img, dtype=np.float32))
        return len(self._kind) - 1

    def build(self) -> Textures:
        n = len(self._kind)
        counts = [w[0].shape[0] for w in self._waves]
        wave_start = np.zeros(n + 1, np.int64)
        wave_start[1:] = np.cumsum(counts)
        img_start = np.zeros(n, np.int64)
        img_shape = np.zeros((n, 2), np.int64)
        chunks, off = [], 0
        for i, im in enumerate(self._images):
            img_start[i] = off
            if im is not None:
                img_shape[i] = im.shape
                chunks.append(im.ravel())
                off += im.size

        def cat(parts, shape, dtype):
            return (np.ascontiguousarray(np.concatenate(parts), dtype=dtype) if parts
                    else np.zeros(shape, dtype))

        return Textures(
            kind=np.array(self._kind, np.int32),
            param=np.array(self._param, np.float64).reshape(n, 4),
            wave_start=wave_start,
            waves=np.ascontiguousarray(np.vstack([
                cat([w[0] for w in self._waves], (0, 3), np.float64).reshape(-1, 3).T,
                cat([w[1] for w in self._waves], (0,), np.float64)[None],
                cat([w[2] for w in self._waves], (0,), np.float64)[None]])),
            img_start=img_start,
            img_shape=img_shape,
            img_data=cat(chunks, (0,), np.float32),
        )


@dataclass(frozen=True)
class SphereGrid:
    """Uniform grid over the spheres' bounding box with CSR cell lists.

    Cell ``(ix, iy, iz)`` has flat index ``ix + nx * (iy + ny * iz)`` and holds the
    spheres whose bounding box overlaps it: ``items[start[c]:start[c + 1]]``.
    An empty grid (dims 0) makes the caster test every sphere.
    """

    lo: np.ndarray
    """(3,) [m] world corner of cell (0, 0, 0)."""
    cell: np.ndarray
    """(1,) [m] cell edge length."""
    dims: np.ndarray
    """(3,) int64: nx, ny, nz."""
    start: np.ndarray
    """(nx*ny*nz + 1,) int64 CSR offsets."""
    items: np.ndarray
    """(M,) int32 sphere indices."""

    @classmethod
    def empty(cls) -> "SphereGrid":
        return cls(np.zeros(3), np.ones(1), np.zeros(3, np.int64), np.zeros(1, np.int64),
                   np.zeros(0, np.int32))

    @classmethod
    def build(cls, centres: np.ndarray, radii: np.ndarray, cell: float | None = None,
              max_cells: int = 4_000_000) -> "SphereGrid":
        """Grid for spheres ``centres`` (N, 3) [m], ``radii`` (N,) [m].

        Default cell edge: the largest diameter (so each sphere overlaps at most
        2x2x2 cells), grown if the grid would exceed ``max_cells``.
        """
        centres = np.asarray(centres, float).reshape(-1, 3)
        radii = np.asarray(radii, float).reshape(-1)
        if centres.shape[0] == 0:
            return cls.empty()
        rmax = float(radii.max())
        lo = (centres - radii[:, None]).min(axis=0) - 1e-6
        hi = (centres + radii[:, None]).max(axis=0) + 1e-6
        h = max(2.0 * rmax, float(cell) if cell else 0.0)
        while np.prod(np.ceil((hi - lo) / h)) > max_cells:
            h *= 1.25
        dims = np.maximum(np.ceil((hi - lo) / h).astype(np.int64), 1)
        i_lo = np.clip(np.floor((centres - radii[:, None] - lo) / h).astype(np.int64), 0, dims - 1)
        i_hi = np.clip(np.floor((centres + radii[:, None] - lo) / h).astype(np.int64), 0, dims - 1)
        span = i_hi - i_lo + 1
        n_off = int(span.max())
        cells, ids = [], []
        rng_off = np.arange(n_off)
        ox, oy, oz = np.meshgrid(rng_off, rng_off, rng_off, indexing="ij")
        offs = np.stack([ox.ravel(), oy.ravel(), oz.ravel()], axis=1)      # (n_off^3, 3)
        for off in offs:
            idx = i_lo + off
            ok = np.all(idx <= i_hi, axis=1)
            c = idx[ok, 0] + dims[0] * (idx[ok, 1] + dims[1] * idx[ok, 2])
            cells.append(c)
            ids.append(np.nonzero(ok)[0])
        cells = np.concatenate(cells)
        ids = np.concatenate(ids)
        order = np.lexsort((ids, cells))
        cells, ids = cells[order], ids[order]
        ncell = int(np.prod(dims))
        start = np.zeros(ncell + 1, np.int64)
        start[1:] = np.cumsum(np.bincount(cells, minlength=ncell))
        return cls(lo.astype(np.float64), np.array([h], np.float64), dims, start, ids.astype(np.int32))


def _f64(a, shape):
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(shape))


@dataclass(frozen=True)
class Scene:
    """A static scene in the world frame [m]. Ns spheres, Nb boxes, Nr rectangles."""

    name: str
    sphere_centres: np.ndarray
    """(Ns, 3) [m]."""
    sphere_radii: np.ndarray
    """(Ns,) [m]."""
    sphere_texture: np.ndarray
    """(Ns,) int32 texture index."""
    box_lo: np.ndarray
    """(Nb, 3) [m] minimum corners of axis-aligned boxes."""
    box_hi: np.ndarray
    """(Nb, 3) [m] maximum corners."""
    box_texture: np.ndarray
    """(Nb,) int32."""
    rect_origin: np.ndarray
    """(Nr, 3) [m] origin of each rectangle's (s, t) coordinates."""
    rect_ex: np.ndarray
    """(Nr, 3) unit s axis."""
    rect_ey: np.ndarray
    """(Nr, 3) unit t axis, orthogonal to s; the normal is ``ex x ey``."""
    rect_bounds: np.ndarray
    """(Nr, 4) [m] ``s_min, s_max, t_min, t_max``."""
    rect_uv: np.ndarray
    """(Nr, 2, 3): image-texture pixel coords ``(col, row) = M[:, :2] @ (s, t) + M[:, 2]``."""
    rect_texture: np.ndarray
    """(Nr,) int32."""
    textures: Textures
    sky_texture: int
    """Texture evaluated at the unit world direction where nothing is hit (-1: constant 0.5)."""
    light: np.ndarray
    """(3,) unit vector towards the directional light, world frame."""
    ambient: float
    diffuse: float
    grid: SphereGrid
    distance: float = 0.0
    """[m] the builder's distance parameter (nearest sphere surface / far wall)."""
    seed: int = 0
    specular: float = 0.0
    """Strength of a white Phong highlight added to every surface's radiance,
    ``specular · max(0, r · v)^shininess`` (r the light mirrored about the normal, v towards the
    viewer): a view-dependent, non-Lambertian part, so one surface point differs between the
    views (0: Lambertian, the default). Light fields stay what the plenoptic constraint assumes
    (a static scene's radiance per ray); paper Eq. 6, the resampler's view fill and the warp's
    blend along the disparity assume Lambertian surfaces."""
    shininess: float = 32.0
    """Phong exponent of ``specular`` (32: the highlight falls to half 12° off the mirror direction)."""

    @property
    def num_primitives(self) -> int:
        return int(self.sphere_radii.shape[0] + self.box_lo.shape[0] + self.rect_origin.shape[0])

    def kernel_args(self) -> tuple:
        """The arrays in the order the ray caster's kernel takes them."""
        t = self.textures
        return (self.sphere_centres, self.sphere_radii, self.sphere_texture,
                self.grid.lo, self.grid.cell, self.grid.dims, self.grid.start, self.grid.items,
                self.box_lo, self.box_hi, self.box_texture,
                self.rect_origin, self.rect_ex, self.rect_ey, self.rect_bounds, self.rect_uv,
                self.rect_texture,
                t.kind, t.param, t.wave_start, t.waves, np.int64(t.max_waves), t.img_start, t.img_shape,
                t.img_data,
                np.int64(self.sky_texture), self.light,
                np.array([self.ambient, self.diffuse, self.specular, self.shininess]))

    def with_image_rect(self, image: np.ndarray, T_world_rect: np.ndarray, bounds, uv_from_st: np.ndarray
                        ) -> tuple["Scene", int]:
        """This scene plus a rectangle showing ``image``; returns (scene, rectangle index).

        image: (H, W) grey texture, uint8/uint16 or float in [0, 1].
        T_world_rect: (4, 4) pose of the rectangle frame: its x, y axes are the s, t
            axes; the rectangle lies in its z = 0 plane; seen from either side.
        bounds: ``(s_min, s_max, t_min, t_max)`` [m] extent in that frame.
        uv_from_st: (2, 3) affine map from (s, t) [m] to image (col, row) [px]
            (pixel centres at integers), sampled bilinearly.
        """
        tb = TextureBuilder(self.textures)
        ti = tb.image(image)
        T = np.asarray(T_world_rect, float)
        k = self.rect_origin.shape[0]
        sc = dataclasses.replace(
            self,
            rect_origin=_f64(np.vstack([self.rect_origin, T[:3, 3]]), (-1, 3)),
            rect_ex=_f64(np.vstack([self.rect_ex, T[:3, 0]]), (-1, 3)),
            rect_ey=_f64(np.vstack([self.rect_ey, T[:3, 1]]), (-1, 3)),
            rect_bounds=_f64(np.vstack([self.rect_bounds, np.asarray(bounds, float)]), (-1, 4)),
            rect_uv=_f64(np.concatenate([self.rect_uv, np.asarray(uv_from_st, float)[None]]), (-1, 2, 3)),
            rect_texture=np.append(self.rect_texture, np.int32(ti)).astype(np.int32),
            textures=tb.build(),
        )
        return sc, k

    def with_rect_pose(self, k: int, T_world_rect: np.ndarray) -> "Scene":
        """This scene with rectangle ``k`` moved to pose ``T_world_rect`` (4, 4)."""
        T = np.asarray(T_world_rect, float)
        o, ex, ey = self.rect_origin.copy(), self.rect_ex.copy(), self.rect_ey.copy()
        o[k], ex[k], ey[k] = T[:3, 3], T[:3, 0], T[:3, 1]
        return dataclasses.replace(self, rect_origin=o, rect_ex=ex, rect_ey=ey)


def _empty_prims() -> dict:
    return dict(
        sphere_centres=np.zeros((0, 3)), sphere_radii=np.zeros(0), sphere_texture=np.zeros(0, np.int32),
        box_lo=np.zeros((0, 3)), box_hi=np.zeros((0, 3)), box_texture=np.zeros(0, np.int32),
        rect_origin=np.zeros((0, 3)), rect_ex=np.zeros((0, 3)), rect_ey=np.zeros((0, 3)),
        rect_bounds=np.zeros((0, 4)), rect_uv=np.zeros((0, 2, 3)), rect_texture=np.zeros(0, np.int32),
    )


def _light_dir() -> np.ndarray:
    l = np.array([-0.3, -0.6, -0.75])         # from above (y down), left, and behind the rig
    return l / np.linalg.norm(l)


MAX_SPHERES = 1_000_000
"""The most spheres :func:`spheres_scene` builds (~40 s on 2 cores at a million; their number grows as
the distance squared: ~220 m for all directions, ~380 m for the forward cone)."""


def spheres_scene(distance: float = 8.0, *, seed: int = 0, faces: str = "all", radius: float = 1.0,
                  optical_depth: float = 5.0, thickness: float = 6.0, waves: int = 24,
                  cone_deg: float = 70.0) -> Scene:
    """The paper's Sect. 5 scene: textured spheres filling the horizon.

    distance: [m] distance from the rig origin to the nearest sphere surface:
        centres are uniform in the spherical shell ``distance + radius <= |c| <=
        distance + radius + thickness``.
    faces: ``"all"`` (every direction; the six cube faces all see spheres) or
        ``"forward"`` (only centres within ``cone_deg`` of +z).
    optical_depth: expected number of spheres a ray crosses in the shell; the
        background (sky) fraction is about ``exp(-optical_depth)``.
    waves: cosine waves per sphere texture, wave numbers uniform in [1, 4] / radius.
    Spheres may overlap. Sky: a smooth function of direction. More than :data:`MAX_SPHERES`
    spheres (a distance beyond ~220 m for all directions) is an :class:`~polycam.errors.InputError`.
    """
    if distance <= 0 or radius <= 0 or thickness <= 0:
        raise ValueError("distance, radius and thickness must be > 0")
    if faces not in ("all", "forward"):
        raise ValueError("faces must be 'all' or 'forward'")
    rng = np.random.default_rng([seed, _SALT_LAYOUT])
    r_in = distance + radius
    r_out = r_in + thickness
    vol = 4.0 / 3.0 * np.pi * (r_out**3 - r_in**3)
    cos_cone = 1.0
    if faces == "forward":
        cos_cone = math.cos(math.radians(cone_deg))
        vol *= (1.0 - cos_cone) / 2.0
    density = optical_depth / (np.pi * radius**2 * thickness)
    n = max(1, int(round(density * vol)))
    if n > MAX_SPHERES:
        # the shell's volume grows as distance²: 2000 m would need ~8e7 spheres (hours, gigabytes)
        d_max = distance * math.sqrt(MAX_SPHERES / n)
        raise InputError(f"the spheres scene at {distance:g} m needs {n:,} spheres of radius {radius:g} m to fill "
                         f"the horizon (at most {MAX_SPHERES:,}: a distance up to about {d_max:.0f} m)")
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    if faces == "forward":
        # uniform on the spherical cap z >= cos_cone
        z = rng.uniform(cos_cone, 1.0, size=n)
        phi = rng.uniform(0.0, 2.0 * np.pi, size=n)
        s = np.sqrt(1.0 - z * z)
        dirs = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    rad = np.cbrt(rng.uniform(r_in**3, r_out**3, size=n))
    centres = dirs * rad[:, None]

    trng = np.random.default_rng([seed, _SALT_TEXTURE])
    tb = TextureBuilder()
    tex = np.empty(n, np.int32)
    for i in range(n):
        tex[i] = tb.waves(trng, base=float(trng.uniform(0.35, 0.65)), contrast=0.3,
                          octaves=[(waves, 1.0 / radius, 4.0 / radius)])
    sky = tb.waves(np.random.default_rng([seed, _SALT_SKY]), base=0.55, contrast=0.12,
                   octaves=[(8, 1.0, 3.0)])
    prims = _empty_prims()
    prims.update(sphere_centres=_f64(centres, (-1, 3)), sphere_radii=np.full(n, float(radius)),
                 sphere_texture=tex)
    return Scene(name="spheres" if faces == "all" else "spheres-forward", textures=tb.build(),
                 sky_texture=sky, light=_light_dir(), ambient=0.5, diffuse=0.5,
                 grid=SphereGrid.build(centres, prims["sphere_radii"]), distance=float(distance),
                 seed=int(seed), **prims)


# Room textures: wave numbers [rad/m] per octave (wavelengths ~2.5 m down to ~9 cm),
# relative amplitude 0.65 per octave, soft threshold 2.5: camouflage-like blobs.
_ROOM_OCTAVES = [(6, 2.5, 5.0), (6, 6.0, 12.0), (6, 15.0, 30.0), (6, 40.0, 70.0)]
_ROOM_DECAY, _ROOM_SHARP = 0.65, 2.5
# Objects (0.1-0.6 m) get finer octaves (wavelengths ~1 m down to ~4 cm) so they show blobs too.
_OBJECT_OCTAVES = [(6, 6.0, 12.0), (6, 15.0, 30.0), (6, 40.0, 70.0), (6, 90.0, 150.0)]
_OBJECT_DECAY = 0.75


def room_scene(distance: float = 4.0, *, seed: int = 0, n_spheres: int = 5, n_boxes: int = 5) -> Scene:
    """A textured box room seen from inside, with spheres and boxes 1-4 m ahead.

    distance: [m] from the rig origin to the far wall (z = distance). The room spans
        ``|x| <= max(1.5, 0.6 distance)``, y in [-1.4, 1.2] (floor at y = +1.2, y is
        down), z in [-1.5, distance]. Objects (radius 0.1-0.35 m spheres, 0.15-0.6 m
        boxes, some on the floor) are placed at depths 1 m to ``min(4, distance -
        0.5)`` inside a 60 x 45 deg cone around +z; fewer when the room is too shallow.
    Textures are multi-octave solid waves (wavelengths ~2.5 m to ~9 cm) with a
    soft-threshold nonlinearity, so there are blob edges for feature matching while
    staying smooth at the pixel scale after anti-aliasing; box faces add sharp edges.
    """
    if distance <= 0.2:
        raise ValueError("room distance must be > 0.2 m")
    rng = np.random.default_rng([seed, _SALT_LAYOUT])
    trng = np.random.default_rng([seed, _SALT_TEXTURE])
    tb = TextureBuilder()
    half_w = max(1.5, 0.6 * distance)
    floor_y, ceil_y, back_z = 1.2, -1.4, -1.5
    boxes_lo = [[-half_w, ceil_y, back_z]]
    boxes_hi = [[half_w, floor_y, distance]]
    boxes_tex = [tb.waves(trng, base=0.55, contrast=0.22, octaves=_ROOM_OCTAVES, sharp=_ROOM_SHARP,
                           decay=_ROOM_DECAY)]
    centres, radii, sph_tex = [], [], []
    placed: list[tuple[np.ndarray, float]] = []     # bounding spheres, to avoid overlaps
    z_max = min(4.0, distance - 0.5)

    def free(c, r):
        return all(np.linalg.norm(c - c2) > r + r2 + 0.05 for c2, r2 in placed)

    def place(rad_xyz, on_floor):
        for _ in range(100):
            z = rng.uniform(1.0, z_max)
            x = rng.uniform(-1, 1) * min(0.5 * z, half_w - 0.1 - rad_xyz[0])
            if on_floor:
                y = floor_y - rad_xyz[1]
            else:
                y = rng.uniform(-1, 1) * min(0.35 * z, 1.0)
            c = np.array([x, y, z])
            r = float(np.linalg.norm(rad_xyz))
            if (c[1] - rad_xyz[1] >= ceil_y and c[1] + rad_xyz[1] <= floor_y and c[2] + rad_xyz[2] < distance
                    and free(c, r)):
                placed.append((c, r))
                return c
        return None

    if z_max > 1.0:
        for i in range(n_spheres):
            r = float(rng.uniform(0.1, 0.35))
            c = place(np.array([r, r, r]), on_floor=bool(rng.random() < 0.3))
            if c is not None:
                centres.append(c)
                radii.append(r)
                sph_tex.append(tb.waves(trng, base=float(rng.uniform(0.3, 0.7)), contrast=0.28,
                                        octaves=_OBJECT_OCTAVES, sharp=_ROOM_SHARP, decay=_OBJECT_DECAY))
        for i in range(n_boxes):
            half = rng.uniform(0.075, 0.3, size=3)
            c = place(half, on_floor=bool(rng.random() < 0.5))
            if c is not None:
                boxes_lo.append(c - half)
                boxes_hi.append(c + half)
                boxes_tex.append(tb.waves(trng, base=float(rng.uniform(0.25, 0.75)), contrast=0.28,
                                          octaves=_OBJECT_OCTAVES, sharp=_ROOM_SHARP, decay=_OBJECT_DECAY))
    prims = _empty_prims()
    if centres:
        prims.update(sphere_centres=_f64(centres, (-1, 3)), sphere_radii=_f64(radii, (-1,)),
                     sphere_texture=np.array(sph_tex, np.int32))
    prims.update(box_lo=_f64(boxes_lo, (-1, 3)), box_hi=_f64(boxes_hi, (-1, 3)),
                 box_texture=np.array(boxes_tex, np.int32))
    # Few spheres: brute force beats a grid.
    grid = SphereGrid.empty() if len(centres) < 16 else SphereGrid.build(prims["sphere_centres"],
                                                                         prims["sphere_radii"])
    return Scene(name="room", textures=tb.build(), sky_texture=-1, light=_light_dir(), ambient=0.45,
                 diffuse=0.55, grid=grid, distance=float(distance), seed=int(seed), **prims)


def make_scene(name: str, distance: float, seed: int = 0) -> Scene:
    """A scene by name: ``spheres`` (all directions), ``spheres-forward`` or ``room``."""
    if name == "spheres":
        return spheres_scene(distance, seed=seed, faces="all")
    if name == "spheres-forward":
        return spheres_scene(distance, seed=seed, faces="forward")
    if name == "room":
        return room_scene(distance, seed=seed)
    raise ValueError(f"unknown synthetic scene {name!r}; expected one of {', '.join(SCENE_NAMES)}")
