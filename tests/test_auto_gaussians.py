"""``--gaussians auto``: the Gaussians per view chosen from the material, as documented in
``lobelight.fit._auto`` (two for long-tailed lobes of moderate roughness carrying most of the
reflected light, one otherwise)."""

from __future__ import annotations

import math

import pytest
import torch

from lobelight import brdf, fit, scene
from lobelight.cli import main
from lobelight.scene import Materials


def _uniform(spec, diffuse=0.0, v: int = 8) -> Materials:
    return Materials(torch.full((v, 3), float(diffuse)), spec)


@pytest.mark.parametrize("alpha", [0.03, 0.08, 0.12, 0.2])
def test_the_width_of_a_ggx_lobe_is_its_alpha(alpha):
    # closed form: GGX half vectors have P(tan^2 theta_h < t) = t / (alpha^2 + t), so their
    # median tan theta_h is alpha, and at normal incidence the light direction's angle is
    # 2 theta_h: tan(theta / 2) = alpha. Tolerance 6 %: a 32 x 32 stratified sample's
    # weighted median is one of 1,024 samples (the quantile's step is 1/1,024 of the mass,
    # ~0.3 % of the angle near the median), plus masking-shadowing and the cut at the horizon,
    # which weigh the wider half vectors slightly less (~4 % at alpha 0.2)
    m = fit.lobe_shape(_uniform(brdf.GGX(alpha=alpha, specular=0.9)), torch.arange(2))
    assert float(m["alpha"][0]) == pytest.approx(alpha, rel=0.06)


@pytest.mark.parametrize("exponent", [30.0, 300.0])
def test_a_round_lobe_has_the_tail_of_a_gaussian(exponent):
    # closed form: a Phong lobe cos^e is a 2D Gaussian in the angle to first order, whose
    # radius has P(r < x) = 1 - exp(-x^2 / 2 s^2): the 90th over the 50th percentile is
    # sqrt(ln 10 / ln 2) = 1.823. Tolerance 2 %: the sample's quantile step (above) and the
    # lobe's departure from a Gaussian at e = 30 (cos^e = exp(e ln cos), ln cos = -t^2/2 - t^4/12)
    m = fit.lobe_shape(_uniform(brdf.Phong(exponent=exponent, specular=0.9)), torch.arange(2))
    assert float(m["tail"][0]) == pytest.approx(math.sqrt(math.log(10) / math.log(2)), rel=0.02)
    assert float(m["tail"][0]) < fit._auto.AUTO_MIN_TAIL


def test_the_share_is_the_specular_albedo_against_the_diffuse():
    # a GGX lobe of F0 0.04 with no Fresnel term reflects 0.04 times its masking (< 1) at
    # normal incidence: against a 0.5 diffuse its share is just under 0.04 / 0.54
    m = fit.lobe_shape(_uniform(brdf.GGX(alpha=0.1, specular=0.04), 0.5), torch.arange(2))
    assert 0.9 * 0.04 / 0.54 <= float(m["share"][0]) <= 0.04 / 0.54


@pytest.mark.parametrize(
    ("material", "n"),
    [
        ("ggx:alpha=0.03,specular=0.95,0.8,0.6", 1),  # sharp metal: placement, not shape
        ("ggx:alpha=0.04,specular=0.9", 1),
        ("ggx:alpha=0.12,specular=0.9", 2),  # moderate roughness, long tails, all the light
        ("ggx:alpha=0.25,specular=0.95,0.8,0.6", 2),  # the gallery's rough metal
        ("ggx:alpha=0.1,specular=0.04,diffuse=0.5", 1),  # plastic: a small share
        ("ggx:alpha=0.25,specular=0.3,diffuse=0.6", 1),  # a third of the light
        ("phong:exponent=30,specular=0.9", 1),  # a round lobe one Gaussian fits
        ("beckmann:alpha=0.25,specular=0.9", 1),  # Beckmann's tails are round too
        ("diffuse:color=0.7", 1),  # no glossy lobe
    ],
)
def test_auto_picks_per_material_as_documented(material, n):
    sc = scene.load("sphere:0", material=material)
    got, reason = fit.choose_gaussians(sc.materials)
    assert got == n, reason
    assert reason.endswith(f": {n}")


def test_a_per_vertex_material_takes_its_majority():
    # 3/4 of the vertices a rough metal, 1/4 plastic: two; the other way round: one
    v = 64
    rough = torch.arange(v) < 48
    for share_rough, want in ((rough, 2), (~rough, 1)):
        spec = brdf.GGX(
            alpha=torch.full((v,), 0.2),
            specular=torch.where(share_rough[:, None], 0.9, 0.04).expand(v, 3).clone(),
        )
        diffuse = torch.where(share_rough[:, None], 0.0, 0.5).expand(v, 3).clone()
        got, reason = fit.choose_gaussians(Materials(diffuse, spec))
        assert got == want, reason
        assert "glossy vertices" in reason  # it says it decided by the majority
    # the built-in knot: a Phong gradient from diffuse to sharp, one
    assert fit.choose_gaussians(scene.load("knot").materials)[0] == 1


def test_the_choice_and_its_reason_are_in_the_provenance():
    sc = scene.load("sphere:0", material="ggx:alpha=0.25,specular=0.9")
    m = fit.fit_model(sc, indirect_paths=0, bounces=0, progress=None)
    choice = m.provenance["n_gaussians_choice"]
    assert m.provenance["n_gaussians"] == m.direct_gaussians == 2
    assert choice["asked"] == "auto" and choice["reason"].endswith(": 2")
    forced = fit.fit_model(sc, 1, indirect_paths=0, bounces=0, progress=None)
    assert forced.direct_gaussians == 1
    assert forced.provenance["n_gaussians_choice"] == {"asked": 1, "reason": "asked for 1"}
    with pytest.raises(ValueError, match="auto"):
        fit.fit_model(sc, "two")


def test_the_bake_flag_takes_auto_or_a_count(tmp_path, capsys):
    import json

    model = tmp_path / "s.npz"
    args = ["bake", "sphere:0", "--material", "ggx:alpha=0.03,specular=0.9", "-o", str(model)]
    args += ["--json", "-q"]
    assert main([*args, "--indirect-paths", "0", "--bounces", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_gaussians"] == 1 and out["n_gaussians_choice"]["asked"] == "auto"
    assert main([*args, "--gaussians", "2", "--indirect-paths", "0", "--bounces", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_gaussians"] == 2 and out["n_gaussians_choice"]["asked"] == 2
    assert main([*args, "--gaussians", "many"]) == 2  # a usage error
