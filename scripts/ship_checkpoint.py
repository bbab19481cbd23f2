"""Copy a trained `lerobot-train` checkpoint into the repository with a model card (README.md).

The card is written from what the run and its evaluation recorded (train_config.json, the training
log's wall time, bavo-eval's results.json), so its numbers are the measured ones. The wall time is read
from `<output_dir>.log` (what `scripts/train_task.sh` tees lerobot-train's output to) when it is on this
machine, summed over resumed segments up to the shipped step; `--wall-min` overrides it.

    python scripts/ship_checkpoint.py --run outputs/train/afar_s1000 --step 006000 \\
        --eval outputs/eval/afar_s1000_006000/results.json --output checkpoints/afar_cube_handoff

The card names the method (the config's policy type) and the task (the training data's `bavo-collect`
record, else the evaluated cells). Without `--eval` the card says the checkpoint is not evaluated yet: ship,
evaluate the shipped folder, then ship again with `--checkpoint DIR --eval results.json` (what
`scripts/train_task.sh recipe` does).

Inference settings (`--num-inference-steps`, `--n-action-steps`, `--temporal-ensemble-coeff`,
`--binary-min-run`, `--smoothed-action-dims` with `--action-smoothing-alpha`) are written into
the shipped config.json and the card says they differ from training; `--notes FILE` adds how they were chosen.
`--checkpoint DIR` re-ships a `pretrained_model` folder (e.g. the shipped one, in place) when the training run
is not on this machine; `--eval` may be given once per results.json (e.g. Stage and Clean evaluated
separately).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
from datetime import datetime
from pathlib import Path

from lerobot_bavo.datasets.metadata import MIX_WEIGHT_KEYS
from lerobot_bavo.demo import SHIPPED_CHECKPOINT as DEMO_CHECKPOINT
from lerobot_bavo.envs.tasks import TASKS
from lerobot_bavo.policies.maniflow.configuration_maniflow import check_chunk_execution

FILES = ("config.json", "model.safetensors", "train_config.json")
MAX_BYTES = 7_000_000  # the size a shipped checkpoint may take in the repository (issue 27: at most 7 MB)


def replace_tensor_file(file: Path, tensors: dict, metadata: dict | None = None) -> None:
    """Write `tensors` over the safetensors `file` through a temporary file beside it (a stop halfway leaves
    the old file whole), keeping its permissions."""
    from safetensors.torch import save_file

    tmp = file.with_name(file.name + ".tmp")
    save_file(tensors, str(tmp), metadata=metadata)
    shutil.copymode(file, tmp)
    tmp.replace(file)


def keep_inference_weights(file: Path, config: dict) -> tuple[int, int]:
    """Rewrite `model.safetensors` with only the tensors inference reads (ManiFlow / A-FAR: the EMA copy, or
    the trained model when `use_ema_for_inference` is off; `ManiFlowPolicy.inference_state_keys`); loading it
    fills the other copy. Returns (tensors kept, tensors dropped)."""
    from safetensors.torch import load_file

    from lerobot_bavo.policies.maniflow.modeling_maniflow import inference_weight_prefixes

    used, unused = inference_weight_prefixes(config.get("use_ema_for_inference", True))
    tensors = load_file(str(file))
    kept = {k: v for k, v in tensors.items() if not k.startswith(unused)}
    if not any(k.startswith(used) for k in kept):
        raise SystemExit(f"{file} holds no '{used}*' tensors; pass --all-weights to ship it whole")
    if len(kept) < len(tensors):
        replace_tensor_file(file, kept, metadata={"format": "pt"})
    return len(kept), len(tensors) - len(kept)


def store_half_precision(file: Path) -> int:
    """Rewrite `model.safetensors` with its float32 tensors stored as float16: half the bytes, so that a model
    twice the size fits the 7 MB a shipped checkpoint may take. LeRobot's loader copies each stored tensor
    into the float32 model (`load_state_dict` casts), so the policy still runs in float32, with weights
    rounded to float16's 11 significant bits (relative error <= 2**-11). Integer tensors (the EMA step) are
    kept. Refuses a tensor that float16 cannot hold (|x| > 65504). Returns the number of tensors converted."""
    import torch
    from safetensors.torch import load_file

    tensors = load_file(str(file))
    converted = 0
    for key, value in tensors.items():
        if value.dtype != torch.float32:
            continue
        half = value.half()
        if not half.isfinite().all() and value.isfinite().all():
            raise SystemExit(f"{file}: tensor '{key}' exceeds float16's range (max |x| = "
                             f"{value.abs().max().item():.4g}); ship it without --half")
        tensors[key] = half
        converted += 1
    if converted:  # a folder already in float16 (re-shipped in place) is left as it is
        replace_tensor_file(file, tensors, metadata={"format": "pt"})
    return converted


def weights_in_half_precision(file: Path) -> bool:
    """Whether `model.safetensors` stores its floating-point tensors in float16 (shipped with `--half`, now
    or when the folder was first shipped: re-shipping with `--checkpoint` keeps the stored precision)."""
    from safetensors import safe_open

    with safe_open(str(file), framework="pt") as f:
        return any(f.get_slice(k).get_dtype() == "F16" for k in f.keys())  # noqa: SIM118 (not a dict)


# The statistics each LeRobot normalisation mode reads (lerobot.processor.normalize_processor,
# `_apply_transform`); IDENTITY reads none.
STATS_READ_BY_MODE = {
    "IDENTITY": (),
    "MEAN_STD": ("mean", "std"),
    "MIN_MAX": ("min", "max"),
    "QUANTILES": ("q01", "q99"),
    "QUANTILE10": ("q10", "q90"),
}
NORMALIZER_STEPS = ("normalizer_processor", "unnormalizer_processor")


def statistics_read(step_config: dict) -> list[str]:
    """The `feature.stat` entries a (un)normalizer step reads at inference, from its saved config: for each of
    its `features`, the statistics of the mode its `norm_map` gives that feature's type."""
    norm_map = step_config.get("norm_map", {})
    keys = []
    for feature, spec in step_config.get("features", {}).items():
        mode = norm_map.get(spec["type"], "IDENTITY")
        if mode not in STATS_READ_BY_MODE:
            raise SystemExit(f"normalisation mode {mode!r} of '{feature}' is unknown to ship_checkpoint.py")
        keys += [f"{feature}.{stat}" for stat in STATS_READ_BY_MODE[mode]]
    return keys


def keep_inference_statistics(folder: Path) -> tuple[int, int]:
    """Rewrite each (un)normalizer state file of the shipped processors with only the statistics it reads at
    inference (`statistics_read`). The training data's statistics hold every feature the dataset has (the
    teacher's training-only targets, indices) and five to ten statistics each (mean, std, quantiles, count);
    a MIN_MAX normaliser reads two. Why it must be exact: LeRobot's normaliser passes a feature through
    unchanged when its statistics are absent, so a missing entry would not fail, it would feed the policy
    raw values; a statistic a step needs but the file lacks is refused here. Returns (entries kept,
    entries dropped) over all files."""
    from safetensors.torch import load_file

    from lerobot_bavo.checkpoints import PROCESSOR_FILES

    kept = dropped = 0
    for name in PROCESSOR_FILES:
        pipeline = json.loads((folder / name).read_text())
        for step in pipeline.get("steps", []):
            if step.get("registry_name") not in NORMALIZER_STEPS or not step.get("state_file"):
                continue
            file = folder / step["state_file"]
            stats = load_file(str(file))
            needed = statistics_read(step.get("config", {}))
            missing = [k for k in needed if k not in stats]
            if missing:
                raise SystemExit(f"{file} lacks statistics its {step['registry_name']} reads: {missing}")
            kept += len(needed)
            dropped += len(stats) - len(needed)
            if len(needed) < len(stats):  # already trimmed (re-shipped in place): left as it is
                replace_tensor_file(file, {k: stats[k].contiguous() for k in needed})
    return kept, dropped


# lerobot-train's log lines that delimit the training time: each (re)start, and each checkpoint it saves
TRAIN_LOG_EVENT = re.compile(
    r"(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) \S+ (?:Start offline training|Checkpoint policy after step (\d+))"
)


def training_wall_min(log_text: str, step: int) -> float | None:
    """Wall minutes lerobot-train spent reaching checkpoint `step`, from its log: each segment (a start or a
    resume) counts from its start to the last checkpoint it saved at or before `step` (work after that
    checkpoint was lost to the stop and redone by the next segment). None if the log never saved `step`."""
    total = 0.0
    start = end = None
    for match in TRAIN_LOG_EVENT.finditer(log_text):
        when = datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S")
        if match.group(2) is None:  # a (re)start: close the previous segment at its last kept checkpoint
            if start is not None and end is not None:
                total += (end - start).total_seconds()
            start, end = when, None
        elif start is not None and int(match.group(2)) <= step:
            end = when
            if int(match.group(2)) == step:
                return (total + (end - start).total_seconds()) / 60
    return None


def collection_summary(train: dict) -> dict | None:
    """What the training dataset's `bavo-collect` record says (condition, execution noise, seeds, discarded
    attempts) and its frame count, or None when that dataset is not on this machine."""
    from lerobot_bavo.datasets.metadata import SIDECAR
    from lerobot_bavo.datasets.views import view_source

    root = train["dataset"].get("root")
    if not root:
        return None
    view_root = Path(root)
    base = view_source(view_root)
    try:
        record = json.loads((base / SIDECAR).read_text())
        info = json.loads((view_root / "meta" / "info.json").read_text())
    except (OSError, ValueError):
        return None
    settings = record["settings"]
    return {"root": str(base), "view_root": str(view_root), "repo_id": record["repo_id"],
            "task": settings["task"],
            "condition": settings["condition"], "execution_noise": settings.get("execution_noise"),
            "episodes": info["total_episodes"], "frames": info["total_frames"],
            "discarded": len(record.get("discarded", [])), "next_seed": record.get("next_seed"),
            "base_seed": settings.get("base_seed", 0), "mixed_from": record.get("mixed_from"),
            "n_points": settings.get("n_points", 256), "self_filter": settings.get("self_filter", False),
            "events_outside_contacts": settings.get("events_outside_contacts", False),
            "decoy_panels": settings.get("decoy_panels", 0)}


METHODS = {  # policy type -> (name on the card, what it is)
    "afar": ("A-FAR", "ManiFlow + WorldQueryFormer future tokens + gated fusion + relational distillation"),
    "maniflow": ("ManiFlow", "consistency flow matching on point clouds: A-FAR's backbone, without its "
                             "future tokens"),
}


# what the frames each `mix_views.py --weigh` mode weights are called on a card, followed by the weight
WEIGHED_FRAMES = {"outside-recovery": "frames outside the view recoveries weigh",
                  "recovery": "the view recoveries' frames weigh", "all": "every frame weighs"}


def weighted(source: dict, dims: list[int] | None = None, applied: bool = True) -> str:
    """What a joined view's source entry says of its loss weights (`mix_views.py --source ROOT:N:WEIGHT`):
    in the action losses, or only in the action dims `dims` (`--policy.loss_weight_dims`); and that the
    weights went unused when the training did not read them (`applied`: `--policy.sample_weights`)."""
    found = [(WEIGHED_FRAMES[weigh], source[key]) for weigh, key in MIX_WEIGHT_KEYS.items()
             if source.get(key) is not None]
    if not found:
        return ""
    if not applied:
        return "; its per-frame loss weights unused: trained without `--policy.sample_weights`"
    where = ("in the action losses" if dims is None
             else f"in action dims {dims_text(dims)} of the action losses, 1 in the others")
    frames, weight = found[0]
    return f"; {frames} {weight} {where}"


def dims_text(dims: list[int]) -> str:
    """[0, 1, 2, 5] -> '0-2, 5': action dims as ranges."""
    runs: list[list[int]] = []
    for d in sorted(dims):
        if runs and d == runs[-1][-1] + 1:
            runs[-1].append(d)
        else:
            runs.append([d])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else f"{r[0]}" for r in runs)


def dims_arg(text: str) -> tuple[int, ...]:
    """'14-20' or '14,15' or '0-2,5' -> action dims (argparse type; the inverse of `dims_text`)."""
    dims: list[int] = []
    try:
        for part in text.split(","):
            first, _, last = part.strip().partition("-")
            dims += range(int(first), int(last or first) + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected dims like 14-20 or 14,15; got {text!r}") from None
    if not dims:
        raise argparse.ArgumentTypeError(f"expected at least one dim; got {text!r}")
    return tuple(dims)


def mixed_data_text(data: dict, noise_text: str, pol: dict | None = None) -> str:
    """The card's data sentence for a view joined by `scripts/mix_views.py` (a documented data variant);
    `pol`, the trained policy's config, says whether and where the view's loss weights were used (None: used,
    in every action dim)."""
    applied = True if pol is None else bool(pol.get("sample_weights", False))
    dims = None if pol is None else pol.get("loss_weight_dims")
    parts = "; ".join(f"the first {m['episodes']} episodes of `{m['root']}` "
                      f"({m['condition']}{weighted(m, dims, applied)})" for m in data["mixed_from"])
    return (f"a data variant, not the paper's protocol: `scripts/mix_views.py` joined the `points` views of "
            f"{parts} ({noise_text}{data['episodes']} episodes, {data['frames']:,} frames, simulator-exact "
            "teacher; each source's collection command and seeds are in its `meta/bavo_collection.json`).")


def card_task(data: dict | None, evals: list[dict], task: str | None = None) -> str:
    """The task the checkpoint was trained on: its data's bavo-collect record, else `--task`, else the one
    evaluated task."""
    if data is not None:
        if task is not None and task != data["task"]:
            raise SystemExit(f"--task {task} contradicts the training data's record ({data['task']})")
        return data["task"]
    if task is not None:
        return task
    tasks = {key.split("/")[0] for results in evals for key in results["cells"]}
    if len(tasks) != 1:
        raise SystemExit(f"cannot tell the training task (data not on this machine; evaluated tasks "
                         f"{tasks}): pass --task")
    return tasks.pop()


# Fields a size preset fills or a `--policy.*` flag may change (the card names those that differ): the model's
# sizes, and A-FAR's relation anchors and fusion-gate learning-rate multiplier (AFAR_PRESETS)
PRESET_FIELDS = ("point_encoder_hidden_dims", "point_feature_dim", "state_feature_dim", "dit_hidden_dim",
                 "dit_num_layers", "dit_num_heads", "dit_mlp_ratio", "time_freq_dim", "time_embed_hidden_dim",
                 "wqf_hidden_dim", "wqf_num_blocks", "wqf_num_heads", "wqf_ffn_ratio", "relation_num_points",
                 "fusion_gate_lr_scale")


def episodes_text(episodes: list[int]) -> str:
    """A `--dataset.episodes` value as written on a card, ready to paste into a shell: one run of consecutive
    indices as `"[$(seq -s, first last)]"` (a fine-tune on 400 of a view's episodes would otherwise print 400
    numbers), any other list as it is."""
    ordered = sorted(episodes)
    if len(ordered) > 2 and ordered == list(range(ordered[0], ordered[-1] + 1)):
        return f'"[$(seq -s, {ordered[0]} {ordered[-1]})]"'
    return "[" + ",".join(map(str, ordered)) + "]"


def start_flags(train: dict) -> tuple[str, str]:
    """The card's `lerobot-train` flags for where the weights start and which episodes train: a fine-tune
    (`--policy.path`, lerobot-train's `pretrained_path`) starts from another checkpoint's weights, EMA and
    processors, so the card names that checkpoint instead of a policy type and size preset, and a run on
    part of a view (`--dataset.episodes`) says which part. Returns (start, episodes), each '' when absent."""
    pol, ds = train["policy"], train["dataset"]
    start = (f"--policy.path={pol['pretrained_path']}" if pol.get("pretrained_path") else
             f"--policy.type={pol['type']} --policy.preset={pol['preset']}")
    episodes = f" --dataset.episodes={episodes_text(ds['episodes'])}" if ds.get("episodes") else ""
    return start, episodes


def preset_flags(pol: dict) -> list[str]:
    """`--policy.<field>=<value>` for each preset-set field of the trained config that differs from its
    preset's value (e.g. `--policy.dit_mlp_ratio=3.5`, `--policy.fusion_gate_lr_scale=1.0`), so that the
    card's command rebuilds the same model and trains it the same way."""
    from lerobot.policies.factory import make_policy_config

    import lerobot_bavo.policies  # noqa: F401  (registers the policy types)

    reference = make_policy_config(pol["type"], preset=pol["preset"], device="cpu")
    flags = []
    for field in PRESET_FIELDS:
        if field not in pol or not hasattr(reference, field):
            continue
        value, preset_value = pol[field], getattr(reference, field)
        if isinstance(preset_value, tuple | list):
            value, preset_value = list(value), list(preset_value)
        if value != preset_value:
            flags.append(f"--policy.{field}={value}".replace(" ", ""))
    return flags


def card(train: dict, evals: list[dict], wall_min: float | None, name: str, data: dict | None, config: dict,
         notes: str = "", half: bool = False, task: str | None = None) -> str:
    pol, ds = train["policy"], train["dataset"]
    method, what = METHODS.get(pol["type"], (pol["type"], "a LeRobot policy"))
    task = card_task(data, evals, task)
    title = task.replace("_", " ").title()
    mixed = bool(data is not None and data.get("mixed_from"))  # a view joined by scripts/mix_views.py
    steps_note = (f" (trained with {pol['num_inference_steps']}; set in the shipped config.json)"
                  if config["num_inference_steps"] != pol["num_inference_steps"] else "")
    chunk_note = (f" (the training config had {pol['n_action_steps']}; set in the shipped config.json)"
                  if config["n_action_steps"] != pol["n_action_steps"] else "")
    coeff = config.get("temporal_ensemble_coeff")
    execution = (f"{config['n_action_steps']} executed per call{chunk_note}" if coeff is None else
                 f"a new one every {config['n_action_steps']} steps{chunk_note}, each executed action the "
                 f"temporal ensemble (ACT's, coefficient {coeff}; set in the shipped config.json) of the "
                 "overlapping chunks' predictions")
    if config.get("smoothed_action_dims") and config.get("action_smoothing_alpha", 1.0) != 1.0:
        alpha = config["action_smoothing_alpha"]
        execution += (f"; action dims {dims_text(config['smoothed_action_dims'])} low-pass filtered at "
                      f"inference (a_t = a_(t-1) + {alpha} (u_t - a_(t-1)); set in the shipped config.json)")
    if config.get("binary_min_run") is not None:
        execution += (f"; a planned gripper switch that the chunk holds for fewer than "
                      f"{config['binary_min_run']} steps before coming back is not executed "
                      "(`binary_min_run`; set in the shipped config.json)")
    steps, batch = train.get("shipped_step") or train["steps"], train["batch_size"]
    schedule = (f" (a checkpoint of a {train['steps']}-step cosine schedule, i.e. before its end)"
                if steps != train["steps"] else "")
    table = ["| task | condition | episodes | seeds | SR (%) | TPS (%) |", "|---|---|---|---|---|---|"]
    reproduce = []
    for results in evals:
        seed = results.get("seed", 1000)
        for key, cell in sorted(results["cells"].items()):
            task, cond = key.split("/")
            table.append(
                f"| {task} | {cond} | {cell['n_episodes']} | {seed}-{seed + cell['n_episodes'] - 1} | "
                f"{cell['sr']:.1f} | {cell['tps']:.1f} |"
            )
        conds = ",".join(sorted({k.split("/")[1] for k in results["cells"]}))
        reproduce.append(f"`bavo-eval --policy checkpoints/{name} --tasks {task} --conditions {conds} "
                         f"--episodes {results['episodes']} --seed {seed}`")
    if not evals:
        table = ["Not evaluated yet."]
        reproduce = [f"`bavo-eval --policy checkpoints/{name} --tasks {task} --conditions clean,stage,random "
                     "--episodes 40 --seed 2000`"]
    cells = [c for results in evals for c in results["cells"].values()]
    status = (
        "\n**Status: it does not succeed yet (SR 0 in every cell below).** It is shipped so that the demo, "
        "both\n"
        "evaluators and the Hub recipe run a real learned policy; the failure ladder in\n"
        "docs/results/ladder_cube_handoff.md says what the CPU budget reached.\n"
        if cells and all(c["sr"] == 0 for c in cells)
        else ""
    )
    wall = (
        f"{wall_min:.1f} min of wall on a 2-core CPU machine" if wall_min else "see the log"
    )
    if data is None:
        data_text = (
            f"`{ds['repo_id']}` (its `bavo-collect` record was not on this machine when the checkpoint "
            "was shipped, so the card cannot say more)."
        )
        frames = None
    else:
        frames = data["frames"]
        noise = data["execution_noise"]
        noise_flag = f" --execution-noise {noise['std']}" if noise else ""
        if data.get("n_points", 256) != 256:
            noise_flag += f" --n-points {data['n_points']}"
        if data.get("self_filter"):
            noise_flag += " --self-filter"
        if data.get("events_outside_contacts"):
            noise_flag += " --events-outside-contacts"
        if data.get("decoy_panels"):
            noise_flag += f" --decoy-panels {data['decoy_panels']}"
        noise_text = (
            f"DART-style execution noise: the env executed the expert's arm targets plus an AR(1) offset "
            f"of std {noise['std']} rad (correlation {noise['correlation']}), the clean targets are "
            "recorded; "
            if noise
            else ""
        )
        data_text = mixed_data_text(data, noise_text, pol) if mixed else (
            f"`bavo-collect --task {task} --condition {data['condition']} --episodes "
            f"{data['episodes']} "
            f"--repo-id {data['repo_id']} --root {data['root']} --workers 2{noise_flag}` "
            f"({noise_text}{data['episodes']} successful episodes from seeds {data['base_seed']}-"
            f"{data['next_seed'] - 1}, {data['discarded']} failed attempts discarded, {frames:,} frames, "
            "simulator-exact teacher), then its `points` view (`python -m lerobot_bavo.datasets.views "
            "--view points`)."
        )
    # a run on part of a view (`--dataset.episodes`) has no epoch count from the view's frames
    epochs = f"{steps * batch / frames:.1f} epochs; " if frames and not ds.get("episodes") else ""
    start, episodes = start_flags(train)
    after = (f", on top of the training of `{pol['pretrained_path']}` (its own card)"
             if pol.get("pretrained_path") else "")
    extra = preset_flags(pol) + [
        f"--policy.{k}={pol[k]}" for k in ("points_per_step", "optimizer_lr", "scheduler_warmup_steps")]
    if pol.get("occluder_dropout"):  # the training recipe against the Stage occluder's position cue
        extra.append(f"--policy.occluder_dropout={pol['occluder_dropout']}")
    if not pol.get("occluder_dropout_in_recovery", True):
        extra.append("--policy.occluder_dropout_in_recovery=false")
    if pol.get("recovery_weight", 1.0) != 1.0:
        extra.append(f"--policy.recovery_weight={pol['recovery_weight']}")
    if pol.get("sample_weights"):  # the per-frame weights of a view joined by scripts/mix_views.py
        extra.append("--policy.sample_weights=true")
    if pol.get("loss_weight_dims") is not None:
        extra.append("--policy.loss_weight_dims=[" + ",".join(str(d) for d in pol["loss_weight_dims"]) + "]")
    binary = config.get("binary_action_dims", [6, 13])
    teacher_text = ". Teacher features are training-only."
    levels = [float(v) for v in config.get("binary_action_levels", [-1.0, 1.0])]
    if levels == [-1.0, 1.0]:
        snap_text = "snapped to fully open or fully closed at\ninference (`binary_action_dims`)"
    else:
        set_after = ([float(v) for v in pol.get("binary_action_levels", [-1.0, 1.0])] != levels)
        snap_text = (f"snapped at inference to the nearest of the\nlevels the demonstrations hold, {levels} "
                     "MIN_MAX-normalised (`binary_action_levels`, from `python -m\n"
                     "lerobot_bavo.datasets.action_levels`"
                     + ("; set in config.json after training, an inference-only setting" if set_after else "")
                     + ")")
    demo = ", `bash scripts/demo.sh` (this checkpoint is its default)" if name == DEMO_CHECKPOINT.name else ""
    n_points = (data or {}).get("n_points", 256)
    self_filter = bool((data or {}).get("self_filter"))
    cloud_text = (f"{n_points} coloured points in the robot base frame"
                  + (", the robot's own body dropped before sampling (`bavo-collect --self-filter`, "
                     "docs/results/self_filter.md)" if self_filter else ""))
    env_flags = (f" --env.n_points={n_points}" if n_points != 256 else "") + (
        " --env.self_filter=true" if self_filter else "")
    if mixed:  # a joined view (self-filtered or not): its own collection, join and training commands
        how = ("the data variant's commands are in docs/training.md, \"Variants and baselines beside the "
               "recipe\"")
    elif self_filter:
        data_name = str(ds["repo_id"]).split("/")[-1].removeprefix(f"bavo_{task}_").removesuffix("_points")
        how = (f"`TASK={task} DATA={data_name} scripts/train_task.sh {pol['type']}` with the recipe's other "
               "variables, after the self-filtered collection: docs/results/self_filter.md gives every "
               "command")
    else:
        how = (f"`TASK={task} scripts/train_task.sh {pol['type']}` with the matching environment variables; "
               f"`TASK={task} bash scripts/train_task.sh recipe {pol['type']}` runs data, training, shipping "
               "and evaluation")
    weights_text = (
        ".\nIt is stored in float16 (`--half`, to fit the 7 MB limit): the policy runs in float32 with its "
        "weights\nrounded to float16, so its actions differ from the trained weights' in the last bits and "
        "some\noutcomes flip; the results above are this folder's (`tests/test_inference_checkpoint.py`)."
        if half else
        ", and its actions are bit for bit those of the full\ncheckpoint "
        "(`tests/test_inference_checkpoint.py`)."
    )
    return f"""---
library_name: lerobot
tags: [lerobot, robotics, bavo-bench, {pol['type']}, active-vision]
---

# {name}: {method} on BAVO-Bench {title} (CPU scale)
{status}
{method} ({what}) trained with
`lerobot-train` on scripted demonstrations of `{task}`, at the `{pol['preset']}`
size preset (see `lerobot_bavo/policies/maniflow/configuration_maniflow.py` and docs/DESIGN.md for every size
that differs from the paper, and why). Inputs: `observation.point_cloud` ({cloud_text}, of which the policy
reads the first {pol.get('points_per_step') or n_points}, an exact FPS subsample)
and `observation.state` (21 joints), 2 observation steps; output: 16-step chunks of 21 absolute joint targets,
{execution}, sampled with {config['num_inference_steps']} Euler
steps{steps_note}, the gripper commands (action dims {list(binary)}) {snap_text}{teacher_text}

## Data
{data_text}

## Training
`lerobot-train {start} {' '.join(extra)}
--dataset.repo_id={ds['repo_id']} --dataset.root={ds.get('root')}{episodes} --batch_size={batch}
--steps={train['steps']} --seed={train['seed']} --num_workers=0` ({how})
Budget: {steps} steps x batch {batch} = {steps * batch:,} samples{schedule}{after}
({epochs}the paper: 100K x 64 = 6.4 M), {wall}. AdamW lr {pol['optimizer_lr']}, cosine
schedule with {pol['scheduler_warmup_steps']} warm-up steps, EMA weights for inference.

## Results (bavo-eval; the demonstrations used seeds below 1000)
{chr(10).join(table)}

Reproduce: {'; '.join(reproduce)}.
{chr(10) + notes if notes else ''}
## Weights
`model.safetensors` holds only what inference reads (the EMA copy;
`scripts/ship_checkpoint.py --all-weights` ships both copies); loading it fills the training copy from the EMA
weights, so fine-tuning with `--policy.path` still works{weights_text}

## Use
- `bavo-eval --policy PATH --tasks {task}`{demo}, or
  `lerobot-eval --policy.path=PATH --env.type=bavo --env.task={task} --env.condition=stage{env_flags}`
  (`bavo-eval` reads the cloud settings from the checkpoint; `lerobot-eval` needs them as flags).
- Push to the Hub: `hf auth login`, then
  `hf upload <user>/{pol['type']}_bavo_{task} checkpoints/{name} .`;
  load with `--policy.path=<user>/{pol['type']}_bavo_{task}`.
- Safety: a checkpoint's processor files name Python classes that LeRobot imports; our loaders accept
  only LeRobot's and this package's processor steps (see docs/checkpoints.md).
"""


def shipped_config(config: dict, args: argparse.Namespace) -> dict:
    """The training config with the inference settings of the command line written in, checked before any
    file is written (SystemExit naming the flag otherwise): a bad flag leaves --output as it was."""
    config = dict(config)
    if (args.smoothed_action_dims is None) != (args.action_smoothing_alpha is None):
        raise SystemExit("--smoothed-action-dims and --action-smoothing-alpha go together")
    for key, value in (
        ("num_inference_steps", args.num_inference_steps),
        ("n_action_steps", args.n_action_steps),
    ):
        if value is not None:
            if value < 1:
                raise SystemExit(f"--{key.replace('_', '-')} must be >= 1")
            config[key] = value
    if args.temporal_ensemble_coeff is not None:
        config["temporal_ensemble_coeff"] = args.temporal_ensemble_coeff
    if args.binary_min_run is not None:
        config["binary_min_run"] = args.binary_min_run
    if config.get("binary_min_run") is not None:
        from lerobot_bavo.policies.switches import check_min_run

        try:
            check_min_run(config["binary_min_run"], config.get("binary_action_dims"),
                          config.get("temporal_ensemble_coeff"))
        except ValueError as err:
            raise SystemExit(f"--binary-min-run: {err}") from None
    if args.smoothed_action_dims is not None:
        from lerobot_bavo.policies.smoothing import check_smoothing

        try:
            check_smoothing(args.smoothed_action_dims, args.action_smoothing_alpha,
                            tuple(config.get("binary_action_dims") or ()))
        except ValueError as err:
            raise SystemExit(f"--smoothed-action-dims / --action-smoothing-alpha: {err}") from None
        config["smoothed_action_dims"] = list(args.smoothed_action_dims)
        config["action_smoothing_alpha"] = args.action_smoothing_alpha
    try:
        check_chunk_execution(config["horizon"], config["n_obs_steps"], config["n_action_steps"],
                              config.get("temporal_ensemble_coeff"))
    except ValueError as err:
        raise SystemExit(f"--n-action-steps / --temporal-ensemble-coeff: {err}") from None
    return config


def main() -> None:
    from lerobot_bavo.features import POINT_FRAMES

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--run", type=Path, help="lerobot-train --output_dir")
    source.add_argument(
        "--checkpoint",
        type=Path,
        help="a pretrained_model folder to ship instead of --run/--step (may be --output itself)",
    )
    p.add_argument(
        "--step",
        default="last",
        help="checkpoint step folder (e.g. 006000) or last; with --checkpoint, the step it was saved at "
        "(for the card's budget) or last",
    )
    p.add_argument("--eval", type=Path, default=[], action="append",
                   help="bavo-eval results.json of this checkpoint (repeat for several runs); none: the card "
                   "says it is not evaluated yet")
    p.add_argument("--notes", type=Path, default=None, help="a Markdown file appended to the card's results")
    p.add_argument("--output", type=Path, required=True,
                   help="where to ship it, e.g. checkpoints/afar_<task>")
    p.add_argument("--wall-min", type=float, default=None,
                   help="training wall time in minutes, for the card; default: read from <output_dir>.log "
                   "(lerobot-train's log) if it is on this machine")
    p.add_argument(
        "--task",
        choices=sorted(TASKS),
        default=None,
        help="the training task, for the card, when neither the training data's record nor an --eval is on "
        "this machine (e.g. re-shipping a committed checkpoint with other inference settings)",
    )
    p.add_argument(
        "--point-frame",
        choices=POINT_FRAMES,
        default=None,
        help="frame of the training clouds; default: read from the training dataset's bavo-collect record",
    )
    p.add_argument(
        "--num-inference-steps",
        type=int,
        default=None,
        help="write this Euler step count into the shipped config.json (an inference setting; the card "
        "says so); default: as trained",
    )
    p.add_argument(
        "--n-action-steps",
        type=int,
        default=None,
        help="write this number of actions executed per policy call into the shipped config.json (an "
        "inference setting, 1 to horizon - n_obs_steps + 1; the card says so); default: as trained",
    )
    p.add_argument(
        "--temporal-ensemble-coeff",
        type=float,
        default=None,
        help="write ACT's temporal ensembling into the shipped config.json (an inference setting: each "
        "executed action is the exp(-coeff * i)-weighted mean of the overlapping chunks' predictions, "
        "a chunk every --n-action-steps steps; the card says so); default: as trained",
    )
    p.add_argument(
        "--binary-min-run",
        type=int,
        default=None,
        help="write this many steps into the shipped config.json as binary_min_run (an inference setting: "
        "a planned gripper switch the chunk does not hold for that long, and that comes back, is not "
        "executed; policies/switches.py; the card says so); default: as trained",
    )
    p.add_argument(
        "--smoothed-action-dims",
        type=dims_arg,
        default=None,
        help="with --action-smoothing-alpha: action dims (e.g. 14-20, the camera arm, or 14,15) whose "
        "commands are low-pass filtered at inference, written into the shipped config.json "
        "(policies/smoothing.py; the card says so); default: as trained",
    )
    p.add_argument(
        "--action-smoothing-alpha",
        type=float,
        default=None,
        help="the low-pass gain in (0, 1] for --smoothed-action-dims (1: off)",
    )
    p.add_argument(
        "--all-weights",
        action="store_true",
        help="ship the whole model.safetensors (training copy and EMA) instead of the inference weights",
    )
    p.add_argument(
        "--half",
        action="store_true",
        help="store the weights in float16 (half the bytes; the policy still runs in float32 with rounded "
        "weights): for a model whose float32 weights exceed the 7 MB limit. Check its SR beside the float32 "
        "folder's: outcomes can flip with rounding",
    )
    p.add_argument(
        "--trim-stats",
        action="store_true",
        help="keep in the processors' statistics files only what their normalisers read at inference (e.g. "
        "min and max of the state, cloud and action), not the training data's every statistic (~0.5 MB)",
    )
    args = p.parse_args()
    src = args.checkpoint if args.checkpoint else args.run / "checkpoints" / args.step / "pretrained_model"
    for name in ("config.json", "train_config.json"):
        if not (src / name).is_file():
            raise SystemExit(f"no checkpoint at {src}: {name} is missing")
    # read every input before the first file is written, so that a wrong path leaves --output as it was
    evals = [json.loads(path.read_text()) for path in args.eval]
    notes = args.notes.read_text() if args.notes else ""
    config = shipped_config(json.loads((src / "config.json").read_text()), args)
    train = json.loads((src / "train_config.json").read_text())
    from lerobot_bavo.checkpoints import recorded_cloud_settings, write_inputs_record

    cloud = recorded_cloud_settings(src) or {}
    frame = args.point_frame or cloud.get("point_frame")
    if frame is None:
        raise SystemExit(f"the training data of {src} is not on this machine; pass --point-frame base|camera")
    args.output.mkdir(parents=True, exist_ok=True)
    names = list(FILES) + [
        f.name for f in src.iterdir() if f.name.startswith(("policy_preprocessor", "policy_postprocessor"))
    ]
    for name in names:
        if (src / name).resolve() != (args.output / name).resolve():
            shutil.copy2(src / name, args.output / name)
    (args.output / "config.json").write_text(json.dumps(config, indent=4) + "\n")
    if not args.all_weights:
        kept, dropped = keep_inference_weights(args.output / "model.safetensors", config)
        print(f"model.safetensors: kept the {kept} inference tensors, dropped {dropped}")
    if args.half:
        converted = store_half_precision(args.output / "model.safetensors")
        print(f"model.safetensors: {converted} tensors in float16")
    if args.trim_stats:
        kept, dropped = keep_inference_statistics(args.output)
        print(f"processor statistics: kept the {kept} read at inference, dropped {dropped}")
    names.append(write_inputs_record(args.output, frame, cloud.get("self_filter", False)).name)
    total = sum((args.output / n).stat().st_size for n in names)
    if total > MAX_BYTES:
        raise SystemExit(f"{args.output} is {total / 1e6:.1f} MB > {MAX_BYTES / 1e6:.0f} MB")
    if args.step.isdigit():
        train["shipped_step"] = int(args.step)
    wall_min = args.wall_min
    log = Path(f"{train.get('output_dir', '')}.log")
    if wall_min is None and train.get("output_dir") and log.is_file() and "shipped_step" in train:
        wall_min = training_wall_min(log.read_text(errors="replace"), train["shipped_step"])
    card_text = card(train, evals, wall_min, args.output.name, collection_summary(train), config, notes,
                     half=weights_in_half_precision(args.output / "model.safetensors"), task=args.task)
    (args.output / "README.md").write_text(card_text)
    print(f"shipped {src} -> {args.output} ({total / 2**20:.1f} MiB)")


if __name__ == "__main__":
    main()
