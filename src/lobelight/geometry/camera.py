"""Pinhole cameras with Mitsuba 3's ``perspective`` sensor conventions.

Mitsuba's ``look_at(origin, target, up)`` builds a camera frame whose columns are
``left = normalize(up x dir)``, ``up' = dir x left`` and ``dir``; the image's left edge shows the
camera's +left side and its top row the +up side. ``fov`` is the full angle along ``fov_axis``
("x" by default, as in Mitsuba). A pixel ``(px, py)`` (``px`` to the right, ``py`` down) has film
coordinates ``x = (px + 0.5) / W``, ``y = (py + 0.5) / H`` and looks along::

    d = left * (1 - 2 x) tan(fov_x / 2) + up' * (1 - 2 y) tan(fov_x / 2) H / W + dir

so frames rendered here and by Mitsuba with the same parameters line up pixel for pixel
(``tests/test_reference.py`` checks it against a Mitsuba render).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .._backend import as_tensor
from ..errors import InputError

__all__ = ["Camera"]


def _vec3(x, name: str) -> tuple[float, float, float]:
    t = as_tensor(x, dtype=torch.float64).reshape(-1)
    if t.numel() != 3 or not bool(torch.isfinite(t).all()):
        raise InputError(name, f"must be 3 finite numbers, got {x!r}")
    return tuple(float(v) for v in t)  # type: ignore[return-value]


@dataclass(frozen=True)
class Camera:
    """A perspective camera: ``origin``, ``target``, ``up`` (world frame), ``fov`` in degrees.

    Attributes
    ----------
    origin, target, up : 3 floats each
    fov : full field of view in degrees along ``fov_axis``
    fov_axis : "x" (Mitsuba's default), "y", "smaller" or "larger"
    """

    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 40.0
    fov_axis: str = "x"

    def __post_init__(self) -> None:
        o, t, u = _vec3(self.origin, "origin"), _vec3(self.target, "target"), _vec3(self.up, "up")
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "target", t)
        object.__setattr__(self, "up", u)
        if not 0 < float(self.fov) < 180:
            raise InputError("fov", f"must be in (0, 180) degrees, got {self.fov}")
        if self.fov_axis not in ("x", "y", "smaller", "larger"):
            raise InputError("fov_axis", f"must be x, y, smaller or larger, got {self.fov_axis!r}")
        d = torch.tensor(t, dtype=torch.float64) - torch.tensor(o, dtype=torch.float64)
        if float(d.norm()) == 0:
            raise InputError("target", "coincides with origin")
        if float(torch.linalg.cross(torch.tensor(u, dtype=torch.float64), d).norm()) < 1e-9 * float(
            d.norm()
        ):
            raise InputError("up", "is parallel to the viewing direction")

    @classmethod
    def look_at(cls, origin, target, up=(0.0, 1.0, 0.0), fov: float = 40.0, **kw) -> Camera:
        """Mitsuba's ``look_at`` with a field of view in degrees (``fov_axis="x"`` default)."""
        return cls(origin=origin, target=target, up=up, fov=fov, **kw)

    def frame(self, *, dtype=torch.float32, device=None) -> torch.Tensor:
        """``(4, 3)`` rows: left, up', dir (unit) and origin."""
        o = torch.tensor(self.origin, dtype=torch.float64)
        d = torch.nn.functional.normalize(torch.tensor(self.target, dtype=torch.float64) - o, dim=0)
        left = torch.nn.functional.normalize(
            torch.linalg.cross(torch.tensor(self.up, dtype=torch.float64), d), dim=0
        )
        up = torch.linalg.cross(d, left)
        return torch.stack([left, up, d, o]).to(dtype=dtype, device=device)

    def tan_half(self, width: int, height: int) -> tuple[float, float]:
        """Tangents of the half field of view across ``width`` and up ``height`` (the axis
        ``fov_axis`` names gets ``tan(fov / 2)``)."""
        t = math.tan(math.radians(self.fov) / 2)
        aspect = width / height
        axis = self.fov_axis
        if axis == "smaller":
            axis = "x" if width <= height else "y"
        elif axis == "larger":
            axis = "x" if width >= height else "y"
        return (t, t / aspect) if axis == "x" else (t * aspect, t)

    def rays(
        self, width: int, height: int, *, offsets=None, device=None, dtype=torch.float32
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Primary rays through every pixel.

        Parameters
        ----------
        width, height : image size in pixels
        offsets : optional (H, W, 2) or (..., H, W, 2) sub-pixel positions in [0, 1) (x right,
            y down); default the pixel centres (0.5, 0.5)

        Returns
        -------
        origins : (..., H, W, 3);  dirs : (..., H, W, 3) unit directions
        """
        if width < 1 or height < 1:
            raise InputError("resolution", f"must be positive, got {width}x{height}")
        f = self.frame(dtype=torch.float64, device=device)
        if offsets is None:
            offsets = torch.full((height, width, 2), 0.5, dtype=torch.float64, device=device)
        off = as_tensor(offsets, device=device).to(torch.float64)
        px = torch.arange(width, dtype=torch.float64, device=device)
        py = torch.arange(height, dtype=torch.float64, device=device)
        x = (px[None, :] + off[..., 0]) / width  # (..., H, W)
        y = (py[:, None] + off[..., 1]) / height
        tx, ty = self.tan_half(width, height)
        d = (
            ((1 - 2 * x) * tx)[..., None] * f[0]
            + ((1 - 2 * y) * ty)[..., None] * f[1]
            + f[2].expand(*x.shape, 3)
        )
        d = torch.nn.functional.normalize(d, dim=-1)
        return f[3].expand_as(d).to(dtype), d.to(dtype)

    def to_dict(self) -> dict:
        return {
            "origin": list(self.origin),
            "target": list(self.target),
            "up": list(self.up),
            "fov": float(self.fov),
            "fov_axis": self.fov_axis,
        }
