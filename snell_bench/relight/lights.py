"""The lights of a scene, for relighting by tracing: key lights and an environment.

Convention:
    - Frame: the camera frame (OpenCV: x right, y down, z forward); a light's ``direction`` is the
      unit vector from the scene *towards* the light.
    - Units: linear RGB in I⁻'s exposure. A key light's ``irradiance`` is what it delivers to a
      surface facing it (``E · max(0, n · l)`` on a surface of normal ``n``); the environment is a
      radiance per direction (a surface facing up under a uniform sky of radiance ``L`` receives
      ``π L``).
    - A key light has an angular radius (the sun: 0.27°); shadows under it are soft by that much.
      A key light with a ``position`` is a point light (a lamp in the room): its ``irradiance`` is
      what a surface facing it receives at 1 m, falling off as ``1 / (d² + falloff)``.
    - :func:`true_lights`: a procedural scene's own light and ambient (its shading model,
      :class:`~snell_bench.scene.procedural.shading.Light`): the ambient ``sky (1 + n_y) / 2 +
      ground (1 - n_y) / 2`` (world y up) is the irradiance of an environment of radiance
      ``sky / π`` above the horizon and ``ground / π`` below it; its point or directional light.
    - :func:`estimate_lights`: from the panorama generated at the object (a light probe): its
      brightest region above the horizon becomes a key light (direction: the region's
      luminance-weighted mean; angular radius: that of a disc of its solid angle), the rest the
      environment. An LDR panorama clips a bright light: where the region is clipped, its integrated
      radiance is only a lower bound on the light's irradiance, so the irradiance is taken as
      ``key_to_ambient`` times the environment's irradiance on a surface facing up (a clear sky's
      sun gives 3 to 10 times its sky's), never below the bound (see docs/relighting.md for how wrong
      that can be).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from snell_bench.imaging.color import srgb_to_linear
from snell_bench.relight.shadow import unit_vector

__all__ = ["KeyLight", "LightRig", "estimate_lights", "hemisphere_environment", "panorama_environment", "true_lights"]


@dataclass(frozen=True)
class KeyLight:
    """A distant light of small angular size: the sun, a lamp seen from the object.

    Attributes:
        direction: ``(3,)`` unit direction towards the light (camera frame).
        irradiance: ``(3,)`` linear RGB on a surface facing it.
        angular_radius_deg: its angular radius (0: a point; soft shadows need more).
        note: how it was found (for the records).
        position: ``(3,)`` a point light's position (camera frame), ``None``: a distant light.
        falloff: a point light's ``1 / (d² + falloff)``.
    """

    direction: np.ndarray
    irradiance: np.ndarray
    angular_radius_deg: float = 0.27
    note: str = ""
    position: np.ndarray | None = None
    falloff: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_vector(self.direction))
        e = np.asarray(self.irradiance, np.float64).reshape(3)
        if not np.isfinite(e).all() or (e < 0).any():
            raise ValueError(f"a key light's irradiance must be finite and >= 0, got {e.tolist()}")
        object.__setattr__(self, "irradiance", e)
        if not 0.0 <= float(self.angular_radius_deg) < 90.0:
            raise ValueError(f"a key light's angular radius must be in [0, 90) degrees, got {self.angular_radius_deg}")
        if self.position is not None:
            object.__setattr__(self, "position", np.asarray(self.position, np.float64).reshape(3))

    def toward(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(directions (N, 3), distances (N,), scale (N,))`` from ``points`` to the light: unit
        directions, the distance (inf for a distant light) and the irradiance's falloff there."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        if self.position is None:
            n = len(p)
            return np.broadcast_to(self.direction, p.shape).copy(), np.full(n, np.inf), np.ones(n)
        v = self.position - p
        d = np.linalg.norm(v, axis=1)
        return v / d[:, None], d, 1.0 / (d**2 + self.falloff)

    def to_json(self) -> dict:
        return {
            "direction": [round(float(x), 6) for x in self.direction],
            "irradiance": [round(float(x), 6) for x in self.irradiance],
            "angular_radius_deg": round(float(self.angular_radius_deg), 4),
            "note": self.note,
        } | (
            {}
            if self.position is None
            else {"position": [round(float(x), 6) for x in self.position], "falloff": float(self.falloff)}
        )


@dataclass
class LightRig:
    """Key lights and an environment (light transport is linear in the emitters: the groups add).

    Attributes:
        keys: the key lights.
        environment: radiance of camera-frame directions ``(N, 3) -> (N, 3)`` linear RGB, or ``None``.
        source: ``true`` (a procedural scene's own lights) or ``panorama`` (estimated).
        info: what the estimate measured (for the records).
    """

    keys: tuple[KeyLight, ...] = ()
    environment: Callable[[np.ndarray], np.ndarray] | None = None
    source: str = "true"
    info: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"source": self.source, "keys": [k.to_json() for k in self.keys], **self.info}


def hemisphere_environment(sky, ground, up) -> Callable[[np.ndarray], np.ndarray]:
    """The environment of radiance ``sky / π`` above the horizon of ``up`` and ``ground / π`` below:
    a surface of normal ``n`` receives ``sky (1 + n·up) / 2 + ground (1 - n·up) / 2``.

    Examples:
        >>> env = hemisphere_environment([1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.0, -1.0, 0.0])
        >>> (env(np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])) * np.pi).round(6).tolist()
        [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]
    """
    sky_l = np.asarray(sky, np.float64).reshape(3) / math.pi
    ground_l = np.asarray(ground, np.float64).reshape(3) / math.pi
    up = unit_vector(up)

    def radiance(d: np.ndarray) -> np.ndarray:
        above = (np.asarray(d, np.float64).reshape(-1, 3) @ up) > 0
        return np.where(above[:, None], sky_l, ground_l)

    return radiance


def true_lights(source, obj) -> LightRig:
    """A procedural scene's own key light and ambient (module convention).

    Args:
        source: the :class:`~snell_bench.scene.procedural.ProceduralScene` (``SceneInputs.source``).
        obj: the placed object (a point light is seen from its centre).

    Raises:
        ValueError: the source is not a procedural scene (only those know their lights).
    """
    light = getattr(source, "light", None)
    if light is None or getattr(source, "up", None) is None:
        raise ValueError(
            f"the true lights are known for procedural scenes only, not for {type(source).__name__}; use the lights "
            "estimated from the panorama (relight=traced)"
        )
    up = unit_vector(source.up)  # the world's up in the camera frame
    env = hemisphere_environment(light.ambient_sky, light.ambient_ground, up)
    if light.kind == "directional":
        key = KeyLight(light.vector, light.color, 0.0, note="the scene's directional light")
    else:
        d = np.asarray(light.vector, np.float64) - np.asarray(obj.center, np.float64)
        key = KeyLight(
            d, light.color, 0.0, note="the scene's point light", position=light.vector, falloff=light.falloff
        )
    return LightRig(keys=(key,), environment=env, source="true")


def panorama_environment(panorama: np.ndarray, pano_camera, mask: np.ndarray | None = None):
    """The environment of a panorama: radiance of camera-frame directions by bilinear lookup in its
    linear RGB; ``mask`` (``(h, 2h)`` bool) pixels are replaced by the median of the rest."""
    from scipy.ndimage import map_coordinates

    lin = srgb_to_linear(np.asarray(panorama, np.float32)).astype(np.float64)
    if mask is not None and mask.any():
        lin = lin.copy()
        lin[mask] = np.median(lin[~mask], axis=0)
    h, w = lin.shape[:2]

    def radiance(d: np.ndarray) -> np.ndarray:
        uv = pano_camera.project_directions(np.asarray(d, np.float64).reshape(-1, 3))
        u = np.mod(uv[:, 0] - 0.0, w)
        v = np.clip(uv[:, 1], 0.0, h - 1.0)
        return np.stack([map_coordinates(lin[..., c], [v, u], order=1, mode="grid-wrap") for c in range(3)], -1)

    return radiance


def _solid_angles(h: int) -> np.ndarray:
    lat = (np.arange(h) + 0.5) / h * math.pi - math.pi / 2
    return (math.pi / h) ** 2 * np.cos(lat)  # per pixel of row i (width 2h)


def estimate_lights(
    panorama: np.ndarray,
    pano_camera,
    up,
    *,
    key_to_ambient: float = 4.0,
    top_fraction: float = 2e-3,
    clip: float = 0.98,
) -> LightRig:
    """A key light and an environment estimated from a panorama at the object (module convention).

    Args:
        panorama: ``(h, 2h, 3)`` sRGB in [0, 1].
        pano_camera: its :class:`~snell_bench.imaging.PanoramaCamera`.
        up: the scene's up direction (camera frame).
        key_to_ambient: a clipped key light's irradiance over the environment's on a surface facing up.
        top_fraction: the brightest fraction of the sphere above the horizon (by solid angle) where
            the key light is looked for.
        clip: an sRGB value at or above which a pixel counts as clipped.

    Returns:
        The :class:`LightRig` (``source="panorama"``), ``info`` with the key's region (solid angle,
        whether clipped, the lower bound on its irradiance).
    """
    from scipy import ndimage

    pano = np.asarray(panorama, np.float32)
    h = pano.shape[0]
    if pano.ndim != 3 or pano.shape[1] != 2 * h or pano.shape[2] != 3:
        raise ValueError(f"the panorama must be (h, 2h, 3), got {pano.shape}")
    up = unit_vector(up)
    lin = srgb_to_linear(pano).astype(np.float64)
    lum = lin @ np.array([0.2126, 0.7152, 0.0722])
    dirs = pano_camera.directions()
    above = dirs @ up > 0
    omega = np.broadcast_to(_solid_angles(h)[:, None], (h, 2 * h))
    order = np.argsort(-np.where(above, lum, -np.inf), axis=None)
    cum = np.cumsum(omega.ravel()[order])
    n_top = max(1, int(np.searchsorted(cum, top_fraction * 2 * math.pi)))
    top = np.zeros(h * 2 * h, bool)
    top[order[:n_top]] = True
    top = top.reshape(h, 2 * h) & above
    labels, count = ndimage.label(top)
    power = ndimage.sum_labels(lum * omega, labels, index=np.arange(1, count + 1))
    region = labels == 1 + int(np.argmax(power))  # the component that sends the most light
    w = (lum * omega)[region]
    d = unit_vector((dirs[region] * w[:, None]).sum(0))
    solid = float(omega[region].sum())
    radius = math.degrees(math.acos(max(-1.0, 1.0 - solid / (2 * math.pi))))
    bound = (lin[region] * omega[region][:, None]).sum(0)
    env = panorama_environment(pano, pano_camera, mask=region)
    cos_up = np.clip(dirs @ up, 0.0, None)
    ambient_up = (env(dirs.reshape(-1, 3)).reshape(h, 2 * h, 3) * (cos_up * omega)[..., None]).sum((0, 1))
    clipped = bool((pano[region].max(-1) >= clip).any())
    if clipped:
        colour = lin[region].mean(0) / max(float(lin[region].mean(0).max()), 1e-12)
        strength = key_to_ambient * float(ambient_up.mean())
        irradiance = np.maximum(bound, colour * strength)
        note = f"clipped: {key_to_ambient:g} x the environment's irradiance facing up (lower bound from the pixels)"
    else:
        irradiance, note = bound, "the region's integrated radiance"
    key = KeyLight(d, irradiance, min(radius, 45.0), note=note)
    info = {
        "key_solid_angle_sr": round(solid, 6),
        "key_clipped": clipped,
        "key_lower_bound": [round(float(x), 6) for x in bound],
        "ambient_facing_up": [round(float(x), 6) for x in ambient_up],
    }
    return LightRig(keys=(key,), environment=env, source="panorama", info=info)
