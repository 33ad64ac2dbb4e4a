"""The procedural scene: its camera, renders and panoramas, and its radiance field."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from snell_bench.imaging.equirect import PanoramaCamera, equirect_grid, equirect_to_direction
from snell_bench.scene.camera import Camera
from snell_bench.scene.procedural.builder import Builder
from snell_bench.scene.procedural.color import srgb_encode
from snell_bench.scene.procedural.frames import Layout
from snell_bench.scene.procedural.layouts import build_room
from snell_bench.scene.procedural.noise import Noise
from snell_bench.scene.procedural.outdoor import build_outdoor
from snell_bench.scene.procedural.shading import Light, RadianceField

__all__ = ["SCENE_KINDS", "SceneRender", "ProceduralScene"]

SCENE_KINDS = ("room", "outdoor", "kitchen")


@dataclass
class SceneRender:
    """A perspective render of a procedural scene.

    Attributes:
        image: sRGB image (H, W, 3), float32 in [0, 1].
        depth: Exact z-depth (H, W) float32 at pixel centres (finite, > 0).
        camera: The camera.
    """

    image: np.ndarray
    depth: np.ndarray
    camera: Camera


class ProceduralScene:
    """A parametric textured 3-D scene with exactly known geometry, in its camera's frame.

    All methods take and return camera-frame quantities (OpenCV axes, metres).

    Args:
        kind: One of :data:`SCENE_KINDS`: ``"room"`` (living room with a wooden table),
            ``"outdoor"`` (stone table on open ground, mountains, sky) or ``"kitchen"`` (marble
            island).
        seed: Non-negative int; selects colours, layout, light and camera pose.

    Attributes:
        up: (3,) unit world-up direction in the camera frame.
        support_point: (3,) camera-frame point on the (horizontal) top of the supporting surface
            (the table / stone table / island) near the image centre column, lower half, where an
            object can stand. Nothing else occupies the surface within ~0.25 m of it.
        support_normal: (3,) equal to ``up``.
        fov_x_deg: Horizontal field of view of :meth:`camera`.
        camera_height: Height of the camera above the floor / ground (m).
        pitch_deg: Downward pitch of the camera (degrees).

    Raises:
        ValueError: If ``kind`` is unknown or ``seed`` is negative.
        TypeError: If ``seed`` is not an int.
    """

    def __reduce__(self):
        """A scene is a function of its kind and seed: pickled as those two (its textures are
        closures), and rebuilt, identical, when unpickled."""
        return type(self), (self.kind, self.seed)

    def __init__(self, kind: str = "room", seed: int = 0):
        if kind not in SCENE_KINDS:
            raise ValueError(f"unknown scene kind {kind!r}; valid kinds are {', '.join(map(repr, SCENE_KINDS))}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int, got {type(seed).__name__} {seed!r}")
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self.kind = kind
        self.seed = int(seed)
        rng = np.random.default_rng(self.seed)
        noise = Noise(rng)
        builder = Builder()
        self.fov_x_deg = float(rng.uniform(58.0, 68.0))
        if kind == "outdoor":
            layout = build_outdoor(builder, noise, rng, self.fov_x_deg)
        else:
            layout = build_room(builder, noise, rng, self.fov_x_deg, kitchen=(kind == "kitchen"))
        self._finalize(builder, layout)

    # ------------------------------------------------------------------ public API
    def camera(self, width: int = 1280, height: int = 720) -> Camera:
        """The scene's pinhole camera at the given resolution (square pixels, centred principal point)."""
        return Camera.from_fov(width, height, self.fov_x_deg)

    def render(self, width: int = 1280, height: int = 720, supersample: int = 1) -> SceneRender:
        """Renders the object-free image, its exact z-depth and the camera.

        Args:
            width: Image width (pixels).
            height: Image height (pixels).
            supersample: ``s`` averages s×s stratified sub-pixel samples (in linear space) for the
                image; depth is always cast through the pixel centres.

        Returns:
            The render.

        Raises:
            ValueError: If ``supersample`` is not a positive integer.
        """
        s = self._check_ss(supersample)
        cam = self.camera(width, height)
        d = cam.pixel_rays()  # (H, W, 3) unit
        origins = np.zeros(3)
        if s == 1:
            rad, t = self.radiance(origins, d.reshape(-1, 3))
            img = rad.reshape(height, width, 3)
        else:
            t = self._field.cast_t(np.zeros((1, 3)), d.reshape(-1, 3))
            grid = cam.pixel_grid()
            acc = np.zeros((height * width, 3), np.float64)
            for oy, ox in self._offsets(s):
                ds = cam.pixel_rays(grid + np.array([ox, oy]))
                acc += self.radiance(origins, ds.reshape(-1, 3))[0]
            img = (acc / (s * s)).reshape(height, width, 3)
        depth = (t.astype(np.float64) * d[..., 2].reshape(-1)).reshape(height, width).astype(np.float32)
        return SceneRender(image=srgb_encode(img), depth=depth, camera=cam)

    def render_panorama(
        self, center=(0.0, 0.0, 0.0), height: int = 1024, up=None, forward=(0.0, 0.0, 1.0), supersample: int = 1
    ) -> np.ndarray:
        """Renders an equirectangular panorama from a camera-frame point.

        It is oriented by ``PanoramaCamera.level(center, up or self.up, forward, height)``: its top
        row looks along ``up``, its centre column along ``forward`` made horizontal.

        Args:
            center: Camera-frame viewpoint (3,).
            height: Panorama height; the width is ``2 * height``.
            up: Up direction (default :attr:`up`).
            forward: Direction of the centre column.
            supersample: ``s`` averages s×s stratified sub-pixel samples (in linear space).

        Returns:
            The panorama ``(height, 2 * height, 3)``, float32 sRGB.

        Raises:
            ValueError: If ``supersample`` is not a positive integer.
        """
        s = self._check_ss(supersample)
        pc = PanoramaCamera.level(np.asarray(center, np.float64), self.up if up is None else up, forward, height)
        if s == 1:
            rad = self.radiance(pc.center, pc.directions().reshape(-1, 3))[0]
        else:
            grid = equirect_grid(height)
            rad = np.zeros((height * 2 * height, 3), np.float64)
            for oy, ox in self._offsets(s):
                dirs = equirect_to_direction(grid + np.array([ox, oy]), height) @ pc.rotation.T
                rad += self.radiance(pc.center, dirs.reshape(-1, 3))[0]
            rad /= s * s
        return srgb_encode(rad.reshape(height, 2 * height, 3))

    def radiance(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear-RGB radiance arriving along rays, and their hit distances.

        Args:
            origins: Camera-frame ray origins, (N, 3) or (3,) (broadcast).
            directions: Camera-frame ray directions, (N, 3); need not be unit (they are
                normalised).

        Returns:
            ``(radiance (N, 3) float32, t (N,) float32)`` with ``t`` the Euclidean distance to the
            first surface (``inf`` where nothing is hit; such rays get the scene's environment
            radiance).

        Raises:
            ValueError: If a direction is zero or not finite.
        """
        return self._field.radiance(origins, directions)

    def albedo(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The diffuse albedo each pixel centre of ``camera`` sees, ``(H, W, 3)`` float32 linear
        RGB, and whether it is lit (not emissive, not the empty background), ``(H, W)`` bool."""
        col, lit = self._field.albedo(np.zeros(3), camera.pixel_rays().reshape(-1, 3))
        return col.reshape(camera.shape + (3,)), lit.reshape(camera.shape)

    @property
    def light(self):
        """The scene's key light and ambient (:class:`~snell_bench.scene.procedural.shading.Light`,
        camera frame)."""
        return self._field.light

    def shadow_casters(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The faces whose material casts shadows (those the shading's shadow rays test):
        ``(vertices (V, 3), faces (F, 3), vertex normals (V, 3))``, camera frame."""
        f = self._field
        faces = f.faces[f.casts_shadow[f.face_material]]
        used = np.unique(faces)
        index = np.full(len(f.vertices), -1, np.int64)
        index[used] = np.arange(len(used))
        return f.vertices[used], index[faces], f.vertex_normals[used]

    def depth(self, camera: Camera) -> np.ndarray:
        """The z-depth each pixel centre of ``camera`` sees, ``(H, W)`` float64 (inf where nothing)."""
        d = camera.pixel_rays()
        t = self._field.cast_t(np.zeros((1, 3)), d.reshape(-1, 3)).astype(np.float64)
        return (t * d[..., 2].reshape(-1)).reshape(camera.shape)

    def key_direct(self, camera: Camera) -> np.ndarray:
        """The key light's ``cos θ × falloff × visibility`` at the surface each pixel centre of
        ``camera`` sees (the shading's direct term without the light's colour), ``(H, W)``."""
        return self._field.direct_factor(np.zeros(3), camera.pixel_rays().reshape(-1, 3)).reshape(camera.shape)

    def mesh(self) -> trimesh.Trimesh:
        """All scene geometry in camera coordinates.

        Returns:
            The mesh; ``metadata['face_material']`` holds each face's material index into
            ``metadata['material_names']``.
        """
        f = self._field
        m = trimesh.Trimesh(vertices=f.vertices.copy(), faces=f.faces.copy(), process=False)
        m.metadata["face_material"] = f.face_material.copy()
        m.metadata["material_names"] = self.material_names
        return m

    @property
    def material_names(self) -> list[str]:
        """Names of the scene's materials, in index order."""
        return [m.name for m in self._field.materials]

    def world_to_camera(self, p_world: np.ndarray) -> np.ndarray:
        """Converts world-frame points (y up, metres) to the camera frame."""
        return (np.asarray(p_world, np.float64) - self._C) @ self._R

    def camera_to_world(self, p_cam: np.ndarray) -> np.ndarray:
        """Converts camera-frame points to the world frame (y up, metres)."""
        return np.asarray(p_cam, np.float64) @ self._R.T + self._C

    def __repr__(self) -> str:
        return f"ProceduralScene(kind={self.kind!r}, seed={self.seed})"

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _check_ss(s) -> int:
        if int(s) != s or s < 1:
            raise ValueError(f"supersample must be a positive integer, got {s!r}")
        return int(s)

    @staticmethod
    def _offsets(s: int):
        c = (np.arange(s) + 0.5) / s - 0.5
        return [(oy, ox) for oy in c for ox in c]

    def _finalize(self, builder: Builder, layout: Layout) -> None:
        """Moves the built world-frame scene into the frame of the layout's camera."""
        C, yaw, pitch = layout.camera
        f = np.array([math.sin(yaw) * math.cos(pitch), -math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        down = np.array([0.0, -1.0, 0.0])
        down = down - (down @ f) * f
        down /= np.linalg.norm(down)
        right = np.cross(down, f)
        R = np.stack([right, down, f], axis=1)  # columns: camera axes in world
        self._R, self._C = R, C
        self.pitch_deg = math.degrees(pitch)
        self.camera_height = float(C[1] - layout.floor)
        V, N, F, M, T = builder.finish()
        self.up = (np.array([0.0, 1.0, 0.0]) @ R).astype(np.float64)
        self.up /= np.linalg.norm(self.up)
        self.support_normal = self.up.copy()
        self.support_point = self.world_to_camera(layout.support)
        L = layout.light
        vec = self.world_to_camera(L.vector) if L.kind == "point" else np.asarray(L.vector) @ R
        light = Light(
            L.kind,
            vec,
            np.asarray(L.color, np.float32),
            np.asarray(L.ambient_sky, np.float32),
            np.asarray(L.ambient_ground, np.float32),
            float(L.falloff),
        )
        self._field = RadianceField(
            (V - C) @ R, (N @ R).astype(np.float32), F, M, T, builder.materials, light, R, C, layout.env
        )
