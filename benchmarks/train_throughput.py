"""Training throughput (samples/s) of `lerobot-train`'s two paths on a BAVO points view, side by side.

"today": LeRobot's own sample loading (row by row from the Arrow table, one query per
delta_timestamps key) + `--policy.preset=cpu` at batch 16, the recipe of the earlier CPU runs.
"new": the in-memory data path (`lerobot_bavo.datasets.fast`) + `--policy.preset=cpu_fast` at batch 64
(the paper's batch size).

Each timed step is what lerobot-train does per optimiser step: fetch a shuffled batch through a
DataLoader (num_workers=0), the policy's preprocessor (normalisation), forward, backward, AdamW
step and the EMA update. The two paths alternate step by step in one process, so machine load
affects both alike. Prints medians, the samples/s of each path, their ratio, and the loading
cost per sample of each reader alone.

Example (both cores, the Cube Handoff points view made by scripts/train_cube_handoff.sh views):
    OPENBLAS_NUM_THREADS=1 python benchmarks/train_throughput.py \\
        --root outputs/datasets/bavo_cube_handoff_points --repo-id local/bavo_cube_handoff_points
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("HF_HUB_OFFLINE", "1")


def parse_args() -> argparse.Namespace:
    class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
        pass

    p = argparse.ArgumentParser(description=__doc__, formatter_class=Formatter)
    p.add_argument("--root", required=True, help="a BAVO points view (python -m lerobot_bavo.datasets.views)")
    p.add_argument("--repo-id", required=True, help="its repo id")
    p.add_argument("--policy", default="afar", choices=["afar", "maniflow"], help="policy type")
    p.add_argument("--threads", type=int, default=2, help="torch threads (2 = both cores of these machines)")
    p.add_argument("--steps", type=int, default=8, help="timed steps per path")
    p.add_argument("--warmup", type=int, default=2, help="untimed steps per path first")
    p.add_argument("--today-preset", default="cpu")
    p.add_argument("--today-batch", type=int, default=16)
    p.add_argument("--new-preset", default="cpu_fast")
    p.add_argument("--new-batch", type=int, default=64)
    p.add_argument("--load-samples", type=int, default=200, help="samples timed for the loading-only figures")
    return p.parse_args()


def build(args, preset: str, batch_size: int, fast: bool):
    """(dataloader iterator factory, preprocessor, policy, optimizer) of one path."""
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

    import lerobot_bavo  # noqa: F401  (registers the policies)
    from lerobot_bavo.datasets.fast import use_in_memory_reader

    cfg = make_policy_config(args.policy, preset=preset, device="cpu")
    meta = LeRobotDatasetMetadata(args.repo_id, root=args.root)
    ds = LeRobotDataset(args.repo_id, root=args.root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    if fast and not use_in_memory_reader(ds):
        raise SystemExit(f"{args.root} cannot be served from memory (see lerobot_bavo.datasets.fast.supports)")
    policy = make_policy(cfg, ds_meta=ds.meta)
    policy.train()
    pre, _ = make_pre_post_processors(cfg, dataset_stats=ds.meta.stats)
    opt = cfg.get_optimizer_preset().build(policy.get_optim_params())
    gen = torch.Generator().manual_seed(0)

    def batches():
        while True:
            yield from torch.utils.data.DataLoader(ds, batch_size=batch_size, shuffle=True, num_workers=0,
                                                   drop_last=True, generator=gen)

    return ds, batches(), pre, policy, opt


def step(path) -> float:
    _, it, pre, policy, opt = path
    t0 = time.perf_counter()
    batch = pre(next(it))
    loss, _ = policy.forward(batch)
    loss.backward()
    opt.step()
    opt.zero_grad(set_to_none=True)
    policy.update()
    return time.perf_counter() - t0


def loading_ms(ds, n: int) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        ds[(i * 7919) % len(ds)]
    return (time.perf_counter() - t0) / n * 1e3


def main() -> None:
    args = parse_args()
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {args.threads}; policy {args.policy}")
    paths = {
        "today": (args.today_preset, args.today_batch, False),
        "new": (args.new_preset, args.new_batch, True),
    }
    built = {name: build(args, preset, batch, fast) for name, (preset, batch, fast) in paths.items()}
    for name, (preset, batch, fast) in paths.items():
        n = sum(p.numel() for p in built[name][3].model.parameters())
        print(f"  {name:5s}: preset {preset}, batch {batch}, {'in-memory' if fast else 'LeRobot'} loading, "
              f"{n / 1e6:.2f} M parameters")
    times = {name: [] for name in paths}
    for i in range(args.warmup + args.steps):
        for name in paths:
            dt = step(built[name])
            if i >= args.warmup:
                times[name].append(dt)
    print(f"\nTraining step (load + normalise + forward + backward + AdamW + EMA), median of {args.steps}:")
    rate = {}
    for name, (_, batch, _) in paths.items():
        med = statistics.median(times[name])
        rate[name] = batch / med
        print(f"  {name:5s}: {med * 1e3:8.1f} ms per step of {batch}, {rate[name]:7.1f} samples/s, "
              f"{med / batch * 1e3 * args.threads:6.2f} core-ms per sample")
    ratio = rate["new"] / rate["today"]
    print(f"  ratio new / today: {ratio:.1f}x samples/s (target >= 10x: {'OK' if ratio >= 10 else 'MISSED'})")

    torch.set_num_threads(1)
    print(f"\nSample loading alone (one dataset item with the policy's delta_timestamps), {args.load_samples} items:")
    for name in paths:
        print(f"  {name:5s}: {loading_ms(built[name][0], args.load_samples):7.2f} ms per sample")


if __name__ == "__main__":
    main()
