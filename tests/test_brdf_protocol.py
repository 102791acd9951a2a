"""The BRDF protocol: every registered model answers every capability with the right type, the
built-in models answer it correctly, and a model registered from outside the package (this
file's own) is read by ``from_dict`` and by the scene files with that one registration.

The toy model here, :class:`Retro`, is the worked example of ``docs/contributing.md``.
"""

from __future__ import annotations

import inspect
import json
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import pytest
import torch
import trimesh

import lobelight
from lobelight import brdf, scene
from lobelight.brdf import BRDF, CosineLobe
from lobelight.brdf._base import (
    _COLOR,
    _COLOUR,
    _NUMBER,
    _PI,
    _REGISTRY,
    _SCALAR,
    _color_as,
    _cospow,
    _mean_color,
    _sample_cospow,
)
from lobelight.errors import InputError
from lobelight.fit._data import half_vector_lobes
from lobelight.geometry import sphere
from lobelight.render._sun_glossy import (
    sun_glossy_supported,
    sun_glossy_uniforms,
    sun_glossy_vertex_params,
)
from lobelight.sgbrdf import is_isotropic

F64 = torch.float64
V = 4  # elements (vertices) of the per-element parameters in the examples
_CU = {"eta": [0.2, 0.92, 1.1], "k": [3.9, 2.45, 2.14]}  # copper-like complex IOR
_LOBES = [
    {"cx": -0.9, "cy": -0.6, "cz": 0.8, "exponent": 8.0, "rho": 0.1},
    {"cx": 0.0, "cy": 0.0, "cz": 1.0, "exponent": 2.0, "rho": [0.05, 0.04, 0.03]},
]
_ROUND_LOBES = [{"cx": -0.8, "cy": -0.8, "cz": 0.9, "exponent": 12.0, "rho": 0.2}]


# --------------------------------------------------------------------------------------------
# the toy model (docs/contributing.md): retro-reflection, a cosine-power lobe about the viewer


class Retro(BRDF):
    """Retro-reflection ``f = ks (e + 1)/(2 pi) pos(wo.wi)^e``: light goes back where it came
    from. Reciprocal; the albedo is at most ``ks``. Sampled by the lobe itself.

    Parameters
    ----------
    specular : () or (..., 3) ``ks`` in [0, 1]
    exponent : () or (...) ``e >= 0``
    """

    type_name = "toy_retro"
    scene_params: ClassVar[Mapping[str, str]] = {"specular": _COLOUR, "exponent": _NUMBER}

    def __init__(self, specular: Any, exponent: Any):
        super().__init__()
        self._set("specular", specular, _COLOR, lo=0.0, hi=1.0)
        self._set("exponent", exponent, _SCALAR, lo=0.0)
        self._check_shapes()

    def _eval(self, wi, wo):
        e = self._get("exponent", wi)
        lobe = (e + 1) / (2 * _PI) * _cospow(wo, wi, e)
        return lobe.unsqueeze(-1) * self._get("specular", wi)

    def _pdf(self, wi, wo):
        e = self._get("exponent", wi)
        return (e + 1) / (2 * _PI) * _cospow(wo, wi, e)

    def _sample_dir(self, wo, u):
        e = self._get("exponent", wo)
        axis, e, u0, u1 = torch.broadcast_tensors(wo, e[..., None], u[..., :1], u[..., 1:2])
        return _sample_cospow(axis, e[..., 0], u0[..., 0], u1[..., 0])

    def _albedo_guess(self, wo):
        return _mean_color(self._get("specular", wo)) + torch.zeros_like(wo[..., 2])

    @property
    def isotropic(self) -> bool:
        return True

    @property
    def cosine_lobe_flags(self) -> tuple[bool, ...]:
        return (False,)

    def _cosine_lobes(self, wo):
        batch = wo.shape[:-1]
        e = self._get("exponent", wo).expand(batch)
        ks = _color_as(self._get("specular", wo), batch)
        return [CosineLobe(wo, e, ks * ((e + 1) / (2 * _PI)).unsqueeze(-1), False)]


@pytest.fixture
def retro():
    """:class:`Retro` registered for one test (and taken out of the registry after it)."""
    assert "toy_retro" not in brdf.REGISTRY
    brdf.register(Retro)
    try:
        yield Retro
    finally:
        _REGISTRY.pop("toy_retro", None)


# --------------------------------------------------------------------------------------------
# every registered model answers every capability


def examples() -> dict[str, list[BRDF]]:
    """Typical instances of every built-in model, by type name (per-vertex ones too)."""
    g = torch.Generator().manual_seed(0)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=g)

    return {
        "lambert": [brdf.Lambert([0.5, 0.4, 0.3]), brdf.Lambert(rand(V, 3))],
        "phong": [brdf.Phong(0.5, 20.0), brdf.Phong(rand(V, 3), 1 + 50 * rand(V))],
        "blinn_phong": [brdf.BlinnPhong(0.5, 30.0)],
        "ward": [brdf.Ward(0.5, 0.2), brdf.Ward(0.5, 0.1, 0.35)],
        "lafortune": [brdf.Lafortune(_LOBES), brdf.Lafortune(_ROUND_LOBES)],
        "ggx": [
            brdf.GGX(0.2),
            brdf.GGX(0.05 + 0.3 * rand(V), specular=rand(V, 3)),
            brdf.GGX(alpha_u=0.15, alpha_v=0.5, **_CU),
        ],
        "beckmann": [brdf.Beckmann(0.3, **_CU), brdf.Beckmann(alpha_u=0.4, alpha_v=0.15)],
        "ggx_schlick": [
            brdf.GGXSchlick(0.2, [0.9, 0.6, 0.3]),
            brdf.metallic_roughness(rand(V, 3), rand(V), rand(V))[1],
        ],
        "sum": [
            brdf.Sum(brdf.Lambert(0.5), brdf.GGX(0.2, specular=0.5)),
            brdf.Sum(brdf.Lambert(0.2), brdf.Phong(0.4, 5.0), brdf.Lafortune(_LOBES)),
        ],
    }


def test_every_registered_model_has_examples_here():
    # a new model is tested below once it has typical instances in examples()
    assert list(brdf.REGISTRY) == list(examples())


def _directions(seed: int, shape: tuple[int, ...] = (16, V)):
    """Unit normals, tangents, views above the horizon and lights (some below): (*shape, 3)."""
    g = torch.Generator().manual_seed(seed)
    n = torch.nn.functional.normalize(torch.randn(*shape, 3, generator=g, dtype=F64), dim=-1)
    t, b, _ = sphere.frame(n)

    def world(z_lo: float) -> torch.Tensor:
        z = z_lo + (1 - z_lo) * torch.rand(*shape, 1, generator=g, dtype=F64)
        phi = 2 * math.pi * torch.rand(*shape, 1, generator=g, dtype=F64)
        r = torch.sqrt(1 - z * z)
        return r * torch.cos(phi) * t + r * torch.sin(phi) * b + z * n

    return n, t, world(0.05), world(-0.3)


def check_capabilities(model: BRDF) -> None:
    """Every capability answers on ``model`` with the right type (and, where it can be checked
    against the model's own values, the right value)."""
    cls = type(model)
    assert brdf.REGISTRY[cls.type_name] is cls
    assert isinstance(model.isotropic, bool)
    assert is_isotropic(model) is model.isotropic
    assert isinstance(cls.half_vector_lobe, bool)
    assert isinstance(model.fresnel, bool)
    assert model.fresnel == ("eta" in model.params)
    assert isinstance(model.schlick, bool)
    assert model.schlick == ("f0" in model.params)

    # scene files: the keys are the constructor's arguments
    if cls.scene_params is not None:
        assert isinstance(cls.scene_params, Mapping)
        args = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
        assert sorted(cls.scene_params) == sorted(args)
        assert set(cls.scene_params.values()) <= {"number", "colour", "lobes"}

    # the sun shader
    if model.sun_model is None:
        assert not sun_glossy_supported(model)
        with pytest.raises(InputError):
            model.sun_widened(0.05)
    else:
        assert isinstance(model.sun_model, int)
        assert sun_glossy_supported(model)
        assert model.sun_param in model.params
        wide = model.sun_widened(0.05)
        assert type(wide) is cls and wide.params.keys() == model.params.keys()
        assert not torch.equal(wide.params[model.sun_param], model.params[model.sun_param])
        assert sun_glossy_uniforms(model)["sun_model"] == model.sun_model
        assert sun_glossy_vertex_params(model, V).shape == (V, 10)
    assert model.sun_widened(0.0) is model

    # cosine lobes: they sum to f_r (n.wi)
    n, t, wo, wi = _directions(5)
    batch = wo.shape[:-1]
    flags = model.cosine_lobe_flags
    lobes = model.cosine_lobes(wo, n, t)
    if flags is None:
        assert lobes is None
    else:
        assert isinstance(flags, tuple) and all(isinstance(f, bool) for f in flags)
        assert [lobe.cosine for lobe in lobes] == list(flags)
        total = torch.zeros(*batch, 3, dtype=F64)
        cos = (n * wi).sum(-1, keepdim=True).clamp_min(0)
        for lobe in lobes:
            assert isinstance(lobe, CosineLobe)
            assert lobe.axis.shape == (*batch, 3) and lobe.exponent.shape == batch
            assert lobe.scale.shape == (*batch, 3)
            torch.testing.assert_close(lobe.axis.norm(dim=-1), torch.ones(batch, dtype=F64))
            power = (lobe.axis * wi).sum(-1, keepdim=True).clamp_min(0) ** lobe.exponent[..., None]
            total += lobe.scale * power * (1 if lobe.cosine else cos)
        torch.testing.assert_close(total, model.eval(wi, wo, n, t) * cos)

    # Mitsuba: a BSDF dict of plain values, or an InputError naming the materials
    try:
        d = model.mitsuba_dict()
    except InputError as exc:
        assert exc.what == "materials"
    else:
        assert isinstance(d["type"], str)
        json.dumps(d)  # plain values only

    # serialisation through the registry
    back = brdf.from_dict(json.loads(json.dumps(model.to_dict())))
    assert type(back) is cls


@pytest.mark.parametrize(
    "model",
    [m for ms in examples().values() for m in ms],
    ids=[f"{name}{j}" for name, ms in examples().items() for j in range(len(ms))],
)
def test_every_capability_answers(model):
    check_capabilities(model)


# --------------------------------------------------------------------------------------------
# the built-in models' answers


_ISOTROPIC = [
    (brdf.Lambert(0.5), True),
    (brdf.Phong(0.5, 10.0), True),
    (brdf.BlinnPhong(0.5, 10.0), True),
    (brdf.Ward(0.5, 0.2), True),
    (brdf.Ward(0.5, 0.2, 0.2), True),
    (brdf.Ward(0.5, 0.1, 0.35), False),
    (brdf.Ward(0.5, torch.tensor([0.1, 0.2]), torch.tensor([0.1, 0.3])), False),
    (brdf.Lafortune(_ROUND_LOBES), True),
    (brdf.Lafortune(_LOBES), False),
    (brdf.GGX(0.2), True),
    (brdf.GGX(alpha_u=0.2, alpha_v=0.2), True),
    (brdf.GGX(alpha_u=0.1, alpha_v=0.3), False),
    (brdf.Beckmann(alpha_u=0.4, alpha_v=0.15), False),
    (brdf.GGXSchlick(0.2, [0.9, 0.5, 0.1]), True),
    (brdf.Sum(brdf.Lambert(0.5), brdf.GGX(0.2)), True),
    (brdf.Sum(brdf.Lambert(0.5), brdf.Ward(0.5, 0.1, 0.35)), False),
]


@pytest.mark.parametrize(("model", "expected"), _ISOTROPIC, ids=[repr(m) for m, _ in _ISOTROPIC])
def test_isotropic(model, expected):
    assert model.isotropic is expected
    assert is_isotropic(model) is expected


def test_isotropic_is_what_it_says():
    # an isotropic model's value is unchanged by turning both directions about the normal
    n, t, wo, wi = _directions(3)
    for model, expected in _ISOTROPIC:
        if any(shape for _, shape in model._batch_shapes()):
            continue  # per-element parameters of another length than the directions'
        turned = torch.nn.functional.normalize(t + 0.7 * torch.linalg.cross(n, t), dim=-1)
        same = torch.allclose(model.eval(wi, wo, n, t), model.eval(wi, wo, n, turned), rtol=1e-6)
        assert same is expected, model


def test_single_alpha_is_how_a_conductor_was_built():
    assert brdf.GGX(0.2).single_alpha and brdf.Beckmann(0.2).single_alpha
    round_uv = brdf.GGX(alpha_u=0.2, alpha_v=0.2)
    assert not round_uv.single_alpha and round_uv.isotropic
    assert round_uv.sun_model is None  # the shader reads one alpha


def test_half_vector_lobes():
    half = {"ggx", "beckmann", "blinn_phong", "ward", "ggx_schlick"}
    for name, models in examples().items():
        for model in models:
            assert model.half_vector_lobe is (name in half), name
            assert half_vector_lobes(model) is (name in half)
    assert half_vector_lobes(None) is False


def _shader_models() -> dict[str, int]:
    """``sun_model`` ids by name, from the shader's own comment on the uniform."""
    text = (Path(lobelight.__file__).parent / "render" / "shaders" / "brdf.glsl").read_text()
    line = next(ln for ln in text.splitlines() if "uniform int sun_model;" in ln)
    return {name.strip(): int(i) for i, name in re.findall(r"(\d) ([A-Za-z -]+)", line)}


def test_sun_models_are_the_shader_s():
    ids = _shader_models()
    assert brdf.GGX(0.1).sun_model == ids["GGX"]
    assert brdf.Beckmann(0.1, **_CU).sun_model == ids["Beckmann"]
    assert brdf.Phong(0.5, 10.0).sun_model == ids["modified Phong"]
    assert brdf.BlinnPhong(0.5, 10.0).sun_model == ids["Blinn-Phong"]
    for model in (
        brdf.Lambert(0.5),
        brdf.Ward(0.5, 0.1),
        brdf.Lafortune(_LOBES),
        brdf.GGX(alpha_u=0.1, alpha_v=0.3),
        brdf.Sum(brdf.Lambert(0.5), brdf.GGX(0.1)),
    ):
        assert model.sun_model is None, model
    assert brdf.GGX(0.1).sun_param == "alpha" and brdf.Phong(0.5, 1.0).sun_param == "exponent"
    assert brdf.BlinnPhong(0.5, 1.0).sun_param == "exponent"
    assert brdf.GGX(0.1, **_CU).fresnel and not brdf.GGX(0.1).fresnel
    schlick = brdf.GGXSchlick(0.1, 0.5)
    assert schlick.sun_model == ids["GGX"] and schlick.sun_param == "alpha"
    assert schlick.schlick and not schlick.fresnel and not brdf.GGX(0.1, **_CU).schlick
    # the shader reads Schlick's F0 in the conductor's eta slot, with a unit specular factor
    assert sun_glossy_uniforms(schlick)["sun_fresnel"] == 2.0
    assert sun_glossy_uniforms(brdf.GGX(0.1, **_CU))["sun_fresnel"] == 1.0
    f0 = torch.rand(V, 3)
    sb = sun_glossy_vertex_params(brdf.GGXSchlick(torch.rand(V), f0), V)
    assert (sb[:, 1:4] == 1).all() and (sb[:, 7:] == 0).all()
    torch.testing.assert_close(torch.from_numpy(sb[:, 4:7]), f0)


def test_sun_widened_adds_the_disc_s_variance():
    s = 0.1
    ggx = brdf.GGX(0.2).sun_widened(s)
    assert float(ggx.params["alpha"]) == pytest.approx(math.sqrt(0.2**2 + s**2 / 4), rel=1e-6)
    phong = brdf.Phong(0.5, 100.0).sun_widened(s)
    assert float(phong.params["exponent"]) == pytest.approx(1 / (1 / 100 + s**2 / 2), rel=1e-6)
    blinn = brdf.BlinnPhong(0.5, 100.0).sun_widened(s)
    a2 = 2 / (100 + 2) + s**2 / 4
    assert float(blinn.params["exponent"]) == pytest.approx(2 / a2 - 2, rel=1e-5)


def test_mitsuba_dicts():
    assert brdf.GGX(0.2).mitsuba_dict() == {
        "type": "roughconductor",
        "distribution": "ggx",
        "alpha": pytest.approx(0.2),
        "material": "none",
        "specular_reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]},
    }
    d = brdf.Beckmann(alpha_u=0.1, alpha_v=0.3, specular=[0.9, 0.8, 0.7], **_CU).mitsuba_dict()
    assert d["type"] == "roughconductor" and d["distribution"] == "beckmann"
    assert (d["alpha_u"], d["alpha_v"]) == (pytest.approx(0.1), pytest.approx(0.3))
    assert d["eta"]["value"] == pytest.approx(_CU["eta"]) and "material" not in d
    assert d["specular_reflectance"]["value"] == pytest.approx([0.9, 0.8, 0.7])
    assert brdf.GGXSchlick(0.09, [0.9, 0.5, 0.2]).mitsuba_dict() == {
        "type": "principled",
        "base_color": {"type": "rgb", "value": pytest.approx([0.9, 0.5, 0.2])},
        "metallic": 1.0,
        "roughness": pytest.approx(0.3),
    }
    for model in (brdf.Phong(0.5, 10.0), brdf.Ward(0.5, 0.1), brdf.Lambert(0.5)):
        with pytest.raises(InputError, match="no Mitsuba counterpart") as err:
            model.mitsuba_dict()
        assert err.value.what == "materials"


def test_cosine_lobe_flags():
    lam, phong, laf = brdf.Lambert(0.5), brdf.Phong(0.5, 10.0), brdf.Lafortune(_LOBES)
    assert lam.cosine_lobe_flags == (True,)
    assert phong.cosine_lobe_flags == (False,)
    assert laf.cosine_lobe_flags == (False, False)
    assert brdf.Sum(lam, phong, laf).cosine_lobe_flags == (True, False, False, False)
    assert brdf.GGX(0.1).cosine_lobe_flags is None
    assert brdf.Sum(lam, brdf.GGX(0.1)).cosine_lobe_flags is None
    n, t, wo, _ = _directions(1)
    assert brdf.Sum(lam, brdf.GGX(0.1)).cosine_lobes(wo, n, t) is None


def test_specular_models_are_the_registry_s():
    registered = [name for name, cls in brdf.REGISTRY.items() if cls.scene_params is not None]
    assert list(scene.SPECULAR_MODELS) == registered
    assert set(registered) == {
        "phong",
        "blinn_phong",
        "ward",
        "lafortune",
        "ggx",
        "beckmann",
        "ggx_schlick",
    }
    for name in registered:
        assert scene.MODEL_PARAMS[name] is brdf.REGISTRY[name].scene_params
    assert "lambert" not in scene.SPECULAR_MODELS and "sum" not in scene.MODEL_PARAMS


# --------------------------------------------------------------------------------------------
# registering a model


def test_an_unregistered_model_is_unknown():
    with pytest.raises(InputError, match="unknown BRDF type 'toy_retro'"):
        brdf.from_dict({"type": "toy_retro", "specular": 0.5, "exponent": 10.0})
    with pytest.raises(InputError, match="unknown model 'toy_retro'"):
        scene.parse_material("toy_retro:specular=0.5,exponent=10")


def test_one_registration_makes_a_model_loadable(retro, tmp_path):
    # from_dict
    model = brdf.from_dict({"type": "toy_retro", "specular": 0.5, "exponent": 10.0})
    assert isinstance(model, Retro)
    assert brdf.BRDF.from_dict(model.to_dict()).to_dict() == model.to_dict()
    check_capabilities(model)
    check_capabilities(Retro(torch.rand(V, 3), 1 + 30 * torch.rand(V)))
    # the scene's tables
    assert "toy_retro" in scene.SPECULAR_MODELS
    assert scene.MODEL_PARAMS["toy_retro"] == {"specular": "colour", "exponent": "number"}
    # a one-line spec, a material table, a gradient and a scene file
    mats = scene.parse_material("toy_retro:specular=0.5,exponent=10,diffuse=0.2", 3)
    assert isinstance(mats.specular, Retro) and mats.model == "toy_retro"
    table = {"diffuse": 0.2, "model": "toy_retro", "specular": [0.5, 0.4, 0.3], "exponent": 10}
    assert isinstance(scene.uniform(table, 3).specular, Retro)
    grad = scene.gradient(table, {**table, "exponent": 40}, torch.tensor([0.0, 0.5, 1.0]))
    assert grad.specular.params["exponent"].tolist() == pytest.approx([10.0, 20.0, 40.0])
    back = scene.Materials.from_dict(json.loads(json.dumps(mats.to_dict())), 3)
    assert isinstance(back.specular, Retro)
    with pytest.raises(InputError, match="alpha"):
        scene.parse_material("toy_retro:alpha=0.1")
    trimesh.creation.icosphere(1).export(tmp_path / "ball.ply")
    (tmp_path / "s.toml").write_text(
        'mesh = "ball.ply"\n[material]\nmodel = "toy_retro"\nspecular = 0.3\nexponent = 20\n'
    )
    sc = scene.load(tmp_path / "s.toml")
    assert isinstance(sc.materials.specular, Retro)
    assert float(sc.materials.specular.params["exponent"]) == 20.0


def test_a_model_samples_by_its_own_hooks(retro):
    # the toy's sampling follows its pdf: the mean weight f cos / pdf is its albedo
    model = Retro(1.0, 5.0)
    n, t, wo, _ = _directions(2, (1,))
    u = torch.rand(200_000, 2, generator=torch.Generator().manual_seed(1), dtype=F64)
    _, weight, _ = model.sample(wo.expand(len(u), 3), n.expand(len(u), 3), u, t.expand(len(u), 3))
    g = torch.Generator().manual_seed(2)
    wi = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=g, dtype=F64), dim=-1)
    cos = (wi * n).sum(-1).clamp_min(0)
    f = model.eval(wi, wo.expand_as(wi), n.expand_as(wi), t.expand_as(wi))[:, 0]
    albedo_uniform = float((f * cos).mean() * 4 * math.pi)
    assert float(weight[:, 0].mean()) == pytest.approx(albedo_uniform, rel=0.03)


def test_register_checks_the_class():
    with pytest.raises(InputError, match="only BRDF classes"):
        brdf.register(int)
    with pytest.raises(InputError, match="needs a type_name"):
        brdf.register(type("Nameless", (Retro,), {"type_name": ""}))
    with pytest.raises(InputError, match="'ggx' is taken"):
        brdf.register(type("Other", (Retro,), {"type_name": "ggx"}))
    assert brdf.register(brdf.GGX) is brdf.GGX  # the same class again: nothing changes
    assert list(brdf.REGISTRY) == list(examples())
    with pytest.raises(TypeError):
        brdf.REGISTRY["x"] = Retro  # read-only: register() is the way in


def test_public_names_are_importable():
    names = ["BRDF", "GGX", "Beckmann", "BlinnPhong", "Lafortune", "Lambert", "Phong", "Sum"]
    names += ["GGXSchlick", "metallic_roughness", "DIELECTRIC_F0"]
    for name in [*names, "Ward", "from_dict", "register", "REGISTRY", "CosineLobe"]:
        assert name in brdf.__all__ and getattr(brdf, name) is not None
    assert brdf.GGX.__module__ == "lobelight.brdf.microfacet"
    assert brdf.GGXSchlick.__module__ == "lobelight.brdf.gltf"
