"""Matrix-multiply FLOPs of one ManiFlow / A-FAR training step per sample (forward, backward and the EMA
teacher's pass), counted by torch.utils.flop_counter on the CPU with a synthetic batch of BAVO's shapes (256
xyz+rgb points, 21-dim state and action, 3-dim teacher features). Counts what a GPU must compute whatever its
speed; elementwise operations are not counted.

`--ops` also counts the ATen operations one whole training step dispatches (forward, backward, the fused AdamW
step, the EMA update), by phase: on a GPU each is a kernel launch or a metadata operation paid on the host, so
the count is what bounds a step whose GPU waits for the host (docs/gpu.md).

Run it for the code on the path; for an older commit put that commit's `lerobot_bavo/` first on the path:
    python benchmarks/train_flops.py --preset paper
    mkdir -p /tmp/base && git archive 729528a lerobot_bavo | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base python benchmarks/train_flops.py --preset paper
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

N_POINTS, STATE_DIM, ACTION_DIM, TEACHER_DIM = 256, 21, 21, 3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default="afar", choices=["afar", "maniflow"])
    p.add_argument("--preset", default="paper")
    p.add_argument("--batch", type=int, default=8, help="samples counted (FLOPs are reported per sample)")
    p.add_argument("--ops", action="store_true",
                   help="also count the ATen operations of one whole step (the second), by phase")
    args = p.parse_args()

    import torch
    from lerobot.configs import FeatureType, PolicyFeature
    from torch.utils.flop_counter import FlopCounterMode

    import lerobot_bavo
    from lerobot_bavo.policies import AfarConfig, AfarPolicy, ManiFlowConfig, ManiFlowPolicy

    inputs = {"observation.point_cloud": PolicyFeature(FeatureType.STATE, (N_POINTS * 6,)),
              "observation.state": PolicyFeature(FeatureType.STATE, (STATE_DIM,))}
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))}
    config_cls, policy_cls = (
        (AfarConfig, AfarPolicy) if args.policy == "afar" else (ManiFlowConfig, ManiFlowPolicy)
    )
    torch.manual_seed(0)
    policy = policy_cls(config_cls(input_features=inputs, output_features=outputs, preset=args.preset,
                                   device="cpu")).train()
    b, to, h = args.batch, policy.config.n_obs_steps, policy.config.horizon
    batch = {"observation.point_cloud": torch.rand(b, to, N_POINTS * 6) * 2 - 1,
             "observation.state": torch.rand(b, to, STATE_DIM) * 2 - 1,
             "action": torch.rand(b, h, ACTION_DIM) * 2 - 1,
             "observation.teacher.z0": torch.randn(b, to, N_POINTS * TEACHER_DIM)}
    batch["observation.teacher.zf"] = batch["observation.teacher.z0"] + 0.1 * torch.randn_like(
        batch["observation.teacher.z0"])
    counter = FlopCounterMode(display=False)
    with counter:
        loss, _ = policy.forward(batch)
        loss.backward()
    n_params = sum(p.numel() for p in policy.model.parameters())
    print(
        f"{lerobot_bavo.__file__}: {args.policy}, preset {args.preset} ({n_params / 1e6:.1f} M parameters), "
        f"{counter.get_total_flops() / b / 1e9:.3g} GFLOP per training sample (forward + backward + EMA "
        "teacher)"
    )
    if args.ops:
        print_operation_counts(policy, batch)


def print_operation_counts(policy, batch: dict) -> None:
    """ATen operations dispatched by the second of two whole training steps (the first builds caches), by
    phase, and the most frequent ones."""
    import collections

    import torch
    from torch.utils._python_dispatch import TorchDispatchMode

    class CountOperations(TorchDispatchMode):
        def __init__(self):
            super().__init__()
            self.counts: collections.Counter = collections.Counter()
            self.phase = ""
            self.compiled_forward = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            self.counts[self.phase, func.overloadpacket.__name__] += 1
            if self.phase == "forward":
                self.compiled_forward += depth[0] > 0
            return func(*args, **(kwargs or {}))

    # forward operations inside the sub-networks `--policy.compile` compiles (CUDA graphs replay them without
    # host work) against the rest, which stays eager; A-FAR's relational losses, compiled as a function, count
    # as the rest here
    depth = [0]
    for model in (policy.model, policy.ema_model):
        for module in policy.compiled_modules(model):
            module.register_forward_pre_hook(lambda *_: depth.__setitem__(0, depth[0] + 1))
            module.register_forward_hook(lambda *_: depth.__setitem__(0, depth[0] - 1))
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=1e-4, fused=True)
    for _ in range(2):
        policy.zero_grad(set_to_none=True)
        counter = CountOperations()
        with counter:
            counter.phase = "forward"
            loss, _ = policy.forward(batch)
            counter.phase = "backward"
            loss.backward()
            counter.phase = "optimizer"
            optimizer.step()
            counter.phase = "ema"
            if hasattr(policy, "update"):
                policy.update()
    phases = collections.Counter()
    for (phase, _), n in counter.counts.items():
        phases[phase] += n
    print(f"ATen operations per training step: {sum(phases.values())} ("
          + ", ".join(f"{phase} {n}" for phase, n in phases.items()) + ")")
    print(f"forward operations inside the compiled sub-networks: {counter.compiled_forward} of "
          f"{phases['forward']}")
    top = counter.counts.most_common(12)
    print("most frequent: " + ", ".join(f"{phase}/{name} {n}" for (phase, name), n in top))


if __name__ == "__main__":
    main()
