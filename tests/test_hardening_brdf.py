"""Materials whose parameters made non-finite lobes: taken at the sharpest lobe lobelight models
with a warning (Ward's roughness, the cosine-power exponents), or refused at the door (a
Lafortune lobe set whose light overflows), so that a bake never fits NaN."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from lobelight import brdf, model
from lobelight.cli import main
from lobelight.errors import InputError


def _half_max_angle(spec) -> float:
    """The angle from the mirror direction at which the lobe ``f cos`` falls to half its peak,
    at normal incidence (float64, a fine grid about the peak)."""
    spec = spec.to("cpu", torch.float64)
    theta = torch.linspace(0, 1e-2, 200_001, dtype=torch.float64)  # 5e-8 radian steps
    w = torch.stack([torch.sin(theta), torch.zeros_like(theta), torch.cos(theta)], -1)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(w)
    f = spec.eval(w, n, n).mean(-1) * torch.cos(theta)
    return float(theta[int((f >= 0.5 * f[0]).nonzero().max())])


def test_ward_alpha_1e_6_is_taken_as_the_sharpest_lobe_with_a_warning():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        w = brdf.Ward(0.5, 1e-6)
    # one warning for an isotropic lobe's one roughness
    assert [str(c.message)[:40] for c in caught] == ["lobelight: ward alpha_x 1e-06 is below 0"]
    assert float(w.params["alpha_x"]) == pytest.approx(brdf.MIN_ROUGHNESS, rel=1e-7)
    assert float(w.params["alpha_y"]) == pytest.approx(brdf.MIN_ROUGHNESS, rel=1e-7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # at the bound: no warning
        brdf.Ward(0.5, brdf.MIN_ROUGHNESS, 0.3)


@pytest.mark.parametrize(
    ("cls", "bound"),
    [(brdf.BlinnPhong, brdf.MAX_HALF_VECTOR_EXPONENT), (brdf.Phong, brdf.MAX_EXPONENT)],
)
def test_an_exponent_of_1e9_is_taken_as_the_sharpest_lobe_with_a_warning(cls, bound):
    with pytest.warns(UserWarning, match=rf"lobelight: {cls.type_name} exponent 1e\+09 is above"):
        b = cls(0.5, 1e9)
    assert float(b.params["exponent"]) == pytest.approx(bound, rel=1e-7)


@pytest.mark.parametrize(
    "spec",
    [
        brdf.Ward(0.5, brdf.MIN_ROUGHNESS),
        brdf.BlinnPhong(0.5, brdf.MAX_HALF_VECTOR_EXPONENT),
        brdf.Phong(0.5, brdf.MAX_EXPONENT),
    ],
    ids=["ward", "blinn_phong", "phong"],
)
def test_every_model_s_sharpest_lobe_is_as_wide_as_beckmann_s(spec):
    # the bounds are one sharpness: the half-maximum angle of the reflected lobe of a Beckmann
    # distribution of roughness 1e-4, exp(-theta^2 / (4 alpha^2)) near the mirror direction,
    # theta = 2 alpha sqrt(ln 2) (closed form); 2 % covers the small-angle approximations
    # (terms of order theta^2 = 1e-8) and the grid (5e-8 of 1.7e-4)
    expected = 2 * brdf.MIN_ROUGHNESS * math.sqrt(math.log(2))
    assert _half_max_angle(spec) == pytest.approx(expected, rel=0.02)


def test_a_lafortune_lobe_set_whose_light_overflows_is_refused():
    # |c| = 2 and exponent 200: the lobe reaches 2^200 = 1.6e60, Inf in float32; its albedo
    # bound is 2 pi 2^200 / 201 = 5.02e58
    lobe = {"cx": -2.0, "cy": -2.0, "cz": 2.0, "exponent": 200.0, "rho": 1.0}
    with pytest.raises(InputError, match=r"lobes: reflect up to 5\.02e\+58 times the light"):
        brdf.Lafortune([lobe])
    with pytest.warns(UserWarning, match=r"lafortune lobes\[0\]\.exponent 1e\+09 is above"):
        lf = brdf.Lafortune([{**lobe, "cx": -1.0, "cy": -1.0, "cz": 1.0, "exponent": 1e9}])
    assert float(lf.params["lobes[0].exponent"]) == pytest.approx(brdf.MAX_EXPONENT, rel=1e-7)


@pytest.mark.parametrize(
    "material", ["ward:alpha_x=1e-6,specular=0.5", "blinn_phong:exponent=1e9,specular=0.5"]
)
def test_a_bake_of_a_too_sharp_material_writes_a_model_the_reader_accepts(
    tmp_path, material, capsys
):
    # both baked with exit 0, a fit error of NaN, and a file every reader refused
    out = tmp_path / "m.npz"
    argv = ["bake", "sphere:1", "--material", material, "-o", str(out)]
    assert main([*argv, "--bounces", "0", "--indirect-paths", "0", "-q"]) == 0
    err = capsys.readouterr().err
    assert "is below 0.0001" in err or "is above 2e+08" in err, err
    m = model.load(out)
    assert math.isfinite(m.provenance["relative_l2_error_mean"])
    assert bool(torch.isfinite(m.gaussians.w).all()) and bool(torch.isfinite(m.gaussians.lam).all())
    assert np.isfinite(m.diffuse.numpy()).all()


def test_a_parameter_blended_at_its_bound_is_accepted():
    """White vertices blended with barycentrics that sum to 1 within an ulp land an ulp above 1:
    accepted (float32 rounding); a real excess is still refused."""
    b = torch.tensor([0.2, 0.3, 0.5], dtype=torch.float32)
    white = (torch.ones(3, 3) * b[:, None]).sum(0) * (1 + 2.0**-23)
    brdf.Lambert(white)
    with pytest.raises(InputError, match="must be <= 1"):
        brdf.Lambert(torch.tensor([1.001, 0.5, 0.5]))
