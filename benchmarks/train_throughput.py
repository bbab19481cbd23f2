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

Example (both cores, the Cube Handoff points view made by scripts/train_task.sh views):
    OPENBLAS_NUM_THREADS=1 python benchmarks/train_throughput.py \\
        --root outputs/datasets/bavo_cube_handoff_points --repo-id local/bavo_cube_handoff_points

With `--baseline-commit C` it compares training steps instead (issue 28): the code of commit C (its
`lerobot_bavo/`, taken with `git archive` into a temporary folder) against the working tree's, same preset,
batch and device, each loading data the way `lerobot-train` does with that code (its plugin hook's dataset
class: per-item in-memory reads at 3be7046, the issue's "today", whole batches since a7b34be; DataLoader with
num_workers=0). Each runs in its own subprocess (a package cannot be imported twice in
one process); the parent alternates them step by step, so machine load affects both alike. A step is
LeRobot's own `update_policy` (autocast when `--use-amp`, forward, backward, gradient norm, optimiser, EMA
`update()`, metrics) after fetching and normalising the batch, as `lerobot-train` does it. On CUDA it also
prints the GPU busy fraction of each (kernel time / wall time, torch.profiler, a few extra steps). Each path
says where it gathered its batches: with `--device cuda` the working tree's data path holds the view on the
GPU and gathers there (`lerobot_bavo.datasets.fast`, "Device-resident batches": num_workers=0 and a CUDA
accelerator, as here); set `BAVO_DEVICE_BATCHES=0` to time its CPU gather instead.
    OPENBLAS_NUM_THREADS=1 python benchmarks/train_throughput.py --root <points view> --repo-id <id> \\
        --baseline-commit 729528a --device cpu --preset cpu_fast --batch 64 --threads 2
Where there is no git history (the GPU machine gets a copy of the working tree), extract the old code here and
carry it: `mkdir -p .device/baseline && git archive 729528a lerobot_bavo | tar -x -C .device/baseline`, then
`--baseline-dir .device/baseline` (docs/gpu.md).
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
    step = p.add_argument_group("step comparison (--baseline-commit)")
    step.add_argument("--baseline-commit", default=None,
                      help="compare the training step of this commit's policy code with the working tree's")
    step.add_argument("--baseline-dir", default=None,
                      help="or: a folder holding the old lerobot_bavo/ (where there is no git history)")
    step.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    step.add_argument("--preset", default="cpu_fast")
    step.add_argument("--batch", type=int, default=64)
    step.add_argument("--use-amp", action="store_true", help="--policy.use_amp=true (bf16 autocast on CUDA)")
    step.add_argument("--new-policy-arg", action="append", default=[], metavar="FIELD=VALUE",
                      help="a config field set on the new path only (e.g. compile=true); repeatable")
    step.add_argument(
        "--profile-steps", type=int, default=5, help="CUDA: steps profiled for the busy fraction"
    )
    step.add_argument("--load-batches", type=int, default=0,
                      help="also time this many batch fetches alone (DataLoader + normalisation) per path")
    step.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # internal: serve steps of one path
    return p.parse_args()


def build(args, preset: str, batch_size: int, fast: bool):
    """(dataloader iterator factory, preprocessor, policy, optimizer) of one path."""
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

    import lerobot_bavo.policies  # noqa: F401  (registers the policies)
    from lerobot_bavo.datasets.fast import use_in_memory_reader

    cfg = make_policy_config(args.policy, preset=preset, device="cpu")
    meta = LeRobotDatasetMetadata(args.repo_id, root=args.root)
    ds = LeRobotDataset(args.repo_id, root=args.root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    if fast and not use_in_memory_reader(ds):
        raise SystemExit(
            f"{args.root} cannot be served from memory (see lerobot_bavo.datasets.fast.supports)"
        )
    require_a_full_batch(ds.num_frames, batch_size, args.root)
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


def require_a_full_batch(num_frames: int, batch: int, root) -> None:
    """The loaders drop the last partial batch (every timed step has the same shape), so a view with fewer
    frames than one batch would never yield one and the benchmark would wait forever."""
    if batch > num_frames:
        raise SystemExit(f"--batch {batch} is larger than {root}'s {num_frames} frames: collect more "
                         "episodes or use a smaller batch")


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


# ---- Step comparison (--baseline-commit)
# ------------------------------------------------------------------------


def policy_overrides(pairs: list[str]) -> dict[str, object]:
    """FIELD=VALUE strings -> config kwargs (true/false -> bool, numbers -> int/float, else the string)."""
    out: dict[str, object] = {}
    for pair in pairs:
        name, _, text = pair.partition("=")
        value: object = {"true": True, "false": False}.get(text.lower(), text)
        if isinstance(value, str):
            for cast in (int, float):
                try:
                    value = cast(text)
                    break
                except ValueError:
                    pass
        out[name] = value
    return out


def busy_fraction(intervals: list[tuple[float, float]], wall: float) -> float:
    """Length of the union of (start, end) intervals over `wall` (same unit): the share of the time a device
    ran at least one kernel."""
    covered, reach = 0.0, float("-inf")
    for start, end in sorted(intervals):
        if end <= reach:
            continue
        covered += end - max(start, reach)
        reach = end
    return covered / wall if wall > 0 else 0.0


def serve_steps(args) -> None:
    """Worker: build one path, then answer "step" with the seconds one training step took, "load" with those
    of one batch fetch alone, "loader" with where batches are gathered, "profile K" with the GPU busy fraction
    over K steps, and "quit"."""
    import json
    import sys

    import lerobot.datasets.factory as lerobot_dataset_factory
    import torch
    from accelerate import Accelerator
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker

    import lerobot_bavo
    import lerobot_bavo.policies  # noqa: F401  (registers the policies; `import lerobot_bavo` alone does not)
    from lerobot_bavo.datasets.fast import install_lerobot_train_hook

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    overrides = policy_overrides(args.new_policy_arg) if args.worker == "new" else {}
    cfg = make_policy_config(
        args.policy, preset=args.preset, device=args.device, use_amp=args.use_amp, **overrides
    )
    meta = LeRobotDatasetMetadata(args.repo_id, root=args.root)
    # The dataset class lerobot-train gets from each code version: its plugin hook replaces the factory's
    # `LeRobotDataset` (per-item reads before the batched path existed, whole batches after).
    install_lerobot_train_hook()
    dataset_class = lerobot_dataset_factory.LeRobotDataset
    ds = dataset_class(args.repo_id, root=args.root, delta_timestamps=resolve_delta_timestamps(cfg, meta))
    if type(ds) is LeRobotDataset or not hasattr(ds.reader, "columns"):
        raise SystemExit(
            f"{args.root} cannot be served from memory (see lerobot_bavo.datasets.fast.supports)"
        )
    require_a_full_batch(ds.num_frames, args.batch, args.root)
    policy = make_policy(cfg, ds_meta=ds.meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=ds.meta.stats)
    opt_cfg = cfg.get_optimizer_preset()
    opt = opt_cfg.build(policy.get_optim_params())
    # lerobot-train's choice of autocast: the config's `dtype` when it has one, else `use_amp` with torch's
    # default.
    dtype = getattr(cfg, "dtype", None)
    mixed = {"bfloat16": "bf16", "float16": "fp16", "float32": "no"}.get(dtype) if dtype else (
        {torch.bfloat16: "bf16", torch.float16: "fp16"}[torch.get_autocast_dtype(args.device)] if cfg.use_amp
        else "no")
    accelerator = Accelerator(cpu=args.device == "cpu", mixed_precision=mixed)
    tracker = MetricsTracker(args.batch, ds.num_frames, ds.num_episodes,
                             {"loss": AverageMeter("loss"), "grad_norm": AverageMeter("grdn"),
                              "lr": AverageMeter("lr"), "update_s": AverageMeter("updt_s"),
                              # update_policy records the peak GPU memory on CUDA (as lerobot-train's tracker)
                              **({"gpu_mem_gb": AverageMeter("mem_gb")} if args.device == "cuda" else {})})
    gen = torch.Generator().manual_seed(0)

    def batches():
        while True:
            yield from torch.utils.data.DataLoader(ds, batch_size=args.batch, shuffle=True, num_workers=0,
                                                   drop_last=True, generator=gen,
                                                   pin_memory=args.device == "cuda")

    it = batches()
    sync = torch.cuda.synchronize if args.device == "cuda" else (lambda: None)

    def step() -> tuple[float, float]:
        """(wall seconds, CPU seconds of this process) of one training step."""
        sync()
        t0, c0 = time.perf_counter(), time.process_time()
        batch = pre(next(it))
        update_policy(tracker, policy, batch, opt, opt_cfg.grad_clip_norm, accelerator)
        sync()
        return time.perf_counter() - t0, time.process_time() - c0

    n_params = sum(p.numel() for p in policy.model.parameters())
    print(
        json.dumps(
            {
                "ready": True,
                "code": lerobot_bavo.__file__,
                "params": n_params,
                "mixed_precision": mixed,
                "optimizer": type(opt).__name__ + (" fused" if opt.defaults.get("fused") else ""),
            }
        ),
        flush=True,
    )
    for line in sys.stdin:
        cmd = line.split()
        if cmd[0] == "loader":
            # where this code gathers a batch: the training device with the device-resident path (the working
            # tree's `InMemoryReader.batch_device`), else the CPU (older code: no such method)
            where = getattr(ds.reader, "batch_device", None)
            print(json.dumps({"gather": str(where()) if where else "cpu"}), flush=True)
        elif cmd[0] == "load":
            # one batch fetched and normalised (on the device where the path gathers there), no training step
            sync()
            t0, c0 = time.perf_counter(), time.process_time()
            pre(next(it))
            sync()
            print(json.dumps({"s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}), flush=True)
        elif cmd[0] == "step":
            wall, cpu = step()
            print(json.dumps({"s": wall, "cpu_s": cpu}), flush=True)
        elif cmd[0] == "profile":
            from torch.autograd import DeviceType
            from torch.profiler import ProfilerActivity, profile

            k = int(cmd[1])
            activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if args.device == "cuda" else [])
            with profile(activities=activities) as prof:
                sync()
                t0 = time.perf_counter()
                for _ in range(k):
                    step()
                wall_us = (time.perf_counter() - t0) * 1e6
            kernels = [(e.time_range.start, e.time_range.end) for e in prof.events()
                       if e.device_type == DeviceType.CUDA]
            cuda = args.device == "cuda"
            mem = torch.cuda.max_memory_allocated() / 2**30 if cuda else None
            # reserved includes the CUDA graphs' private pools, which the allocated figure leaves out
            reserved = torch.cuda.max_memory_reserved() / 2**30 if cuda else None
            print(json.dumps({"busy": busy_fraction(kernels, wall_us) if kernels else None, "mem_gib": mem,
                              "reserved_gib": reserved}), flush=True)
        elif cmd[0] == "quit":
            return


def baseline_code(commit: str, into: str) -> str:
    """`lerobot_bavo/` of `commit` extracted under `into`; returns `into` (a folder to put first on
    sys.path)."""
    import subprocess
    import tarfile
    from io import BytesIO
    from pathlib import Path

    repo = Path(__file__).resolve().parent.parent
    tar = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", commit, "lerobot_bavo"],
                         check=True, capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(tar)) as t:
        t.extractall(into, filter="data")
    return into


def compare_steps(args) -> None:
    import json
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    repo = Path(__file__).resolve().parent.parent

    def git(*cmd: str) -> str:  # "" where there is no git or no history (the GPU machine)
        try:
            return subprocess.run(["git", "-C", str(repo), *cmd], capture_output=True, text=True,
                                  check=False).stdout.strip()
        except OSError:
            return ""

    head = git("rev-parse", "--short", "HEAD") or "no git history"
    dirty = git("status", "--porcelain", "lerobot_bavo")
    print(
        f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {args.threads}; device "
        f"{args.device}; "
        f"policy {args.policy}, preset {args.preset}, batch {args.batch}, use_amp {args.use_amp}"
    )
    print(
        f"  old: lerobot_bavo/ of {args.baseline_commit or args.baseline_dir}; new: the working tree ({head}"
        f"{', with uncommitted changes' if dirty else ''}) {' '.join(args.new_policy_arg)}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        old = (
            str(Path(args.baseline_dir).resolve())
            if args.baseline_dir
            else baseline_code(args.baseline_commit, tmp)
        )
        code = {"old": old, "new": str(repo)}
        argv = sys.argv[1:]
        workers = {}
        for name in ("old", "new"):
            # first on the path, before whatever the environment has there (on the GPU machine: the wheels)
            env = dict(
                os.environ,
                PYTHONPATH=os.pathsep.join(filter(None, [code[name], os.environ.get("PYTHONPATH")])),
            )
            workers[name] = subprocess.Popen(
                [sys.executable, __file__, *argv, "--worker", name],
                env=env,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                bufsize=1,
            )

        def ask(name: str, cmd: str) -> dict:
            w = workers[name]
            w.stdin.write(cmd + "\n")
            w.stdin.flush()
            while True:
                line = w.stdout.readline()
                if not line:
                    raise SystemExit(f"the {name} worker stopped (see its error above)")
                if line.startswith("{"):
                    return json.loads(line)

        def ready(name: str) -> dict:
            while True:
                line = workers[name].stdout.readline()
                if not line:
                    raise SystemExit(f"the {name} worker stopped (see its error above)")
                if line.startswith("{"):
                    return json.loads(line)

        for name in workers:
            info = ready(name)
            print(f"  {name}: {info['code']}, {info['params'] / 1e6:.2f} M parameters, mixed precision "
                  f"{info['mixed_precision']}, {info['optimizer']}")
        times = {name: [] for name in workers}
        cpu_times = {name: [] for name in workers}
        for i in range(args.warmup + args.steps):
            # neither always runs right after the other
            order = ("old", "new") if i % 2 == 0 else ("new", "old")
            for name in order:
                answer = ask(name, "step")
                if i >= args.warmup:
                    times[name].append(answer["s"])
                    cpu_times[name].append(answer["cpu_s"])
        gather = {name: ask(name, "loader")["gather"] for name in workers}
        loads = {name: [] for name in workers}
        for i in range(args.load_batches):
            for name in (("old", "new") if i % 2 == 0 else ("new", "old")):
                loads[name].append(ask(name, "load"))
        busy, peak, reserved = {}, {}, {}
        if args.device == "cuda" and args.profile_steps > 0:
            profiled = {name: ask(name, f"profile {args.profile_steps}") for name in workers}
            busy = {name: p["busy"] for name, p in profiled.items()}
            peak = {name: p.get("mem_gib") for name, p in profiled.items()}
            reserved = {name: p.get("reserved_gib") for name, p in profiled.items()}
        for worker in workers.values():
            worker.stdin.write("quit\n")
            worker.stdin.flush()
            worker.wait(timeout=60)

    print(
        f"\nTraining step (load + normalise + LeRobot's update_policy), median of {args.steps} alternated "
        "steps "
        f"(load average at end {os.getloadavg()[0]:.2f}):"
    )
    rate = {}
    for name, ts in times.items():
        med = statistics.median(ts)
        q1, q3 = statistics.quantiles(ts, n=4)[0], statistics.quantiles(ts, n=4)[2]
        rate[name] = args.batch / med
        extra = f", batches gathered on {gather[name]}"
        extra += f", GPU busy {busy[name]:.0%}" if busy.get(name) is not None else ""
        extra += f", peak GPU memory {peak[name]:.1f} GiB" if peak.get(name) is not None else ""
        extra += f" ({reserved[name]:.1f} GiB reserved)" if reserved.get(name) is not None else ""
        print(
            f"  {name}: {med * 1e3:8.1f} ms per step of {args.batch} (quartiles "
            f"{q1 * 1e3:.1f}-{q3 * 1e3:.1f}), "
            f"{rate[name]:7.1f} samples/s, CPU time {statistics.median(cpu_times[name]) * 1e3:.1f} ms{extra}"
        )
    if args.load_batches:
        print(f"\nBatch fetch alone (DataLoader + normalisation, batch {args.batch}), median of "
              f"{args.load_batches} alternated fetches:")
        for name, answers in loads.items():
            print(f"  {name}: {statistics.median(a['s'] for a in answers) * 1e3:7.2f} ms wall, "
                  f"{statistics.median(a['cpu_s'] for a in answers) * 1e3:7.2f} ms CPU time")
    pairs = [o / n for o, n in zip(times["old"], times["new"], strict=True)]
    cpu_ratio = statistics.median(cpu_times["old"]) / statistics.median(cpu_times["new"])
    print(f"  ratio new / old: {rate['new'] / rate['old']:.2f}x samples/s (median of the per-round ratios "
          f"{statistics.median(pairs):.2f}x; CPU time per step old / new {cpu_ratio:.2f}x)")


def main() -> None:
    args = parse_args()
    if args.worker:
        return serve_steps(args)
    if args.baseline_commit or args.baseline_dir:
        return compare_steps(args)
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(
        f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {args.threads}; policy {args.policy}"
    )
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
    print(
        f"\nSample loading alone (one dataset item with the policy's delta_timestamps), {args.load_samples} "
        "items:"
    )
    for name in paths:
        print(f"  {name:5s}: {loading_ms(built[name][0], args.load_samples):7.2f} ms per sample")


if __name__ == "__main__":
    main()
