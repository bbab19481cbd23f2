"""Loading LeRobot checkpoints we did not write: what they may make us import, and whether they fit the env.

Why: LeRobot's processor loader imports and instantiates whatever `"class"` a checkpoint's
`policy_preprocessor.json` / `policy_postprocessor.json` names (`{"class": "subprocess.Popen",
"config": {"args": [...]}}` runs a shell command at load time), and its policy loader accepts a
`model.safetensors` with missing tensors (it only logs them). Checkpoints come from the Hub, so every
loading path of this package (`bavo-eval`, `bavo-demo`, `LeRobotPolicyAgent`) runs these checks first.

Trusted: processor steps registered in LeRobot's `ProcessorStepRegistry` (LeRobot's own and this
package's, registered on import), and `"class"` paths inside `lerobot.processor.` or `lerobot_bavo.`
that resolve to a `ProcessorStep`. Everything else is refused *before anything is imported*, unless the
caller opts in with `trust_remote_code=True` (`--trust-remote-code` on the CLIs).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

# Module prefixes whose processor step classes may be imported by dotted path.
TRUSTED_CLASS_PREFIXES = ("lerobot.processor.", "lerobot_bavo.")
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


class UntrustedCheckpointError(ValueError):
    """A checkpoint asks to import or run something outside LeRobot's and this package's processor steps."""


class CheckpointMismatchError(ValueError):
    """A checkpoint does not fit the environment it is asked to run in, or its weights are incomplete."""


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise CheckpointMismatchError(f"{path} is not valid JSON ({e})") from e
    if not isinstance(data, dict):
        raise CheckpointMismatchError(f"{path} must hold a JSON object, got {type(data).__name__}")
    return data


def _registered_step_names() -> set[str]:
    from lerobot.processor import ProcessorStepRegistry

    import lerobot_bavo.policies  # noqa: F401  (registers our steps)

    return set(ProcessorStepRegistry.list())


def processor_step_problems(path: str | Path) -> list[str]:
    """Every processor step of the checkpoint at `path` that is not trusted, as 'file: step i ...' strings.

    Reads only JSON; imports a `"class"` only when its module path is under a trusted prefix (and then
    checks it is a `ProcessorStep`).
    """
    import importlib

    path = Path(path)
    registered = _registered_step_names()
    problems = []
    for name in PROCESSOR_FILES:
        file = path / name
        if not file.is_file():
            continue
        steps = _read_json(file).get("steps", [])
        if not isinstance(steps, list):
            problems.append(f"{file}: 'steps' is not a list")
            continue
        for i, step in enumerate(steps):
            if not isinstance(step, dict):
                problems.append(f"{file}: step {i} is not an object")
                continue
            if "registry_name" in step:
                if step["registry_name"] not in registered:
                    problems.append(f"{file}: step {i} registry_name {step['registry_name']!r} is not a registered "
                                    "LeRobot / lerobot_bavo processor step")
                continue
            cls_path = step.get("class")
            if not isinstance(cls_path, str):
                problems.append(f"{file}: step {i} names neither a registry_name nor a class")
                continue
            if not cls_path.startswith(TRUSTED_CLASS_PREFIXES):
                problems.append(f"{file}: step {i} class {cls_path!r} is outside "
                                f"{' / '.join(p.rstrip('.') for p in TRUSTED_CLASS_PREFIXES)}")
                continue
            module, _, attr = cls_path.rpartition(".")
            try:
                from lerobot.processor import ProcessorStep

                cls = getattr(importlib.import_module(module), attr)
                ok = isinstance(cls, type) and issubclass(cls, ProcessorStep)
            except (ImportError, AttributeError):
                ok = False
            if not ok:
                problems.append(f"{file}: step {i} class {cls_path!r} is not a processor step")
    return problems


def check_processor_steps(path: str | Path, trust_remote_code: bool = False) -> None:
    """Raise `UntrustedCheckpointError` naming every untrusted processor step, unless `trust_remote_code`."""
    if trust_remote_code:
        return
    problems = processor_step_problems(path)
    if problems:
        raise UntrustedCheckpointError(
            f"refusing to load the checkpoint at {path}: it names processor steps that are neither LeRobot's nor "
            "lerobot_bavo's, and loading them would import and run their code:\n  " + "\n  ".join(problems)
            + "\nIf you trust where this checkpoint comes from, pass --trust-remote-code (trust_remote_code=True)."
        )


def checkpoint_digest(path: str | Path) -> str:
    """sha256 over the checkpoint's config, weights and processor files (names and bytes), in name order.

    Evaluation resume keys on it, so a checkpoint replaced at the same path cannot mix two models'
    episodes in one results file."""
    path = Path(path)
    h = hashlib.sha256()
    names = sorted(f.name for f in path.iterdir() if f.is_file() and (
        f.name in ("config.json", "model.safetensors") or f.name.startswith(("policy_preprocessor", "policy_postprocessor"))))
    for name in names:
        h.update(name.encode() + b"\0")
        with open(path / name, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def env_settings(path: str | Path) -> dict:
    """`BavoEnv` settings a checkpoint records in its input features: n_points (from the cloud, 6 channels),
    image_height / image_width (from `observation.images.active`, CHW), environment_state (object poses
    among the inputs). Keys it does not record are absent."""
    cfg = _read_json(Path(path) / "config.json")
    inputs = cfg.get("input_features")
    if not isinstance(inputs, dict):
        raise CheckpointMismatchError(f"{Path(path) / 'config.json'} has no input_features object")
    out: dict = {}
    pc = inputs.get("observation.point_cloud")
    if pc is not None:
        out["n_points"] = math.prod(pc["shape"]) // 6
    img = inputs.get("observation.images.active")
    if img is not None:
        shape = list(img["shape"])
        c_first = shape[0] == 3
        out["image_height"], out["image_width"] = (shape[1], shape[2]) if c_first else (shape[0], shape[1])
    out["environment_state"] = "observation.environment_state" in inputs
    return out


def mismatches(recorded: dict, actual: dict) -> list[str]:
    """'key: checkpoint X, env Y' for every recorded setting the env does not have."""
    return [f"{k}: checkpoint {v!r}, env {actual.get(k)!r}" for k, v in recorded.items() if actual.get(k) != v]


def check_weights_complete(policy, path: str | Path) -> None:
    """Raise if `model.safetensors` misses tensors of the policy or holds unknown ones (LeRobot only logs it)."""
    from safetensors import safe_open

    file = Path(path) / "model.safetensors"
    with safe_open(str(file), framework="pt") as f:
        stored = set(f.keys())
    expected = set(policy.state_dict().keys())
    missing, unexpected = sorted(expected - stored), sorted(stored - expected)
    if missing or unexpected:
        raise CheckpointMismatchError(
            f"{file} does not match the {type(policy).__name__} its config.json describes: "
            f"{len(missing)} missing tensor(s) {missing[:5]}{' ...' if len(missing) > 5 else ''}, "
            f"{len(unexpected)} unexpected {unexpected[:5]}{' ...' if len(unexpected) > 5 else ''}"
        )
