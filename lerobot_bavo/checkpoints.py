"""Loading LeRobot checkpoints we did not write: what they may make us import, and whether they fit the env.

Why: LeRobot's processor loader imports and instantiates whatever `"class"` a checkpoint's
`policy_preprocessor.json` / `policy_postprocessor.json` names (`{"class": "subprocess.Popen",
"config": {"args": [...]}}` runs a shell command at load time), and its policy loader accepts a
`model.safetensors` with missing tensors (it only logs them). Checkpoints come from the Hub, so every
loading path of this package (`bavo-eval`, `bavo-demo`, `LeRobotPolicyAgent`) runs these checks first.

Trusted: processor steps registered in LeRobot's `ProcessorStepRegistry` (LeRobot's own and this
package's, registered on import) except those that load models or tokenizers from the Hub
(`HUB_LOADING_STEPS`) and those whose config asks for Hub code (`trust_remote_code`), and `"class"` paths
inside `lerobot.processor.` or `lerobot_bavo.` that resolve to a `ProcessorStep`; policy types whose loading
runs no code from outside LeRobot, torch and torchvision (`AUDITED_POLICY_TYPES`; LeRobot's pi0_fast,
groot, gaussian_actor and wall_x, by contrast, load Hub models with `trust_remote_code=True` when built).
Everything else is refused *before anything is imported*, unless the caller opts in with
`trust_remote_code=True` (`--trust-remote-code` on the CLIs).

Sizes: a checkpoint's JSON files are read only up to 1 MiB and as UTF-8, the sizes its config asks for
(sampler steps, horizon, widths, depths, point count, image size) are bounded (`lerobot_bavo.limits`, checked
by our policy configs and by `env_settings`), and a truncated `model.safetensors` is named
(`check_tensor_files`): before, such a checkpoint could hang `bavo-eval` past 6 GB or end it with a raw
traceback. Messages show values from the files through `limits.short_repr`.

Fit: a checkpoint's `config.json` records the point count, image size and object-pose input it was
trained on; the point-cloud frame (base or camera) is recorded only by the `bavo-collect` dataset it was
trained on (`train_config.json` -> `meta/bavo_collection.json`, following a training view back to its
source), and so is the robot self-filter; when that dataset is not on this machine both are unknown
(`recorded_cloud_settings`), unless the checkpoint carries them (`bavo_inputs.json`).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

from lerobot_bavo.features import OBS_ENV_STATE, OBS_IMAGE, OBS_POINT_CLOUD, POINT_CHANNELS, POINT_FRAMES
from lerobot_bavo.limits import bound_problems, short_repr

# Module prefixes whose processor step classes may be imported by dotted path.
TRUSTED_CLASS_PREFIXES = ("lerobot.processor.", "lerobot_bavo.")
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")
# Policy types whose construction from a checkpoint runs no code from outside LeRobot, torch and torchvision
# (read in LeRobot 0.6.1's sources: no Hub `from_pretrained` / `trust_remote_code` in their modules; ACT and
# Diffusion may fetch torchvision's ImageNet weights, which load as tensors only), and this package's two.
AUDITED_POLICY_TYPES = ("act", "diffusion", "vqbet", "tdmpc", "maniflow", "afar")
# Registered LeRobot 0.6.1 steps that load a model, tokenizer or processor named in their config from the Hub
# (`from_pretrained`; the action tokenizer with trust_remote_code=True by default, the reward classifier a Hub
# encoder with trust_remote_code=True, the reward models' `robometer_encoder` and `topreward_encoder`
# (registered when `lerobot.rewards` is imported) a Hub processor with trust_remote_code=True, the others
# tokenizers or weights): a checkpoint could point them at any repository. None of them is used by the audited
# policy types. tests/test_faults.py imports every LeRobot module that registers a step and checks that the
# list covers each one whose source calls `from_pretrained` or `hf_hub_download`.
HUB_LOADING_STEPS = frozenset({
    "action_tokenizer_processor", "tokenizer_processor", "reward_classifier_processor", "eo1_qwen_processor",
    "groot_action_unpack_unnormalize_v2", "groot_n1_7_action_decode_v1", "molmoact2_pack_inputs",
    "robometer_encoder", "topreward_encoder",
})


class UntrustedCheckpointError(ValueError):
    """A checkpoint asks to import or run something outside LeRobot's and this package's processor steps and
    audited policy types."""


class CheckpointMismatchError(ValueError):
    """A checkpoint does not fit the environment it is asked to run in, or its weights are incomplete."""


# The largest JSON file of a checkpoint read (config.json, processor files, bavo_inputs.json,
# train_config.json): real ones are a few KB; reading a bigger one whole would only cost memory.
MAX_JSON_BYTES = 1 << 20


def _read_text(path: Path) -> str:
    """The UTF-8 text of a small checkpoint file; CheckpointMismatchError naming it when it is over
    `MAX_JSON_BYTES` or not UTF-8."""
    with open(path, "rb") as fh:
        data = fh.read(MAX_JSON_BYTES + 1)
    if len(data) > MAX_JSON_BYTES:
        raise CheckpointMismatchError(
            f"{path} is over {MAX_JSON_BYTES} bytes; a checkpoint's JSON files are a few KB"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise CheckpointMismatchError(f"{path} is not UTF-8 text ({e.reason} at byte {e.start})") from None


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(_read_text(path))
    except json.JSONDecodeError as e:
        raise CheckpointMismatchError(f"{path} is not valid JSON ({e})") from e
    except RecursionError:
        raise CheckpointMismatchError(f"{path} is nested too deeply to be a checkpoint file") from None
    if not isinstance(data, dict):
        raise CheckpointMismatchError(f"{path} must hold a JSON object, got {type(data).__name__}")
    return data


def _registered_step_names() -> set[str]:
    from lerobot.processor import ProcessorStepRegistry

    import lerobot_bavo.policies  # noqa: F401  (registers our steps)

    return set(ProcessorStepRegistry.list())


def _asks_for_remote_code(step: dict) -> bool:
    """Whether a registered step would be built with `trust_remote_code` on: set in its config, or left out
    where the step's field defaults to True (LeRobot's `action_tokenizer_processor` hands it to
    `transformers.AutoProcessor.from_pretrained`, which then runs the tokenizer repo's Python code)."""
    import dataclasses

    from lerobot.processor import ProcessorStepRegistry

    config = step.get("config") or {}
    if not isinstance(config, dict):
        return False
    if "trust_remote_code" in config:
        return bool(config["trust_remote_code"])
    cls = ProcessorStepRegistry.get(step["registry_name"])
    fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    f = fields.get("trust_remote_code")
    return f is not None and f.default is not dataclasses.MISSING and bool(f.default)


def policy_config_problems(path: str | Path) -> list[str]:
    """What in `config.json` would make loading the checkpoint fetch or run code: a policy `type` that is not
    registered, or not one of `AUDITED_POLICY_TYPES`, or a PEFT adapter (`use_peft`: LeRobot then loads the
    base policy its adapter config names, from the Hub). Reads only JSON."""
    from lerobot.configs.policies import PreTrainedConfig

    import lerobot_bavo.policies  # noqa: F401  (registers maniflow / afar)

    file = Path(path) / "config.json"
    cfg = _read_json(file)
    kind = cfg.get("type")
    known = sorted(PreTrainedConfig.get_known_choices())
    if kind not in known:
        return [f"{file}: policy type {short_repr(kind)} is not a registered LeRobot / lerobot_bavo policy "
                f"({', '.join(known)})"]
    problems = []
    if kind not in AUDITED_POLICY_TYPES:
        problems.append(
            f"{file}: policy type {short_repr(kind)} is not audited: LeRobot types outside "
            f"{', '.join(AUDITED_POLICY_TYPES)} download pretrained components when built, some with "
            "trust_remote_code=True"
        )
    if cfg.get("use_peft"):
        problems.append(f"{file}: use_peft is set (a PEFT adapter loads the base policy named in its adapter "
                        "config, unchecked)")
    return problems


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
            state_file = step.get("state_file")
            if state_file is not None and (
                not isinstance(state_file, str) or Path(state_file).name != state_file
            ):
                problems.append(
                    f"{file}: step {i} state_file {short_repr(state_file)} is not a file name inside "
                    "the checkpoint"
                )
            if "registry_name" in step:
                name = short_repr(step["registry_name"])
                if step["registry_name"] not in registered:
                    problems.append(f"{file}: step {i} registry_name {name} is not a registered "
                                    "LeRobot / lerobot_bavo processor step")
                elif step["registry_name"] in HUB_LOADING_STEPS:
                    problems.append(f"{file}: step {i} registry_name {name} loads a model or "
                                    "tokenizer its config names from the Hub")
                elif _asks_for_remote_code(step):
                    problems.append(f"{file}: step {i} registry_name {name} asks to load Hub code "
                                    "(trust_remote_code is not false in its config)")
                continue
            cls_path = step.get("class")
            if not isinstance(cls_path, str):
                problems.append(f"{file}: step {i} names neither a registry_name nor a class")
                continue
            if not cls_path.startswith(TRUSTED_CLASS_PREFIXES):
                problems.append(f"{file}: step {i} class {short_repr(cls_path)} is outside "
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
                problems.append(f"{file}: step {i} class {short_repr(cls_path)} is not a processor step")
    return problems


def check_processor_steps(path: str | Path, trust_remote_code: bool = False) -> None:
    """Raise `UntrustedCheckpointError` naming every untrusted processor step and policy setting (see
    `processor_step_problems`, `policy_config_problems`), unless `trust_remote_code`. Reads only JSON files
    and imports only LeRobot's and this package's modules, so it is safe on any checkpoint."""
    if trust_remote_code:
        return
    problems = policy_config_problems(path) + processor_step_problems(path)
    if problems:
        raise UntrustedCheckpointError(
            f"refusing to load the checkpoint at {path}: loading it would import or fetch code that is "
            "neither "
            "LeRobot's nor lerobot_bavo's audited code:\n  "
            + "\n  ".join(problems)
            + "\nIf you trust where this checkpoint comes from, pass --trust-remote-code "
              "(trust_remote_code=True)."
        )


def checkpoint_digest(path: str | Path) -> str:
    """sha256 over the checkpoint's config, weights and processor files (names and bytes), in name order.

    Evaluation resume keys on it, so a checkpoint replaced at the same path cannot mix two models'
    episodes in one results file."""
    path = Path(path)
    h = hashlib.sha256()
    names = sorted(
        f.name
        for f in path.iterdir()
        if f.is_file()
        and (
            f.name in ("config.json", "model.safetensors")
            or f.name.startswith(("policy_preprocessor", "policy_postprocessor"))
        )
    )
    for name in names:
        h.update(name.encode() + b"\0")
        with open(path / name, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def env_settings(path: str | Path) -> dict:
    """`BavoEnv` settings a checkpoint records: n_points (from the cloud's input shape, 6 channels),
    image_height / image_width (from `observation.images.active`, CHW), environment_state (object poses
    among the inputs), and point_frame and self_filter where its training data records them
    (`recorded_cloud_settings`). Keys it does not record are absent (point_frame and self_filter also when the
    checkpoint reads no point cloud)."""
    file = Path(path) / "config.json"
    cfg = _read_json(file)
    inputs = cfg.get("input_features")
    if not isinstance(inputs, dict):
        raise CheckpointMismatchError(f"{file} has no input_features object")

    def shape_of(key: str) -> list[int]:
        shape = inputs[key].get("shape") if isinstance(inputs[key], dict) else None
        if not (isinstance(shape, list) and shape and all(isinstance(n, int) and n > 0 for n in shape)):
            raise CheckpointMismatchError(f"{file}: input_features[{short_repr(key)}] has no valid shape "
                                          f"(got {short_repr(shape)})")
        return shape

    out: dict = {}
    if OBS_POINT_CLOUD in inputs:
        shape = shape_of(OBS_POINT_CLOUD)
        if math.prod(shape) % POINT_CHANNELS:
            raise CheckpointMismatchError(
                f"{file}: observation.point_cloud shape {short_repr(shape)} is not N x 6 (xyz rgb)"
            )
        out["n_points"] = math.prod(shape) // POINT_CHANNELS
        cloud = recorded_cloud_settings(path)
        if cloud is not None:
            out.update(cloud)
    if OBS_IMAGE in inputs:
        shape = shape_of(OBS_IMAGE)
        if len(shape) != 3 or 3 not in (shape[0], shape[-1]):
            raise CheckpointMismatchError(
                f"{file}: observation.images.active shape {short_repr(shape)} is not CHW / HWC RGB"
            )
        out["image_height"], out["image_width"] = (
            (shape[1], shape[2]) if shape[0] == 3 else (shape[0], shape[1])
        )
    out["environment_state"] = OBS_ENV_STATE in inputs
    problems = bound_problems(out)
    if problems:
        raise CheckpointMismatchError(
            f"{file} asks the env for observations out of bounds: " + "; ".join(problems)
        )
    return out


INPUTS_RECORD = "bavo_inputs.json"


def write_inputs_record(path: str | Path, point_frame: str, self_filter: bool = False) -> Path:
    """Record beside a checkpoint's weights how its training clouds were made (frame; robot self-filter, only
    when on), so that it loads with the right env settings on a machine without its training data (see
    `recorded_cloud_settings`)."""
    if point_frame not in POINT_FRAMES:
        raise ValueError(f"point_frame must be 'base' or 'camera', got {point_frame!r}")
    if not isinstance(self_filter, bool):
        raise ValueError(f"self_filter must be true or false, got {self_filter!r}")
    out = Path(path) / INPUTS_RECORD
    record = {"point_frame": point_frame, **({"self_filter": True} if self_filter else {})}
    out.write_text(json.dumps(record, indent=2) + "\n")
    return out


def _cloud_settings(record: object, source: Path, strict: bool) -> dict | None:
    """{"point_frame", "self_filter"} from a record holding them (an inputs record, or a collection record's
    `settings`); a record without `self_filter` predates the option: off. None for an invalid record when
    not `strict`; CheckpointMismatchError naming `source` when `strict`."""
    frame = record.get("point_frame") if isinstance(record, dict) else None
    self_filter = record.get("self_filter", False) if isinstance(record, dict) else None
    if frame in POINT_FRAMES and isinstance(self_filter, bool):
        return {"point_frame": frame, "self_filter": self_filter}
    if not strict:
        return None
    raise CheckpointMismatchError(
        f"{source}: point_frame must be 'base' or 'camera' and self_filter (optional) true or false; got "
        f"point_frame {short_repr(frame)}, self_filter {short_repr(self_filter)}"
    )


def recorded_cloud_settings(path: str | Path) -> dict | None:
    """How the clouds the checkpoint at `path` was trained on were made: {"point_frame": "base" / "camera",
    "self_filter": bool}, or None if no file on this machine records it.

    A checkpoint that travels without its data (the shipped one, a Hub download) carries `bavo_inputs.json`
    (`INPUTS_RECORD`, written by `write_inputs_record`), which wins. Otherwise: LeRobot's policy config has no
    place for it; lerobot-train writes `train_config.json` beside the
    weights, whose `env` (when an eval env was configured) or `dataset` names where it came from. The
    `bavo-collect` record of that dataset (`meta/bavo_collection.json`) holds `settings`; a
    training view (`<root>_points`, see `lerobot_bavo.datasets.views`) has none, so its source folder is
    read instead. A relative dataset root is taken from the current folder, as lerobot-train did."""
    own = Path(path) / INPUTS_RECORD
    if own.is_file():
        try:
            record = json.loads(_read_text(own))
        except (json.JSONDecodeError, RecursionError) as exc:
            raise CheckpointMismatchError(f"{own} is not a valid inputs record ({exc!r}); expected "
                                          '{"point_frame": "base"} or {"point_frame": "camera"}') from exc
        return _cloud_settings(record, own, strict=True)
    file = Path(path) / "train_config.json"
    if not file.is_file():
        return None
    try:
        train = json.loads(_read_text(file))
    except (json.JSONDecodeError, RecursionError, CheckpointMismatchError):
        return None
    env = train.get("env") if isinstance(train, dict) else None
    if isinstance(env, dict) and env.get("type") == "bavo":
        found = _cloud_settings(env, file, strict=False)
        if found is not None:
            return found
    dataset = train.get("dataset") if isinstance(train, dict) else None
    if not isinstance(dataset, dict):
        return None
    roots = []
    if isinstance(dataset.get("root"), str):
        roots.append(Path(dataset["root"]))
    elif isinstance(dataset.get("repo_id"), str):
        from lerobot.utils.constants import HF_LEROBOT_HOME

        roots.append(Path(HF_LEROBOT_HOME) / dataset["repo_id"])
    from lerobot_bavo.datasets.metadata import SIDECAR
    from lerobot_bavo.datasets.views import view_source

    roots += [view_source(root) for root in roots if view_source(root) != root]
    for root in roots:
        record = root / SIDECAR
        try:
            settings = json.loads(record.read_text())["settings"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        found = _cloud_settings(settings, record, strict=False)
        if found is not None:
            return found
    return None


def mismatches(recorded: dict, actual: dict) -> list[str]:
    """'key: checkpoint X, env Y' for every recorded setting the env does not have."""
    return [
        f"{k}: checkpoint {v!r}, env {actual.get(k)!r}" for k, v in recorded.items() if actual.get(k) != v
    ]


def load_policy_config(path: str | Path):
    """The checkpoint's `PreTrainedConfig` (LeRobot's reader, so every config's own checks and bounds run:
    `lerobot_bavo.limits`); CheckpointMismatchError naming config.json and the cause otherwise."""
    from lerobot.configs.policies import PreTrainedConfig

    import lerobot_bavo.policies  # noqa: F401  (registers maniflow / afar)
    from lerobot_bavo.datasets.lerobot_private import config_tempfiles_removed

    path = Path(path)
    _read_json(path / "config.json")  # size, encoding and JSON first, with their own messages
    try:
        with config_tempfiles_removed():  # LeRobot's reader leaves a tmpXXXX.json behind otherwise
            return PreTrainedConfig.from_pretrained(path)
    except Exception as e:  # draccus reports an unknown policy type as a bare "invalid choice", and a
        # config's own check (e.g. n_action_steps out of range) only in the chain below its wrapper error
        cause = e
        while cause.__cause__ is not None or cause.__context__ is not None:
            cause = cause.__cause__ or cause.__context__
        detail = f"{e}" if cause is e else f"{e} (because: {cause})"
        raise CheckpointMismatchError(
            f"{path / 'config.json'} cannot be read as a LeRobot policy config "
            f"(is its 'type' a registered policy, are its values valid?): {detail}"
        ) from e


def check_tensor_files(path: str | Path) -> None:
    """Raise CheckpointMismatchError naming `model.safetensors` (or a processor's state file) when it is
    missing, truncated or not a safetensors file. Why: LeRobot's loader fails on those with a bare
    `SafetensorError` traceback ("incomplete metadata, file not fully covered" for a cut-off download). Reads
    headers only."""
    from safetensors import safe_open

    path = Path(path)
    weights = path / "model.safetensors"
    if not weights.is_file():
        raise CheckpointMismatchError(f"{path} has no model.safetensors (the policy's weights)")
    for file in [weights, *sorted(p for p in path.glob("*.safetensors") if p != weights)]:
        try:
            with safe_open(str(file), framework="pt") as f:
                list(f.keys())
        except Exception as e:  # SafetensorError, OSError
            raise CheckpointMismatchError(
                f"{file} is truncated or not a safetensors file ({e}); copy or download the checkpoint again"
            ) from None


def check_weights_complete(policy, path: str | Path) -> None:
    """Raise if `model.safetensors` misses tensors of the policy or holds unknown ones (LeRobot only logs it).

    A policy that names the tensors its inference reads (`inference_state_keys()`, ManiFlow / A-FAR) may come
    from an inference-only checkpoint that holds just those."""
    from safetensors import safe_open

    file = Path(path) / "model.safetensors"
    with safe_open(str(file), framework="pt") as f:
        stored = set(f.keys())
    expected = set(policy.state_dict().keys())
    inference_keys = getattr(policy, "inference_state_keys", None)
    required = set(inference_keys()) if callable(inference_keys) and stored < expected else expected
    missing, unexpected = sorted(required - stored), sorted(stored - expected)
    if missing or unexpected:
        raise CheckpointMismatchError(
            f"{file} does not match the {type(policy).__name__} its config.json describes: "
            f"{len(missing)} missing tensor(s) {missing[:5]}{' ...' if len(missing) > 5 else ''}, "
            f"{len(unexpected)} unexpected {unexpected[:5]}{' ...' if len(unexpected) > 5 else ''}"
        )
