"""A fast probe of the demonstrations: a deterministic MLP on privileged state (the failure ladder's rung 0).

Why: a ManiFlow run on CPU costs an hour, so questions about the *data* (expert timing jitter, DART-style
execution noise, Clean vs Stage demonstrations, chunk execution) are answered first with a plain 4-layer
MLP: joints (21) + object poses (14) -> the next 16 absolute joint targets, per-dimension standardisation,
MSE, batch 256 x 6000 steps (about 1 min on one core), 20 evaluation episodes in about 1.5 min. It is the
issue's reference model (which reached 8/10 on Clean). Not a LeRobot policy and never shipped: its numbers
are diagnostics, reported as such in docs/results/ladder_cube_handoff.md.

    python scripts/state_mlp_probe.py record --condition clean --episodes 40 --noise 0.01 --out
    /tmp/probe/dart.npz python scripts/state_mlp_probe.py record --dataset
    outputs/datasets/bavo_cube_handoff_state --out /tmp/probe/stage.npz python scripts/state_mlp_probe.py
    train --data /tmp/probe/dart.npz --out /tmp/probe/dart.pt python scripts/state_mlp_probe.py eval --model
    /tmp/probe/dart.pt --condition clean --episodes 20

`record` rolls out the scripted expert itself (no images are kept, so it is fast) or reads a `state` training
view of a bavo-collect dataset; seeds 0.., evaluation seeds 1000.. as everywhere in this project.
"""

from __future__ import annotations

import argparse
import glob
import os
import time

import numpy as np

HORIZON = 16
HIDDEN = 512


def record(args) -> None:
    if args.dataset:
        import pandas as pd

        df = pd.concat([pd.read_parquet(f) for f in sorted(glob.glob(f"{args.dataset}/data/*/*.parquet"))])
        df = df.sort_values("index")
        arrays = {
            "S": np.stack(df["observation.state"].values),
            "E": np.stack(df["observation.environment_state"].values),
            "A": np.stack(df["action"].values),
            "EP": df["episode_index"].to_numpy(),
        }
        np.savez(args.out, **arrays)
        print(f"{len(arrays['S'])} frames of {len(np.unique(arrays['EP']))} episodes -> {args.out}")
        return
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert
    from lerobot_bavo.experts.perturbation import ExecutionNoise

    noise = ExecutionNoise(std=args.noise, clean_contacts=args.clean_contacts)
    # Tiny images: the probe reads state only, which does not depend on the observation's resolution.
    env = BavoEnv(args.task, args.condition, render_mode=None, environment_state=True, n_points=16,
                  image_height=60, image_width=80)
    rows = {"S": [], "E": [], "A": [], "EP": []}
    kept, seed = 0, args.seed
    while kept < args.episodes:
        obs, info = env.reset(seed=seed)
        expert = make_expert(env, seed=None if args.no_jitter else seed)
        expert.reset()
        process = noise.process(seed)
        ep = {"S": [], "E": [], "A": []}
        while True:
            action = np.asarray(expert.act(obs, info), dtype=np.float32)
            ep["S"].append(obs["agent_pos"]), ep["E"].append(obs["environment_state"]), ep["A"].append(action)
            executed = process.perturb(action, quiet=noise.quiet_for(expert)) if noise.enabled else action
            obs, _, terminated, truncated, info = env.step(executed)
            if terminated or truncated:
                break
        if info["is_success"]:
            for k in ep:
                rows[k] += ep[k]
            rows["EP"] += [kept] * len(ep["S"])
            kept += 1
        print(f"seed {seed}: success {info['is_success']}, {len(ep['S'])} steps", flush=True)
        seed += 1
    np.savez(args.out, **{k: np.asarray(v) for k, v in rows.items()})
    print(f"{len(rows['S'])} frames of {kept} episodes -> {args.out}")


def make_net(n_in: int, n_out: int):
    import torch.nn as nn

    return nn.Sequential(nn.Linear(n_in, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
                         nn.Linear(HIDDEN, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, n_out))


def train(args) -> None:
    import torch

    z = np.load(args.data)
    x = np.concatenate([z["S"], z["E"]], 1).astype(np.float32)
    a, ep = z["A"].astype(np.float32), z["EP"]
    n = len(x)
    # Chunk targets a_t .. a_{t+15}, repeating the episode's last action past its end (edge padding).
    last = np.zeros(n, dtype=np.int64)
    for e in np.unique(ep):
        idx = np.flatnonzero(ep == e)
        last[idx] = idx[-1]
    chunk_idx = np.minimum(np.arange(n)[:, None] + np.arange(HORIZON)[None], last[:, None])
    if args.norm == "std":
        xm, xs, am, as_ = x.mean(0), x.std(0) + 1e-6, a.mean(0), a.std(0) + 1e-6
    else:  # min-max to [-1, 1], the policies' MIN_MAX
        xm, xs = (x.min(0) + x.max(0)) / 2, (x.max(0) - x.min(0)) / 2 + 1e-6
        am, as_ = (a.min(0) + a.max(0)) / 2, (a.max(0) - a.min(0)) / 2 + 1e-6
    xn = torch.tensor((x - xm) / xs)
    yn = torch.tensor(((a[chunk_idx] - am) / as_).reshape(n, -1))
    torch.manual_seed(args.seed)
    net = make_net(x.shape[1], yn.shape[1])
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.steps)
    gen = torch.Generator().manual_seed(args.seed)
    t0 = time.perf_counter()
    for step in range(args.steps):
        b = torch.randint(0, n, (args.batch,), generator=gen)
        loss = ((net(xn[b]) - yn[b]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 1000 == 0 or step == args.steps - 1:
            print(f"step {step}: loss {loss.item():.5f}", flush=True)
    print(f"trained on {n} frames in {time.perf_counter() - t0:.0f} s")
    torch.save(
        {"net": net.state_dict(), "xm": xm, "xs": xs, "am": am, "as": as_, "n_in": x.shape[1]}, args.out
    )


def evaluate(args) -> None:
    import torch

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.metrics import NUM_MILESTONES

    ck = torch.load(args.model, weights_only=False)
    net = make_net(ck["n_in"], HORIZON * len(ck["am"]))
    net.load_state_dict(ck["net"])
    net.eval()
    env = BavoEnv(args.task, args.condition, render_mode=None, environment_state=True)
    results = []
    for seed in range(args.eval_seed, args.eval_seed + args.episodes):
        obs, info = env.reset(seed=seed)
        queue: list[np.ndarray] = []
        while True:
            if not queue:
                x = np.concatenate([obs["agent_pos"], obs["environment_state"]])
                with torch.inference_mode():
                    y = net(torch.tensor((x - ck["xm"]) / ck["xs"], dtype=torch.float32)[None]).numpy()
                queue = list((y.reshape(HORIZON, -1) * ck["as"] + ck["am"])[: args.execute])
            obs, _, terminated, truncated, info = env.step(queue.pop(0))
            if terminated or truncated:
                break
        results.append((bool(info["is_success"]), int(info["progress"])))
        print(f"seed {seed}: success {results[-1][0]}, milestone {results[-1][1]}", flush=True)
    sr = 100 * np.mean([r[0] for r in results])
    tps = 100 * np.mean([r[1] for r in results]) / NUM_MILESTONES
    print(f"{args.condition}: SR {sr:.0f} / TPS {tps:.0f} over {len(results)} episodes "
          f"(final milestones {np.bincount([r[1] for r in results], minlength=NUM_MILESTONES + 1).tolist()})")


def main() -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="expert rollouts (or a state view) -> npz")
    r.add_argument("--task", default="cube_handoff")
    r.add_argument("--condition", default="clean")
    r.add_argument("--episodes", type=int, default=40, help="successful episodes wanted")
    r.add_argument("--seed", type=int, default=0, help="first seed")
    r.add_argument("--noise", type=float, default=0.0, help="DART execution noise std, rad (0: off)")
    r.add_argument("--clean-contacts", action="store_true", help="no noise in the expert's contact phases")
    r.add_argument("--no-jitter", action="store_true", help="the expert's nominal timing (no +-15%% jitter)")
    r.add_argument("--dataset", default=None, help="read a bavo `state` training view instead of rolling out")
    r.add_argument("--out", required=True)
    t = sub.add_parser("train", help="fit the MLP")
    t.add_argument("--data", required=True)
    t.add_argument("--out", required=True)
    t.add_argument("--steps", type=int, default=6000)
    t.add_argument("--batch", type=int, default=256)
    t.add_argument("--norm", choices=("std", "minmax"), default="std")
    t.add_argument("--seed", type=int, default=0)
    e = sub.add_parser("eval", help="closed-loop episodes on held-out seeds")
    e.add_argument("--model", required=True)
    e.add_argument("--task", default="cube_handoff")
    e.add_argument("--condition", default="clean")
    e.add_argument("--episodes", type=int, default=20)
    e.add_argument("--eval-seed", type=int, default=1000)
    e.add_argument("--execute", type=int, default=8, help="actions executed per predicted chunk of 16")
    args = p.parse_args()
    import torch

    torch.set_num_threads(1)
    {"record": record, "train": train, "eval": evaluate}[args.cmd](args)


if __name__ == "__main__":
    main()
