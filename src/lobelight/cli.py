"""The ``lobelight`` command line: one entry point, ``--help`` everywhere, ``--json`` for machines.

Exit codes: 0 success, 1 unexpected error, 2 bad input (one line naming the input and problem).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _latlong_dirs(height: int):
    """Directions of lat-long pixel centres in Mitsuba 3's envmap orientation, (H, 2H, 3)."""
    import torch

    w = 2 * height
    u = (torch.arange(w, dtype=torch.float64) + 0.5) / w
    # rows are corner-aligned as in Mitsuba's envmap (row 0 at the pole): v = i / (H - 1)
    v = torch.arange(height, dtype=torch.float64) / (height - 1)
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    th, ph = math.pi * vv, 2 * math.pi * uu
    # inverse of u = atan2(x, -z) / 2 pi, v = acos(y) / pi
    return torch.stack([th.sin() * ph.sin(), th.cos(), -th.sin() * ph.cos()], -1).float()


def _to_png(img, path: Path, *, exposure: float = 0.0) -> None:
    """Write linear radiance ``(H, W, 3)`` as an sRGB PNG, atomically."""
    import numpy as np
    from PIL import Image

    x = np.asarray(img, dtype=np.float64) * 2.0**exposure
    x = np.clip(x, 0, None)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    out = (np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    tmp = path.with_name(path.name + ".tmp")
    Image.fromarray(out).save(tmp, format="PNG")
    tmp.replace(path)


def _cmd_demo(args) -> dict:
    import torch

    from .envmap import builtin, load, prefilter

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    env = load(args.env) if args.env else builtin()
    env = env.to(args.device)
    t1 = time.perf_counter()
    pf = prefilter(env, base_res=args.base_res, device=args.device)
    t2 = time.perf_counter()
    dirs = _latlong_dirs(args.height).to(args.device)
    # exposure that maps the map's mean radiance to mid grey
    mean = float(env.power().mean()) / (4 * math.pi)
    exposure = math.log2(0.18 / max(mean, 1e-9))
    images = []
    rows = [("original", env.radiance(dirs))]
    for lam in args.lambdas:
        rows.append((f"lam={lam:g}", pf.lookup(dirs, torch.full(dirs.shape[:-1], lam))))
    for label, img in rows:
        name = "envmap-" + label.replace("=", "-").replace(".", "p") + ".png"
        _to_png(img.cpu().numpy(), out / name, exposure=exposure)
        images.append(str(out / name))
    strip = torch.cat([img for _, img in rows], 0).cpu().numpy()
    _to_png(strip, out / "prefiltered-levels.png", exposure=exposure)
    return {
        "command": "demo",
        "env": env.name,
        "base_res": args.base_res,
        "levels": len(pf.levels),
        "lam_range": [pf.lam_min, pf.lam_max],
        "seconds_load": t1 - t0,
        "seconds_prefilter": t2 - t1,
        "images": images,
        "overview": str(out / "prefiltered-levels.png"),
    }


def _cmd_bench(args) -> dict:
    from .bench import bench_prefilter, bench_transport

    if args.what == "prefilter":
        return bench_prefilter(base_res=args.base_res, repeats=args.repeats, device=args.device)
    if args.what == "transport":
        return bench_transport(scene=args.scene, device=args.device)
    if args.what == "lobe-tables":
        from .cosine import bench_tables

        return bench_tables(device=args.device)
    if args.what == "brdf-fit":
        from .sgbrdf import bench_fit

        return bench_fit(material=args.material, device=args.device)
    raise AssertionError(args.what)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lobelight", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"lobelight {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp):
        sp.add_argument("--json", action="store_true", help="print a machine-readable summary")
        sp.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1, ...)")

    d = sub.add_parser(
        "demo", help="render the built-in environment's Gaussian-prefiltered levels to PNG"
    )
    common(d)
    d.add_argument("--env", help="an .hdr/.exr environment instead of the built-in sky")
    d.add_argument("--out", default="lobelight-out", help="output folder (default: lobelight-out)")
    d.add_argument(
        "--base-res", type=int, default=128, help="cube-map face resolution of the sharpest level"
    )
    d.add_argument("--height", type=int, default=128, help="height of the lat-long images")
    d.add_argument(
        "--lambdas",
        type=float,
        nargs="+",
        default=[600.0, 100.0, 20.0, 4.0, 1.0],
        help="Gaussian sharpness values to show",
    )
    d.set_defaults(run=_cmd_demo)

    b = sub.add_parser("bench", help="benchmarks with machine-readable output")
    common(b)
    b.add_argument(
        "what",
        choices=["prefilter", "transport", "lobe-tables", "brdf-fit"],
        help="what to time",
    )
    b.add_argument(
        "--material", default="ward", help="material of brdf-fit (ward, ward_aniso, ...)"
    )
    b.add_argument("--scene", default="knot:3", help="scene for the transport benchmark")
    b.add_argument(
        "--base-res", type=int, default=512, help="face resolution of the input cube map"
    )
    b.add_argument("--repeats", type=int, default=3)
    b.set_defaults(run=_cmd_bench)
    return p


def _version() -> str:
    from . import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 unexpected error, 2 bad input)."""
    from .errors import InputError

    args = _parser().parse_args(argv)
    try:
        summary = args.run(args)
    except InputError as e:
        print(f"lobelight: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for k, v in summary.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
