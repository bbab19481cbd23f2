"""The optimiser of the ManiFlow / A-FAR training preset: LeRobot's AdamW, run by PyTorch's fused
implementation.

Registered with LeRobot's optimizer choices as "adamw_fused" (saved in a checkpoint's train_config.json, so
that `lerobot-train --resume` rebuilds it); importing `lerobot_bavo.policies` registers it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from lerobot.optim import AdamWConfig, OptimizerConfig

# Devices on which torch.optim.AdamW(fused=True) runs.
FUSED_ADAMW_DEVICES = ("cpu", "cuda")


def parameter_devices(params) -> set[str]:
    """Device types of the parameters in `params`: tensors, or param-group dicts holding them under
    "params"."""
    devices = set()
    for item in params:
        tensors = item["params"] if isinstance(item, dict) else [item]
        if isinstance(tensors, torch.Tensor):
            tensors = [tensors]
        devices.update(t.device.type for t in tensors)
    return devices


@OptimizerConfig.register_subclass("adamw_fused")
@dataclass
class FusedAdamWConfig(AdamWConfig):
    """LeRobot's `AdamWConfig` (same fields, same update rule) built with `fused=True` where PyTorch has it.

    Why: the default AdamW runs about ten small operations per parameter tensor on the CPU (~100 tensors in
    these policies) and a few multi-tensor kernels per step on CUDA; the fused one updates all parameters in
    one kernel. On other devices it falls back to PyTorch's default implementation.
    """

    def build(self, params) -> torch.optim.Optimizer:
        params = list(params)
        kwargs = asdict(self)
        kwargs.pop("grad_clip_norm")
        if params and parameter_devices(params) <= set(FUSED_ADAMW_DEVICES):
            kwargs["fused"] = True
        return torch.optim.AdamW(params, **kwargs)
