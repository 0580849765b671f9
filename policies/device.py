"""Where a policy trains and runs: ``--device auto|cpu|cuda|mps``, and mixed precision on CUDA.

``auto`` takes CUDA when a CUDA GPU is present, else Apple's MPS, else the CPU. On the CPU every
run is deterministic for its seed (single-threaded by default, ``TrainConfig.threads``); on a GPU
cuDNN picks its own kernels and results agree only to rounding.

Mixed precision: on CUDA, forward and loss run under ``torch.autocast`` in bfloat16 (convolutions
and matrix products in half precision, reductions and the optimiser state in float32). bfloat16
has float32's exponent range, so no loss scaling is needed. The CPU and MPS run in float32.
"""

from __future__ import annotations

import contextlib

import torch

from demo.errors import DemoError

DEVICES = ("auto", "cpu", "cuda", "mps")


def resolve_device(name: str = "auto") -> torch.device:
    """The torch device ``name`` stands for here; a DemoError for one this machine does not have."""
    name = (name or "auto").lower()
    if name not in DEVICES and not name.startswith("cuda:"):
        raise DemoError("--device", f"unknown device {name!r} (auto, cpu, cuda, cuda:N, mps)")
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        if _mps_available():
            return torch.device("mps")
        return torch.device("cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise DemoError("--device", f"{name} asked for, but torch sees no CUDA GPU here (use --device cpu)")
    if name == "mps" and not _mps_available():
        raise DemoError("--device", "mps asked for, but this torch has no usable MPS backend (use --device cpu)")
    return torch.device(name)


def _mps_available() -> bool:
    backend = getattr(torch.backends, "mps", None)
    return bool(backend is not None and backend.is_available())


def autocast(device: torch.device) -> contextlib.AbstractContextManager:
    """bfloat16 autocast on CUDA; nothing elsewhere."""
    if device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()
