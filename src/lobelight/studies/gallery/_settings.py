"""The gallery's settings that the command line needs before anything heavy is imported: the
Mitsuba variants tried, how references are rendered (the sharp metals' with more samples) and
the equal-quality sweep's extent."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from ...errors import InputError

__all__ = ["SHARP_REFERENCE_SAMPLES", "SWEEP_MAX_SPP", "VARIANTS", "ReferenceSettings"]

#: Mitsuba variants tried in turn when none is asked for.
VARIANTS = ("llvm_ad_rgb", "scalar_rgb")
#: The equal-quality sweep's largest samples per pixel by default.
SWEEP_MAX_SPP = 256

#: The sharp metals' references take this many times the samples per pixel of the others. A
#: mirror seen in a mirror lit by a small bright source (the object in its own sharp
#: reflection, under a sun or a softbox) is a caustic path that a path tracer finds rarely:
#: at the settings' 1024 samples its noise took 0.3-0.5 dB off the scores of the sharp bunny
#: in the park and the sharp teapot under the studio map, against 16,384 samples
#: (docs/results.md). Every score is reported beside its reference's own noise
#: (``reference_noise_psnr_display``).
SHARP_REFERENCE_SAMPLES = 16


@dataclass(frozen=True)
class ReferenceSettings:
    """How references are rendered: Mitsuba's ``path`` integrator with ``max_depth`` (path
    length as Mitsuba counts it: 2 is direct lighting), ``spp`` samples per pixel in passes of
    ``pass_spp`` (independent seeds; their spread gives the standard error), a box pixel
    filter, and the mask from a ``mask_grid x mask_grid`` grid of rays per pixel."""

    spp: int = 1024
    max_depth: int = 8
    width: int = 512
    height: int = 512
    pass_spp: int = 32
    seed: int = 0
    mask_grid: int = 4

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            least = 0 if k == "seed" else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise InputError(
                    f"--{k.replace('_', '-')}", f"must be an integer >= {least}, got {v!r}"
                )
        if self.spp % self.pass_spp or self.spp // self.pass_spp < 2:
            raise InputError(
                "--spp",
                f"must be a multiple of {self.pass_spp} (two passes or more), got {self.spp}",
            )

    def to_dict(self) -> dict[str, int]:
        return asdict(self)
