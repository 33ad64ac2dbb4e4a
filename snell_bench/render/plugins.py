"""Mitsuba plugins written in Python: the refraction-path BSDF, the refraction-only glass of the
paper's reference and a pinhole sensor of any intrinsics.

A plugin class subclasses a type of the current Mitsuba variant (``mi.BSDF``, ``mi.Sensor``), which
exists only once a variant is set, so each class is built by a factory from the ``mitsuba`` module
(:func:`refraction_path_bsdf_class`, :func:`refraction_only_bsdf_class`,
:func:`pinhole_sensor_class`) and :func:`register_plugins` registers them for the current variant,
once per variant
(:func:`~snell_bench.render.variants.set_variant` calls it). Importing this module does not import
Mitsuba.

Convention:
    - ``snell_refraction_path`` (:data:`REFRACTION_PATH_BSDF`): Mitsuba's smooth ``dielectric``
      (``int_ior``, ``ext_ior``) that follows the refraction path deterministically, with weight 1:
      transmission at every interface, reflection only under total internal reflection.
    - ``snell_refraction_only`` (:data:`REFRACTION_ONLY_BSDF`): glass whose camera rays only
      refract, every other ray meeting Mitsuba's smooth ``dielectric`` (``int_ior``, ``ext_ior``).
      A camera ray's first hit on the object transmits deterministically, with weight 1 (no
      first-surface reflection and no Fresnel loss: the transmitted weight is 1, not ``1 - F``);
      inside and after, the dielectric reflects with probability ``F`` and transmits with ``1 - F``
      (so Fresnel loss at the exit, internal reflections and total internal reflection all stay).
      This is the paper's refraction-only Blender reference as the authors' ``render_gt`` builds
      it: a mix shader that gives camera rays (Blender's *Is Camera Ray*) a Refraction BSDF
      (transmission only, of unit colour) and every other ray a Glass BSDF. A ray is a camera
      ray when its origin ``o = p + t wi`` (``p`` the hit, ``t`` the distance, ``wi`` towards the
      origin) has ``z < camera_z``: camera rays start on the near clip plane, every other ray on a
      surface, so ``camera_z`` between the near clip plane and the nearest geometry separates them
      exactly.
    - ``snell_pinhole`` (:data:`PINHOLE_SENSOR`): a pinhole camera at the origin of the camera frame
      of :mod:`snell_bench.scene.camera` (OpenCV: x right, y down, z forward; no ``to_world``) with
      any intrinsics, given as the first two rows of ``K⁻¹`` (properties ``inv_k_ij``, ``i < 2``). The
      film sample at Mitsuba film position ``u`` (film pixel ``i`` covers ``[i, i + 1)``) casts the
      ray of direction ``K⁻¹ (u - 0.5, 1)`` (normalised), from the plane ``z = near_clip`` to the plane
      ``z = far_clip``, as Mitsuba's ``perspective`` sensor clips. It draws no aperture sample, so its
      sampler stream is that of ``perspective``; its rays carry no differentials (texel-exact,
      ``nearest`` textures use none).
"""

from __future__ import annotations

__all__ = [
    "PINHOLE_SENSOR",
    "REFRACTION_ONLY_BSDF",
    "REFRACTION_PATH_BSDF",
    "pinhole_sensor_class",
    "refraction_only_bsdf_class",
    "refraction_path_bsdf_class",
    "register_plugins",
]

#: The plugin name of the refraction-path BSDF.
REFRACTION_PATH_BSDF = "snell_refraction_path"
#: The plugin name of the refraction-only glass (camera rays refract only).
REFRACTION_ONLY_BSDF = "snell_refraction_only"
#: The plugin name of the pinhole sensor.
PINHOLE_SENSOR = "snell_pinhole"

_registered: set[str] = set()


def _dielectric_base(mi) -> type:
    """A ``mi.BSDF`` that wraps Mitsuba's smooth ``dielectric`` (``int_ior``, ``ext_ior`` of the
    plugin's properties) and delegates everything but ``sample`` to it."""

    class DelegatingDielectric(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self._inner = mi.load_dict(
                {"type": "dielectric", "int_ior": props.get("int_ior", 1.5), "ext_ior": props.get("ext_ior", 1.0)}
            )
            sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            refl = mi.BSDFFlags.DeltaReflection | sides
            trans = mi.BSDFFlags.DeltaTransmission | sides
            self.m_components = [refl, trans]
            self.m_flags = refl | trans

        def eval(self, ctx, si, wo, active=True):
            return self._inner.eval(ctx, si, wo, active)  # zero: delta lobes

        def pdf(self, ctx, si, wo, active=True):
            return self._inner.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._inner.eval_pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

    return DelegatingDielectric


def refraction_path_bsdf_class(mi) -> type:
    """The refraction-path BSDF (see the module's conventions) for the current variant.

    Args:
        mi: the ``mitsuba`` module, set to a variant.

    Returns:
        A subclass of ``mi.BSDF`` whose constructor takes the plugin's ``mi.Properties``.
    """

    class RefractionPathBSDF(_dielectric_base(mi)):
        """Mitsuba's smooth dielectric, but following the refraction path deterministically:
        transmission at every interface, reflection only under total internal reflection."""

        def sample(self, ctx, si, sample1, sample2, active=True):
            # the dielectric reflects iff sample1 <= Fresnel reflectance: with 1 only under TIR
            return self._inner.sample(ctx, si, sample1 * 0.0 + 1.0, sample2, active)

        def to_string(self):
            return f"RefractionPathBSDF[{self._inner}]"

    return RefractionPathBSDF


def refraction_only_bsdf_class(mi) -> type:
    """The refraction-only glass (see the module's conventions) for the current variant.

    Args:
        mi: the ``mitsuba`` module, set to a variant.

    Returns:
        A subclass of ``mi.BSDF`` whose constructor takes the plugin's ``mi.Properties``
        (``int_ior``, ``ext_ior``, ``camera_z``).
    """
    import drjit as dr

    class RefractionOnlyBSDF(_dielectric_base(mi)):
        """Mitsuba's smooth dielectric, except that camera rays (origin at ``z < camera_z``) always
        transmit, with weight 1."""

        def __init__(self, props):
            super().__init__(props)
            self._camera_z = float(props.get("camera_z"))

        def sample(self, ctx, si, sample1, sample2, active=True):
            # the ray's origin: the hit point moved back along the ray by its length
            origin_z = si.p.z + si.t * si.to_world(si.wi).z
            camera = origin_z < self._camera_z
            # the dielectric reflects iff sample1 <= Fresnel reflectance: with 1 only under TIR
            return self._inner.sample(ctx, si, dr.select(camera, sample1 * 0.0 + 1.0, sample1), sample2, active)

        def to_string(self):
            return f"RefractionOnlyBSDF[camera_z={self._camera_z}, {self._inner}]"

    return RefractionOnlyBSDF


def pinhole_sensor_class(mi) -> type:
    """The pinhole sensor of any intrinsics (see the module's conventions) for the current variant.

    Args:
        mi: the ``mitsuba`` module, set to a variant.

    Returns:
        A subclass of ``mi.Sensor`` whose constructor takes the plugin's ``mi.Properties``
        (``inv_k_ij``, ``near_clip``, ``far_clip``, a film and a sampler).
    """
    import drjit as dr

    rgb = bool(mi.is_rgb)
    unit_weight = mi.Color3f(1.0) if rgb else None

    class PinholeSensor(mi.Sensor):
        """A pinhole camera at the origin with any intrinsics: the ray through film position ``u``
        (Mitsuba's film pixels, pixel ``i`` covering ``[i, i + 1)``) has the direction of
        ``K⁻¹ (u - 0.5, 1)`` in the camera frame (no ``to_world``). See
        :func:`~snell_bench.render.pieces.pinhole_sensor`."""

        def __init__(self, props):
            mi.Sensor.__init__(self, props)
            self.m_needs_sample_3 = False  # no aperture: the sampler's stream is that of `perspective`
            self._inv_k = [float(props.get(f"inv_k_{i}{j}")) for i in range(2) for j in range(3)]
            self._near = float(props.get("near_clip"))
            self._far = float(props.get("far_clip"))
            film = self.film()
            offset, size = film.crop_offset(), film.crop_size()
            # position samples are fractions of the crop window; pixel centres are at integers
            self._x0, self._y0 = float(offset[0]) - 0.5, float(offset[1]) - 0.5
            self._sx, self._sy = float(size[0]), float(size[1])

        def _ray(self, time, wavelength_sample, position_sample, active):
            if rgb:
                wavelengths, weight = mi.Color0f(), unit_weight
            else:
                wavelengths, weight = self.sample_wavelengths(
                    dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active
                )
            a, b, c, d, e, f = self._inv_k
            x = position_sample.x * self._sx + self._x0
            y = position_sample.y * self._sy + self._y0
            # the direction of K⁻¹ (x, y, 1) is (dx, dy, 1) / n; the clip planes are planes of
            # constant z, as in `perspective`: the ray starts at z = near_clip, ends at z = far_clip
            dx, dy = a * x + b * y + c, d * x + e * y + f
            n = dr.sqrt(dx * dx + dy * dy + 1.0)
            inv_n = 1.0 / n
            ray = mi.RayDifferential3f(
                mi.Point3f(dx * self._near, dy * self._near, self._near),
                mi.Vector3f(dx * inv_n, dy * inv_n, inv_n),
                time,
                wavelengths,
            )
            ray.maxt = (self._far - self._near) * n
            # has_differentials stays False: texel-exact (nearest) textures use none
            return ray, weight

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            ray, weight = self._ray(time, sample1, sample2, active)
            return mi.Ray3f(ray), weight

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            return self._ray(time, sample1, sample2, active)

        def bbox(self):
            return mi.ScalarBoundingBox3f(mi.ScalarPoint3f(0.0))

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"PinholeSensor[inv_k={self._inv_k}, near_clip={self._near}, far_clip={self._far}]"

    return PinholeSensor


def register_plugins(mi) -> None:
    """Register ``snell_refraction_path``, ``snell_refraction_only`` and ``snell_pinhole`` for the
    current variant of ``mi`` (once per variant; later calls for that variant do nothing).

    Args:
        mi: the ``mitsuba`` module, set to a variant.
    """
    variant = mi.variant()
    if variant in _registered:
        return
    bsdf = refraction_path_bsdf_class(mi)
    mi.register_bsdf(REFRACTION_PATH_BSDF, lambda props: bsdf(props))
    only = refraction_only_bsdf_class(mi)
    mi.register_bsdf(REFRACTION_ONLY_BSDF, lambda props: only(props))
    sensor = pinhole_sensor_class(mi)
    mi.register_sensor(PINHOLE_SENSOR, lambda props: sensor(props))
    _registered.add(variant)
