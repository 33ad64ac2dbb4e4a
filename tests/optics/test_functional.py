"""Physics oracles for refract / reflect / fresnel (closed-form optics, independent formulas)."""

import math

import numpy as np
import pytest
import torch
from tolerances import EPS64

from snell_bench.optics import face_forward, fresnel, fresnel_cos, reflect, refract

N_UP = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)


def incoming(theta: torch.Tensor) -> torch.Tensor:
    """Unit directions hitting the plane z = 0 from above at angles ``theta`` to the normal +z."""
    return torch.stack([torch.sin(theta), torch.zeros_like(theta), -torch.cos(theta)], -1)


def sin_to_normal(d: torch.Tensor) -> torch.Tensor:
    return torch.linalg.vector_norm(torch.cross(d, N_UP.expand_as(d), dim=-1), dim=-1)


class TestFresnel:
    def test_normal_incidence_glass(self):
        r = fresnel_cos(torch.tensor(1.0, dtype=torch.float64), 1.0, 1.5)
        assert float(r) == pytest.approx(0.04, abs=1e-12)
        # symmetric going out of the glass at normal incidence
        assert float(fresnel_cos(torch.tensor(1.0, dtype=torch.float64), 1.5, 1.0)) == pytest.approx(0.04, abs=1e-12)

    def test_against_angle_form(self):
        # classic textbook form: R_s = sin^2(ti - tt) / sin^2(ti + tt), R_p = tan^2(ti - tt) / tan^2(ti + tt)
        n1, n2 = 1.0, 1.5
        ti = np.linspace(0.01, math.radians(89.0), 200)
        tt = np.arcsin(n1 / n2 * np.sin(ti))
        rs = (np.sin(ti - tt) / np.sin(ti + tt)) ** 2
        rp = (np.tan(ti - tt) / np.tan(ti + tt)) ** 2
        ref = 0.5 * (rs + rp)
        got = fresnel_cos(torch.from_numpy(np.cos(ti)), n1, n2).numpy()
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)

    def test_brewster_angle_has_no_p_reflection(self):
        n1, n2 = 1.0, 1.5
        tb = math.atan(n2 / n1)
        tt = math.asin(n1 / n2 * math.sin(tb))
        rs = (math.sin(tb - tt) / math.sin(tb + tt)) ** 2
        assert float(fresnel_cos(torch.tensor(math.cos(tb), dtype=torch.float64), n1, n2)) == pytest.approx(
            rs / 2, rel=1e-10
        )

    def test_total_internal_reflection_is_one(self):
        crit = math.asin(1 / 1.5)
        th = torch.linspace(crit + 1e-4, math.radians(89.99), 50, dtype=torch.float64)
        r = fresnel_cos(torch.cos(th), 1.5, 1.0)
        assert torch.all(r == 1.0)
        # and continuous up to the critical angle from below
        below = fresnel_cos(torch.tensor(math.cos(crit - 1e-7), dtype=torch.float64), 1.5, 1.0)
        assert float(below) > 0.99

    def test_grazing_and_matched_index(self):
        assert float(fresnel_cos(torch.tensor(0.0, dtype=torch.float64), 1.0, 1.5)) == pytest.approx(1.0)
        r = fresnel_cos(torch.linspace(1e-3, 1.0, 20, dtype=torch.float64), 1.3, 1.3)
        assert torch.all(r.abs() < 1e-15)
        r = fresnel_cos(torch.tensor([0.0, 0.5, 1.0]), 1.0, 1.0)  # no NaN at exact grazing
        assert torch.all(torch.isfinite(r))

    def test_range_and_dtype(self):
        c = torch.rand(1000, dtype=torch.float32)
        for n1, n2 in [(1.0, 1.5), (1.5, 1.0), (1.0, 2.42), (2.42, 1.0), (1.0, 1.000001)]:
            r = fresnel_cos(c, n1, n2)
            assert r.dtype == torch.float32
            assert torch.all((r >= 0) & (r <= 1))

    def test_vector_form_matches_cosine_form(self):
        th = torch.linspace(0, 1.5, 30, dtype=torch.float64)
        d = incoming(th)
        for n in (N_UP, -N_UP):  # either normal orientation
            np.testing.assert_allclose(fresnel(d, n.expand_as(d), 1.0, 1.5), fresnel_cos(torch.cos(th), 1.0, 1.5))


class TestRefract:
    @pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.0, 1.333), (1.0, 2.42), (1.5, 1.0), (2.42, 1.0), (1.5, 1.2)])
    def test_snell_invariant(self, n1, n2):
        th = torch.linspace(0.0, math.radians(89.9), 500, dtype=torch.float64)
        d = incoming(th)
        out, tir = refract(d, N_UP.expand_as(d), n1 / n2)
        ok = ~tir
        assert ok.any()
        lhs = n1 * torch.sin(th[ok])
        rhs = n2 * sin_to_normal(out[ok])
        torch.testing.assert_close(lhs, rhs, rtol=0, atol=1e-12)
        # transmitted rays continue downwards, in the plane of incidence, with unit length
        assert torch.all(out[ok][:, 2] < 0)
        torch.testing.assert_close(out[:, 1], torch.zeros_like(out[:, 1]), rtol=0, atol=1e-15)
        torch.testing.assert_close(torch.linalg.vector_norm(out, dim=-1), torch.ones(len(th), dtype=torch.float64))

    def test_total_internal_reflection(self):
        crit = math.asin(1 / 1.5)
        th = torch.tensor([crit - 1e-3, crit + 1e-3, 1.2, 1.5], dtype=torch.float64)
        d = incoming(th)
        out, tir = refract(d, N_UP.expand_as(d), 1.5)
        assert tir.tolist() == [False, True, True, True]
        torch.testing.assert_close(out[tir], reflect(d[tir], N_UP.expand_as(d[tir])))
        assert torch.all(out[tir][:, 2] > 0)  # mirrored back up

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_unit_ior_is_identity(self, seed):
        """``gamma = 1 - (1 - beta^2)`` carries the rounding of ``1 - beta^2`` (at most ``u``), so
        ``sqrt(gamma)`` is off ``beta`` by at most ``u / (2 beta)`` (``sqrt(u)`` as ``beta -> 0``): grazing
        rays leave IOR 1 with that error, plus a few ``u`` from the products; twice the bound."""
        g = torch.Generator().manual_seed(seed)
        d = torch.nn.functional.normalize(torch.randn(1000, 3, dtype=torch.float64, generator=g), dim=-1)
        n = face_forward(
            torch.nn.functional.normalize(torch.randn(1000, 3, dtype=torch.float64, generator=g), dim=-1), d
        )
        out, tir = refract(d, n, 1.0)
        assert not tir.any()
        beta = -(d * n).sum(-1)
        tol = 2 * (torch.minimum(EPS64 / beta, torch.tensor(2 * EPS64).sqrt()) + 4 * EPS64)
        assert ((out - d).abs().amax(-1) <= tol).all()
        near = beta > 1e-3  # away from grazing the error stays at rounding level
        torch.testing.assert_close(out[near], d[near], rtol=0, atol=1e-12)

    def test_ior_near_one_is_continuous(self):
        th = torch.linspace(0.0, 1.4, 50, dtype=torch.float64)
        d = incoming(th)
        out, _ = refract(d, N_UP.expand_as(d), 1 / (1 + 1e-6))
        assert float((out - d).abs().max()) < 1e-5

    def test_in_and_out_of_a_slab_recovers_direction(self):
        th = torch.linspace(0.0, math.radians(89.0), 100, dtype=torch.float64)
        d = incoming(th)
        n = N_UP.expand_as(d)
        inside, tir_in = refract(d, n, 1 / 1.5)
        out, tir_out = refract(inside, n, 1.5)  # the parallel back face; normal still faces the ray
        assert not tir_in.any() and not tir_out.any()
        torch.testing.assert_close(out, d, rtol=0, atol=1e-12)

    def test_grazing_incidence_is_finite(self):
        d = incoming(torch.tensor([math.pi / 2, math.pi / 2 - 1e-12], dtype=torch.float64))
        for eta in (1 / 1.5, 1.5, 1.0):
            out, _ = refract(d, N_UP.expand_as(d), eta)
            assert torch.all(torch.isfinite(out))
        out32, _ = refract(d.float(), N_UP.float().expand_as(d), 1 / 1.5)
        assert out32.dtype == torch.float32 and torch.all(torch.isfinite(out32))
        # entering at grazing incidence bends to the critical angle
        out, _ = refract(d[:1], N_UP[None], 1 / 1.5)
        assert float(sin_to_normal(out)) == pytest.approx(1 / 1.5, abs=1e-9)

    def test_per_ray_eta_broadcasts(self):
        d = incoming(torch.full((3,), 0.5, dtype=torch.float64))
        eta = torch.tensor([1.0, 1 / 1.5, 1.5], dtype=torch.float64)
        out, _ = refract(d, N_UP.expand_as(d), eta)
        for i in range(3):
            ref, _ = refract(d[i : i + 1], N_UP[None], float(eta[i]))
            torch.testing.assert_close(out[i], ref[0])


def test_reflect_is_involution_and_preserves_length():
    d = torch.nn.functional.normalize(torch.randn(100, 3, dtype=torch.float64), dim=-1)
    n = torch.nn.functional.normalize(torch.randn(100, 3, dtype=torch.float64), dim=-1)
    r = reflect(d, n)
    torch.testing.assert_close(reflect(r, n), d)
    torch.testing.assert_close(torch.linalg.vector_norm(r, dim=-1), torch.ones(100, dtype=torch.float64))
    torch.testing.assert_close((r * n).sum(-1), -(d * n).sum(-1))


def test_adjoint_correction_is_one_on_flat_faces_and_reverses_with_the_path():
    """Veach's adjoint factor |(ns·wi)(ng·wo)| / |(ns·wo)(ng·wi)|: 1 where the shading normal is the
    face normal, the reciprocal for the reversed path (wo and wi swapped), and the hand value for a
    tilted shading normal."""
    from snell_bench.optics.functional import adjoint_correction

    g = torch.Generator().manual_seed(0)
    unit = lambda: torch.nn.functional.normalize(torch.randn(64, 3, dtype=torch.float64, generator=g), dim=-1).numpy()
    d, d_new, ng = unit(), unit(), unit()
    ns = ng + 0.1 * unit()
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    np.testing.assert_allclose(adjoint_correction(d, d_new, ng, ng), 1.0, rtol=4 * EPS64)
    np.testing.assert_allclose(
        adjoint_correction(d, d_new, ns, ng) * adjoint_correction(-d_new, -d, ns, ng), 1.0, rtol=16 * EPS64
    )
    s = math.sin(0.2)
    ns1, ng1 = np.array([[s, 0.0, math.cos(0.2)]]), np.array([[0.0, 0.0, 1.0]])
    di, do = np.array([[0.0, 0.0, -1.0]]), np.array([[0.6, 0.0, -0.8]])
    expected = abs(-math.cos(0.2) * -0.8) / abs((0.6 * s - 0.8 * math.cos(0.2)) * -1.0)
    assert float(adjoint_correction(di, do, ns1, ng1)[0]) == pytest.approx(expected, rel=4 * EPS64)
