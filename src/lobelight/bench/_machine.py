"""Where a benchmark ran, for the records benchmarks write, and the wait that timings of GPU
work need."""

from __future__ import annotations

import os
import platform

import torch

__all__ = ["machine", "sync"]


def machine(device: str) -> dict:
    """Where a benchmark ran: CPU model and cores, torch version, GPU name if any."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "device": device,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


def sync(device: str | torch.device) -> None:
    """Wait for the device's queued work (timings of GPU work need it)."""
    if str(device).startswith("cuda"):
        torch.cuda.synchronize(device)
