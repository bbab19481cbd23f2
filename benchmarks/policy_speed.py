"""ManiFlow vs A-FAR speed on synthetic batches (CPU preset by default).

Prints, measured side by side in one run:
  1. the training step time (forward + backward + AdamW step + EMA update) of ManiFlow and A-FAR at the given
     batch size and thread count, and their ratio (target: A-FAR <= 1.3x ManiFlow);
  2. the inference latency of one action chunk (policy.predict_action_chunk, EMA model, batch 1) on ONE
     thread with 1 and 2 flow steps (target: < 20 ms).

Steps of the two policies are interleaved (ManiFlow, A-FAR, ManiFlow, ...) so that load from other processes
affects both alike; medians and minima are reported, with the load average at the start. On a shared machine
`--clock cpu` (process CPU time instead of wall time) is far less sensitive to other processes; use it with
`--train-threads 1`, since CPU time adds up over threads.

Example:
    OPENBLAS_NUM_THREADS=1 python benchmarks/policy_speed.py --preset cpu --batch-size 32
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import torch  # noqa: E402
from lerobot.configs import FeatureType, PolicyFeature  # noqa: E402

from lerobot_bavo.policies import AfarConfig, AfarPolicy, ManiFlowConfig, ManiFlowPolicy  # noqa: E402


def parse_args() -> argparse.Namespace:
    class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
        pass

    p = argparse.ArgumentParser(description=__doc__, formatter_class=Formatter)
    p.add_argument("--preset", default="cpu", choices=["cpu", "cpu_fast", "paper"], help="policy size preset")
    p.add_argument("--batch-size", type=int, default=32, help="training batch size")
    p.add_argument("--train-threads", type=int, default=2, help="torch threads for the training steps")
    p.add_argument("--train-steps", type=int, default=6, help="timed training steps per policy")
    p.add_argument("--warmup-steps", type=int, default=2, help="untimed training steps per policy first")
    p.add_argument(
        "--infer-iters", type=int, default=30, help="timed action chunks per policy and step count"
    )
    p.add_argument("--num-points", type=int, default=256, help="points per observation step (N = N_q)")
    p.add_argument("--teacher-dim", type=int, default=64, help="teacher feature width d_T of z0/zf")
    p.add_argument("--dit-hidden-dim", type=int, default=None, help="override the preset's DiT-X width")
    p.add_argument("--dit-num-layers", type=int, default=None, help="override the preset's DiT-X depth")
    p.add_argument("--wqf-hidden-dim", type=int, default=None, help="override the preset's WQF width")
    p.add_argument("--wqf-num-blocks", type=int, default=None, help="override the WQF block count")
    p.add_argument("--wqf-num-heads", type=int, default=None, help="override the WQF head count")
    p.add_argument("--wqf-ffn-ratio", type=float, default=None, help="override the preset's WQF FFN ratio")
    p.add_argument(
        "--relation-num-points", type=int, default=None,
        help="override the preset's relational anchor count (0 = all points)",
    )
    p.add_argument(
        "--clock", choices=["wall", "cpu"], default="wall",
        help="wall: time.perf_counter; cpu: time.process_time (robust to other load; sums over threads)",
    )
    p.add_argument("--seed", type=int, default=0, help="torch seed")
    return p.parse_args()


def make_configs(args) -> tuple[ManiFlowConfig, AfarConfig]:
    inputs = {
        "observation.point_cloud": PolicyFeature(FeatureType.STATE, (args.num_points, 6)),
        "observation.state": PolicyFeature(FeatureType.STATE, (21,)),
    }
    outputs = {"action": PolicyFeature(FeatureType.ACTION, (21,))}
    common = dict(preset=args.preset, device="cpu")
    if args.dit_hidden_dim is not None:
        common["dit_hidden_dim"] = args.dit_hidden_dim
    if args.dit_num_layers is not None:
        common["dit_num_layers"] = args.dit_num_layers
    mf = ManiFlowConfig(input_features=dict(inputs), output_features=dict(outputs), **common)
    extra = {
        k: getattr(args, k)
        for k in ("wqf_hidden_dim", "wqf_num_blocks", "wqf_num_heads", "wqf_ffn_ratio", "relation_num_points")
        if getattr(args, k) is not None
    }
    af = AfarConfig(input_features=dict(inputs), output_features=dict(outputs), **common, **extra)
    return mf, af


def synthetic_batch(b: int, n: int, d_t: int, to: int = 2, horizon: int = 16) -> dict[str, torch.Tensor]:
    return {
        "observation.point_cloud": torch.rand(b, to, n, 6) * 2 - 1,
        "observation.state": torch.rand(b, to, 21) * 2 - 1,
        "action": torch.rand(b, horizon, 21) * 2 - 1,
        "observation.teacher.z0": torch.randn(b, to, n, d_t),
        "observation.teacher.zf": torch.randn(b, to, n, d_t),
    }


CLOCK = time.perf_counter


def train_step(policy, opt, batch) -> float:
    t0 = CLOCK()
    loss, _ = policy.forward(batch)
    loss.backward()
    opt.step()
    opt.zero_grad(set_to_none=True)
    policy.update()
    return CLOCK() - t0


def main() -> None:
    global CLOCK
    args = parse_args()
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    torch.manual_seed(args.seed)
    print(f"load average at start: {os.getloadavg()[0]:.2f} (timings are only meaningful on an idle machine "
          f"or with --clock cpu); clock: {args.clock}")
    mf_cfg, af_cfg = make_configs(args)
    policies = {"maniflow": ManiFlowPolicy(mf_cfg), "afar": AfarPolicy(af_cfg)}
    for name, pol in policies.items():
        n = sum(p.numel() for p in pol.model.parameters())
        print(f"{name:8s} params (online model): {n / 1e6:.2f} M")
    c = mf_cfg
    print(
        f"preset={c.preset}: DiT-X {c.dit_hidden_dim} wide x {c.dit_num_layers} layers x {c.dit_num_heads} "
        "heads, "
        f"point encoder 6->{'->'.join(map(str, c.point_encoder_hidden_dims))}->{c.point_feature_dim}, "
        f"WQF {af_cfg.wqf_hidden_dim} wide x {af_cfg.wqf_num_blocks} blocks x {af_cfg.wqf_num_heads} heads "
        f"(FFN x{af_cfg.wqf_ffn_ratio}), "
        f"relation anchors {af_cfg.relation_num_points or args.num_points}, "
        f"N={args.num_points}, To={c.n_obs_steps}, horizon={c.horizon}, d_T={args.teacher_dim}"
    )

    # 1. Training step.
    torch.set_num_threads(args.train_threads)
    batch = synthetic_batch(args.batch_size, args.num_points, args.teacher_dim)
    opts = {}
    for name, pol in policies.items():
        pol.train()
        cfg_opt = pol.config.get_optimizer_preset()
        opts[name] = cfg_opt.build(pol.get_optim_params())
    times: dict[str, list[float]] = {k: [] for k in policies}
    for i in range(args.warmup_steps + args.train_steps):
        for name, pol in policies.items():
            dt = train_step(pol, opts[name], batch)
            if i >= args.warmup_steps:
                times[name].append(dt)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"\nTraining step (fwd+bwd+AdamW+EMA), batch {args.batch_size}, {args.train_threads} thread(s), "
          f"median of {args.train_steps}:")
    for name in policies:
        print(f"  {name:8s} {med[name] * 1e3:8.1f} ms  (min {min(times[name]) * 1e3:.1f})")
    ratio = med["afar"] / med["maniflow"]
    print(f"  ratio A-FAR / ManiFlow: {ratio:.2f}x  (target <= 1.3x: {'OK' if ratio <= 1.3 else 'MISSED'})")

    # 2. Inference latency.
    torch.set_num_threads(1)
    obs = {
        "observation.point_cloud": torch.rand(1, 2, args.num_points, 6) * 2 - 1,
        "observation.state": torch.rand(1, 2, 21) * 2 - 1,
    }
    print(f"\nInference: one action chunk at batch 1, 1 thread, median of {args.infer_iters}:")
    worst = 0.0
    for steps in (1, 2):
        for name, pol in policies.items():
            pol.eval()
            pol.reset()
            pol.config.num_inference_steps = steps
            for _ in range(3):
                pol.predict_action_chunk(obs)
            lat = []
            for _ in range(args.infer_iters):
                t0 = CLOCK()
                pol.predict_action_chunk(obs)
                lat.append(CLOCK() - t0)
            m = statistics.median(lat)
            worst = max(worst, m)
            print(f"  {name:8s} {steps} flow step(s): {m * 1e3:6.1f} ms  (min {min(lat) * 1e3:.1f})")
    print(f"  worst median {worst * 1e3:.1f} ms  (target < 20 ms: {'OK' if worst < 0.020 else 'MISSED'})")


if __name__ == "__main__":
    main()
