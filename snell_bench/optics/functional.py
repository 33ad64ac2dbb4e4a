"""Pure, batched optics on torch tensors.

Convention:
    - ``d``: incoming ray directions ``(..., 3)``, unit length, pointing *along* the ray.
    - ``n``: unit surface normals ``(..., 3)`` *facing the incoming ray* (``d . n <= 0``); use
      :func:`face_forward` to orient a surface normal.
    - ``eta``: ratio ``nu_i / nu_t`` of the refractive index on the incoming side to the one on the
      transmitted side (``1 / 1.5`` entering glass from air), a float or a tensor broadcastable to
      ``d[..., 0]``.
    - Any floating dtype; computations stay in the input dtype (pass float64 for the last digits).

    The paper's form of Snell's law, with ``beta = -d . n`` and ``gamma = 1 - eta^2 (1 - beta^2)``:
    ``d' = eta d + (eta beta - sqrt(gamma)) n``; ``gamma < 0`` is total internal reflection (TIR),
    where the ray is mirrored: ``d' = d - 2 (d . n) n``.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["adjoint_correction", "face_forward", "reflect", "refract", "fresnel", "fresnel_cos", "interact"]


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def face_forward(n: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Orient normals to face the rays.

    Args:
        n: ``(..., 3)`` normals.
        d: ``(..., 3)`` ray directions.

    Returns:
        ``n`` flipped where needed so that it faces the ray ``d`` (``d . n <= 0``).

    Examples:
        >>> d = torch.tensor([0.6, -0.8, 0.0])
        >>> face_forward(torch.tensor([0.0, -1.0, 0.0]), d).tolist()
        [-0.0, 1.0, -0.0]
    """
    return torch.where((_dot(d, n) > 0)[..., None], -n, n)


def reflect(d: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror reflection ``d - 2 (d . n) n``.

    Args:
        d: ``(..., 3)`` ray directions.
        n: ``(..., 3)`` unit normals (either orientation gives the same result).

    Returns:
        ``(..., 3)`` mirrored directions.

    Examples:
        >>> r = reflect(torch.tensor([0.6, -0.8, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
        >>> [round(float(v), 4) for v in r]
        [0.6, 0.8, 0.0]
    """
    return d - 2.0 * _dot(d, n)[..., None] * n


def refract(d: torch.Tensor, n: torch.Tensor, eta) -> tuple[torch.Tensor, torch.Tensor]:
    """Refract ``d`` at a surface with normal ``n`` (facing the ray) and index ratio ``eta``.

    Finite for every unit input, grazing incidence (``beta -> 0``) and ``eta == 1`` (the identity)
    included.

    Args:
        d: ``(..., 3)`` unit ray directions.
        n: ``(..., 3)`` unit normals facing the rays.
        eta: index ratio ``nu_i / nu_t`` (float or tensor broadcastable to ``d[..., 0]``).

    Returns:
        ``(d_out (..., 3), tir (...) bool)``: the transmitted direction (unit length), or the
        mirrored direction where ``tir`` is true.

    Examples:
        At normal incidence the direction is unchanged:

        >>> out, tir = refract(torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, 0.0, -1.0]), 1 / 1.5)
        >>> out.tolist(), bool(tir)
        ([0.0, 0.0, 1.0], False)

        Entering glass, the tangential component shrinks by ``eta``; leaving it at a grazing
        angle, the ray is totally reflected:

        >>> d, n = torch.tensor([0.6, -0.8, 0.0]), torch.tensor([0.0, 1.0, 0.0])
        >>> out, tir = refract(d, n, 1 / 1.5)
        >>> round(float(out[0]), 4), bool(tir)
        (0.4, False)
        >>> out, tir = refract(torch.tensor([0.8, -0.6, 0.0]), n, 1.5)
        >>> [round(float(v), 4) for v in out], bool(tir)
        ([0.8, 0.6, 0.0], True)
    """
    eta = torch.as_tensor(eta, dtype=d.dtype, device=d.device)
    beta = (-_dot(d, n)).clamp(0.0, 1.0)
    gamma = 1.0 - eta * eta * (1.0 - beta * beta)
    tir = gamma < 0
    sq = torch.sqrt(gamma.clamp_min(0.0))
    e = eta[..., None] if eta.ndim else eta
    t = e * d + (eta * beta - sq)[..., None] * n
    out = torch.where(tir[..., None], reflect(d, n), t)
    out = out / torch.linalg.vector_norm(out, dim=-1, keepdim=True).clamp_min(torch.finfo(d.dtype).tiny)
    return out, tir


def fresnel_cos(cos_i: torch.Tensor, n_i, n_t) -> torch.Tensor:
    """Exact unpolarised Fresnel reflectance ``R = (R_s + R_p) / 2`` from the angle of incidence.

    ``R = 1`` under TIR and at grazing incidence; ``R = 0`` for ``n_i == n_t`` (except exactly at
    grazing incidence, where the limit 1 is returned).

    Args:
        cos_i: cosine of the angle of incidence, in ``[0, 1]`` (clamped there); any shape.
        n_i: refractive index on the incoming side (float or broadcastable tensor).
        n_t: refractive index on the transmitted side.

    Returns:
        ``R`` with the shape of ``cos_i`` (its floating dtype, else the default dtype).

    Examples:
        >>> round(float(fresnel_cos(torch.tensor(1.0), 1.0, 1.5)), 4)  # normal incidence, air -> glass
        0.04
        >>> [round(float(r), 4) for r in fresnel_cos(torch.tensor([1.0, 0.0]), 1.5, 1.0)]  # 0: grazing
        [0.04, 1.0]
    """
    cos_i = torch.as_tensor(cos_i).clamp(0.0, 1.0)
    dt = cos_i.dtype if cos_i.is_floating_point() else torch.get_default_dtype()
    cos_i = cos_i.to(dt)
    n_i = torch.as_tensor(n_i, dtype=dt, device=cos_i.device)
    n_t = torch.as_tensor(n_t, dtype=dt, device=cos_i.device)
    eta = n_i / n_t
    gamma = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    tir = gamma < 0
    cos_t = torch.sqrt(gamma.clamp_min(0.0))
    tiny = torch.finfo(dt).tiny
    den_s = n_i * cos_i + n_t * cos_t
    den_p = n_t * cos_i + n_i * cos_t
    rs = ((n_i * cos_i - n_t * cos_t) / den_s.clamp_min(tiny)) ** 2
    rp = ((n_t * cos_i - n_i * cos_t) / den_p.clamp_min(tiny)) ** 2
    r = 0.5 * (rs + rp)
    degenerate = (den_s <= tiny) | (den_p <= tiny)  # grazing incidence at matched indices
    return torch.where(tir | degenerate, torch.ones_like(r), r.clamp(0.0, 1.0))


def fresnel(d: torch.Tensor, n: torch.Tensor, n_i, n_t) -> torch.Tensor:
    """Fresnel reflectance of rays hitting a surface (:func:`fresnel_cos` of ``|d . n|``).

    Args:
        d: ``(..., 3)`` unit ray directions.
        n: ``(..., 3)`` unit normals (either orientation).
        n_i: refractive index on the incoming side.
        n_t: refractive index on the transmitted side.

    Returns:
        ``(...)`` reflectance.

    Examples:
        >>> d = torch.tensor([0.0, 0.0, 1.0])
        >>> round(float(fresnel(d, torch.tensor([0.0, 0.0, 1.0]), 1.0, 1.5)), 4)
        0.04
    """
    return fresnel_cos(_dot(d, n).abs(), n_i, n_t)


def interact(
    d: np.ndarray, ns: np.ndarray, ng: np.ndarray, n_i: np.ndarray, n_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refract or totally reflect rays at surface points between media of IOR ``n_i`` (the side the
    ray comes from) and ``n_t`` (the other side); numpy float64 in and out (the tracer's arrays).

    Args:
        d: ``(N, 3)`` unit ray directions.
        ns: ``(N, 3)`` outward shading normals.
        ng: ``(N, 3)`` outward face normals.
        n_i, n_t: ``(N,)`` indices of refraction before and after the surface.

    Returns:
        ``(d_new, goes_inside, fresnel, mirror, nf)``: new directions, whether they end on the inner
        side of the surface (its face normal's back), Fresnel reflectance, mirror directions and the
        normals used (facing the rays). A shading normal that would send the ray to the wrong side
        of the geometric surface (near silhouettes) is replaced by the face normal there.
    """
    from_inside = np.einsum("ij,ij->i", d, ng) > 0
    eta = n_i / n_t
    dt, nst, ngt = (torch.from_numpy(a) for a in (d, ns, ng))
    nf = face_forward(nst, dt)
    d_new, tir = refract(dt, nf, torch.from_numpy(eta))
    # a shading normal must not send the ray to the wrong side of the geometric surface
    goes_inside = torch.where(tir, torch.from_numpy(from_inside), ~torch.from_numpy(from_inside))
    s = (d_new * ngt).sum(-1)
    wrong = torch.where(goes_inside, s > 0, s < 0)
    if bool(wrong.any()):
        nfg = face_forward(ngt, dt)
        d_g, tir_g = refract(dt, nfg, torch.from_numpy(eta))
        d_new = torch.where(wrong[:, None], d_g, d_new)
        tir = torch.where(wrong, tir_g, tir)
        nf = torch.where(wrong[:, None], nfg, nf)
        goes_inside = torch.where(tir, torch.from_numpy(from_inside), ~torch.from_numpy(from_inside))
    cos_i = -(dt * nf).sum(-1)
    R = fresnel_cos(cos_i, torch.from_numpy(np.asarray(n_i, np.float64)), torch.from_numpy(np.asarray(n_t, np.float64)))
    mirror = reflect(dt, nf)
    return d_new.numpy(), goes_inside.numpy(), R.numpy(), mirror.numpy(), nf.numpy()


def adjoint_correction(d: np.ndarray, d_new: np.ndarray, ns: np.ndarray, ng: np.ndarray) -> np.ndarray:
    """``(N,)`` the factor light carries through a scattering at a shading normal when it is traced
    from the light (Veach 1997, §5.3: the adjoint BSDF of shading normals), so that light traced
    forward and paths traced from the camera agree: ``|(ns·wi)(ng·wo)| / |(ns·wo)(ng·wi)|`` with
    ``wi = -d`` (towards where the light came from) and ``wo = d_new``; 1 where ``ns = ±ng``, 0 where
    a cosine vanishes. Mitsuba's particle tracer applies the same factor at every surface.

    Args:
        d: ``(N, 3)`` unit directions the light arrives along.
        d_new: ``(N, 3)`` unit directions it leaves along (refracted or mirrored).
        ns: ``(N, 3)`` unit shading normals used (either orientation).
        ng: ``(N, 3)`` unit face normals (either orientation).

    Examples:
        >>> n = np.array([[0.0, 0.0, 1.0]])
        >>> float(adjoint_correction(np.array([[0.6, 0.0, -0.8]]), np.array([[0.4, 0.0, -0.9165]]), n, n)[0])
        1.0
    """
    num = np.abs(np.einsum("ij,ij->i", ns, d) * np.einsum("ij,ij->i", ng, d_new))
    den = np.abs(np.einsum("ij,ij->i", ns, d_new) * np.einsum("ij,ij->i", ng, d))
    return np.divide(num, den, out=np.zeros_like(num), where=den > 0)
