"""Shadows and caustics traced through the glass, lit by the panorama: relighting without weights.

The paper relights with FLUX Kontext; its future work names "native lighting and shadow handling via
light source estimation and ray tracing". This relighter does that: the scene near the object is
I⁻'s depth mesh (:func:`~snell_bench.relight.transport.receiver_from_depth`); the lights are the
panorama's (:func:`~snell_bench.relight.lights.estimate_lights`: its environment and its brightest
region as a key light) or, for a procedural scene, its own (``lights="true"``); light is traced
through the glass onto the receiver (:mod:`snell_bench.relight.transport`); the image is relit by
differential rendering.

Convention:
    - Differential rendering in linear RGB (Debevec 1998, ratio form): every receiver pixel is
      multiplied by ``E_with / E_without``, its irradiance with the object over that without it,

          E_without = E_env + Σ_k E_k cos θ_k V_k,
          E_with    = E_env + ΔE_env + Σ_k (E_k cos θ_k V_k (1 - b_k) + C_k),

      (``b_k`` the share of key light k the object hides, ``C_k`` its caustic, ``ΔE_env`` the
      object's change of the environment's light, ``V_k`` whether the depth mesh hides the key light
      from the pixel): the albedo the image implies, ``I⁻ / E_without``, cancels. Pixels that are no
      receiver (no depth, a depth edge) keep their values.
    - Object pixels see the background through the glass: their refracted share ``1 - F`` takes the
      ratio at their refraction warp's source pixel (bilinear; none where π^R is invalid), their
      reflection none.
    - The output is clipped to [0, 1] in sRGB (a bright caustic may clip, as a camera would).
    - ``seed`` draws the beam's and the environment rays' jitter: candidates differ by noise only.
"""

from __future__ import annotations

import numpy as np
import torch

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.remap import remap
from snell_bench.relight.base import check_image
from snell_bench.relight.lights import LightRig, estimate_lights, true_lights
from snell_bench.relight.shadow import Occluder, scene_up
from snell_bench.relight.transport import (
    caustic_irradiance,
    environment_terms,
    key_terms,
    receiver_from_depth,
    scene_visibility,
)

__all__ = ["TracedRelighter", "apply_ratio", "relight_ratio"]


def relight_ratio(
    scene,
    obj,
    lights: LightRig,
    *,
    tracer,
    shadow_samples: int,
    caustic_rays: int,
    env_samples: int,
    seed: int,
    blur_px: float = 0.0,
    internal_reflections: int = 4,
) -> tuple[np.ndarray, dict]:
    """``(H, W, 3)`` float64 ``E_with / E_without`` of I⁻'s receivers (module convention; 1 where no
    receiver), and a record (the lights, each key's beam energy)."""
    receiver = receiver_from_depth(scene.depth, scene.camera)
    occluder = Occluder.from_mesh(obj.vertices, obj.faces)
    e_env, d_env = (
        environment_terms(receiver, tracer, occluder, lights.environment, env_samples, seed)
        if lights.environment is not None
        else (np.zeros(receiver.points.shape), np.zeros(receiver.points.shape))
    )
    without, with_ = e_env.copy(), e_env + d_env
    record = {"lights": lights.to_json(), "keys": []}
    for k, key in enumerate(lights.keys):
        geometry, blocked = key_terms(receiver, key, occluder, shadow_samples)
        caustic, beam = caustic_irradiance(
            receiver,
            scene.camera,
            scene.depth,
            tracer,
            occluder,
            key,
            caustic_rays,
            seed + 7919 * (k + 1),
            blur_px,
            internal_reflections,
        )
        changed = (blocked > 0) | (caustic > 0).any(-1) | (d_env != 0).any(-1)
        vis = scene_visibility(receiver, tracer, key, changed)
        direct = (geometry * vis)[..., None] * key.irradiance
        without += direct
        with_ += direct * (1.0 - blocked)[..., None] + caustic
        record["keys"].append(beam)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(without > 1e-12, with_ / without, 1.0)
    ratio = np.where(receiver.valid[..., None], np.clip(ratio, 0.0, None), 1.0)
    return ratio, record


def apply_ratio(image: torch.Tensor, ratio: np.ndarray, *, refraction=None, fresnel=None) -> torch.Tensor:
    """``image`` (``(1, 3, H, W)`` sRGB) times ``ratio`` ``(H, W, 3)`` in linear RGB; object pixels
    (where ``refraction``, π^R with NaN where invalid, moves them) take the ratio at their source pixel
    for their refracted share ``1 - fresnel``. Pixels with ratio 1 keep their exact values."""
    H, W = check_image(image)
    img = image.detach().to("cpu", torch.float32)
    seen = np.array(ratio, np.float32)
    if seen.shape != (H, W, 3):
        raise ValueError(f"the ratio is {seen.shape} for a {(H, W)} image")
    if refraction is not None:
        coords = np.asarray(refraction, np.float32)
        grid = np.stack(np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)), -1)
        moved = ~(coords == grid).all(-1)
        if moved.any():
            src = torch.from_numpy(np.ascontiguousarray(seen.transpose(2, 0, 1)))[None]
            sampled, valid = remap(src, coords[moved][None])
            through = sampled[0, :, 0].numpy().T  # (M, 3), 0 where invalid
            ok = valid[0, 0].numpy()
            through = np.where(ok[:, None], through, 1.0)
            F = np.zeros(int(moved.sum()), np.float32) if fresnel is None else np.asarray(fresnel, np.float32)[moved]
            seen[moved] = F[:, None] + (1.0 - F[:, None]) * through
    changed = torch.from_numpy((seen != 1.0).any(-1))
    out = img.clone()
    if bool(changed.any()):
        k = torch.from_numpy(seen)[changed].T  # (3, M)
        out[0][:, changed] = linear_to_srgb(srgb_to_linear(img[0][:, changed]) * k).clamp(0.0, 1.0)
    return out


class TracedRelighter:
    """Shadows and caustics traced through the glass under the panorama's lights, composited by
    differential rendering (module docstring).

    Args:
        lights: ``panorama`` (estimated from the generated panorama) or ``true`` (a procedural
            scene's own lights).
        shadow_samples: shadow rays per receiver over a key light's cone.
        caustic_rays: rays of each key light's beam through the object.
        env_samples: environment rays per receiver near the object.
        key_to_ambient: a clipped key light's irradiance over the environment's facing up.
        blur_px: the caustic splat's Gaussian blur (pixels; 0: none: a blur carries the light of a caustic hidden behind the object into the pixels beside it).
        max_bounces: interactions per ray inside the glass.
        internal_reflections: generations of the light an exit reflects back into the glass that
            the caustic beam follows (0: the refracted path alone).
    """

    name = "traced"

    def __init__(
        self,
        lights: str = "panorama",
        shadow_samples: int = 64,
        caustic_rays: int = 400_000,
        env_samples: int = 64,
        key_to_ambient: float = 4.0,
        blur_px: float = 0.0,
        max_bounces: int = 8,
        internal_reflections: int = 4,
    ):
        if lights not in ("panorama", "true"):
            raise ValueError(
                f"relight.relighter.lights={lights!r}: use panorama (estimated) or true (procedural scenes)"
            )
        for key, value, lo in (
            ("shadow_samples", shadow_samples, 1),
            ("caustic_rays", caustic_rays, 0),
            ("env_samples", env_samples, 1),
            ("max_bounces", max_bounces, 1),
            ("internal_reflections", internal_reflections, 0),
        ):
            if int(value) != value or value < lo:
                raise ValueError(f"relight.relighter.{key}={value!r}: use an integer >= {lo}")
        if not (key_to_ambient > 0 and blur_px >= 0):
            raise ValueError(f"key_to_ambient ({key_to_ambient}) must be > 0 and blur_px ({blur_px}) >= 0")
        self.lights = lights
        self.shadow_samples, self.caustic_rays, self.env_samples = (
            int(shadow_samples),
            int(caustic_rays),
            int(env_samples),
        )
        self.key_to_ambient, self.blur_px, self.max_bounces = float(key_to_ambient), float(blur_px), int(max_bounces)
        self.internal_reflections = int(internal_reflections)
        self.last_record: dict = {}

    def describe(self) -> str:
        return (
            f"shadows and caustics traced through the glass (Open3D), lights {'of the scene' if self.lights == 'true' else 'estimated from the panorama'}, "
            f"differential rendering; {self.shadow_samples} shadow rays, {self.caustic_rays} caustic rays per key light, "
            f"{self.env_samples} environment rays near the object, {self.internal_reflections} internal reflections followed"
        )

    def rig(self, *, scene, obj, warps, panorama) -> LightRig:
        """The lights: the scene's own, or estimated from the panorama."""
        if self.lights == "true":
            return true_lights(scene.source, obj)
        if panorama is None:
            raise ValueError(
                "relighting with lights from the panorama needs the cell's panorama (a method that makes one)"
            )
        pano = panorama.detach().cpu().numpy()[0].transpose(1, 2, 0) if isinstance(panorama, torch.Tensor) else panorama
        return estimate_lights(
            np.asarray(pano, np.float32), warps.pano, scene_up(obj, scene), key_to_ambient=self.key_to_ambient
        )

    def relight(self, image, *, prompt: str = "", seed: int, scene=None, obj=None, warps=None, panorama=None):
        """The image with the object's traced shadow and caustic (``prompt`` is not used)."""
        from snell_bench.optics.tracer import SceneTracer
        from snell_bench.scene.depth_mesh import build_background

        if scene is None or obj is None or warps is None:
            raise ValueError("the traced relighter needs the scene, the placed object and its warps")
        H, W = check_image(image)
        if tuple(np.shape(scene.depth)) != (H, W):
            raise ValueError(f"image {(H, W)} and depth {tuple(np.shape(scene.depth))} must have the same size")
        lights = self.rig(scene=scene, obj=obj, warps=warps, panorama=panorama)
        tracer = SceneTracer(
            build_background(scene.depth, scene.camera, extra_points=obj.vertices), obj, max_bounces=self.max_bounces
        )
        ratio, self.last_record = relight_ratio(
            scene,
            obj,
            lights,
            tracer=tracer,
            shadow_samples=self.shadow_samples,
            caustic_rays=self.caustic_rays,
            env_samples=self.env_samples,
            seed=int(seed),
            blur_px=self.blur_px,
            internal_reflections=self.internal_reflections,
        )
        refraction = np.where(np.asarray(warps.refraction_valid)[..., None], warps.refraction, np.nan)
        return apply_ratio(image, ratio, refraction=refraction, fresnel=warps.fresnel)
