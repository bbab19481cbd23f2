"""The training step (issue 28): the same losses and gradients as the step before its speed-ups.

`training_step_reference.json` holds, for each case below, the loss terms and per-parameter gradient checksums
of one fp32 CPU training step computed by the code at commit 729528a (before the step was reworked). The cases
pin the random draws (seeded), give every zero-initialised layer random weights (else most gradients are
exactly 0 and compare trivially) and make the EMA teacher differ from the online network. To write the file
again (only when the training objective changes on purpose): `python tests/test_training_step.py --write`.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs import FeatureType, PolicyFeature

import lerobot_bavo.policies  # noqa: F401  (registers "maniflow" and "afar")
from lerobot_bavo.policies import AfarConfig, AfarPolicy, ManiFlowConfig, ManiFlowPolicy

REFERENCE = Path(__file__).with_name("training_step_reference.json")

N_POINTS, STATE_DIM, ACTION_DIM, TEACHER_DIM, HORIZON = 32, 21, 21, 3, 16
PC, STATE, ACT = "observation.point_cloud", "observation.state", "action"
Z0, ZF, VALID = "observation.teacher.z0", "observation.teacher.zf", "observation.teacher.valid"
OCCLUDER = "observation.teacher.occluder"

TINY = dict(preset="cpu", device="cpu", point_encoder_hidden_dims=(16, 32), point_feature_dim=32,
            state_feature_dim=16, dit_hidden_dim=32, dit_num_layers=2, dit_num_heads=2, time_freq_dim=16,
            time_embed_hidden_dim=32, dropout=0.0)
TINY_AFAR = dict(TINY, wqf_hidden_dim=16, wqf_num_blocks=2, wqf_num_heads=2, relation_num_points=0)

# name -> (policy type, config overrides, batch options)
CASES: dict[str, tuple[str, dict, dict]] = {
    "maniflow": ("maniflow", {}, {}),
    "maniflow_padding_mask": ("maniflow", {"do_mask_loss_for_padding": True}, {"pad": True}),
    "afar": ("afar", {}, {}),
    "afar_invalid_samples_anchor_subset_fps_prefix": (
        "afar",
        {"relation_num_points": 12, "points_per_step": 24},
        {"invalid": (1, 4), "flat_teacher": True},
    ),
    # reads 24 of the 32 points: occluder dropout needs points behind those read (refused otherwise)
    "afar_occluder_dropout": ("afar", {"occluder_dropout": 0.5, "points_per_step": 24},
                              {"occluder": True, "flat_teacher": True}),
    "afar_current_relation_only": ("afar", {"use_future_evolution_loss": False}, {}),
    "afar_no_fusion": ("afar", {"use_fusion": False}, {}),
}


def features(teacher: bool) -> tuple[dict, dict]:
    inputs = {PC: PolicyFeature(FeatureType.STATE, (N_POINTS * 6,)),
              STATE: PolicyFeature(FeatureType.STATE, (STATE_DIM,))}
    if teacher:
        inputs[Z0] = PolicyFeature(FeatureType.STATE, (N_POINTS * TEACHER_DIM,))
    return inputs, {ACT: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))}


def make_policy(kind: str, overrides: dict) -> ManiFlowPolicy:
    torch.manual_seed(0)
    inputs, outputs = features(teacher=kind == "afar")
    if kind == "afar":
        policy = AfarPolicy(
            AfarConfig(input_features=inputs, output_features=outputs, **{**TINY_AFAR, **overrides})
        )
    else:
        policy = ManiFlowPolicy(ManiFlowConfig(input_features=inputs, output_features=outputs,
                                               **{**TINY, **overrides}))
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for name, p in policy.model.named_parameters():  # every zero-initialised weight gets a random value
            if "adaln" in name or "out_mlp.2" in name or "context_pos" in name or "fusion_gate" in name:
                p.copy_(0.2 * torch.randn(p.shape, generator=g))
        for pe, p in zip(policy.ema_model.parameters(), policy.model.parameters(), strict=True):
            pe.copy_(p + 0.05 * torch.randn(p.shape, generator=g))  # a teacher distinct from the student
    return policy.train()


def make_batch(
    kind: str,
    b: int = 8,
    to: int = 2,
    pad: bool = False,
    invalid: tuple = (),
    flat_teacher: bool = False,
    occluder: bool = False,
) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(2)
    batch = {PC: torch.rand(b, to, N_POINTS * 6, generator=g) * 2 - 1,
             STATE: torch.rand(b, to, STATE_DIM, generator=g) * 2 - 1,
             ACT: torch.rand(b, HORIZON, ACTION_DIM, generator=g) * 2 - 1}
    if pad:
        batch["action_is_pad"] = torch.zeros(b, HORIZON, dtype=torch.bool)
        batch["action_is_pad"][::3, -5:] = True
    if kind == "afar":
        z0 = torch.randn(b, to, N_POINTS, TEACHER_DIM, generator=g)
        zf = z0 + 0.3 * torch.randn(b, to, N_POINTS, TEACHER_DIM, generator=g)
        batch[Z0], batch[ZF] = (z.flatten(2) if flat_teacher else z for z in (z0, zf))
        if invalid:
            valid = torch.ones(b, to, 1)
            valid[list(invalid)] = 0.0
            batch[VALID] = valid
    if occluder:
        batch[OCCLUDER] = (torch.rand(b, to, N_POINTS, generator=g) < 0.3).float()
    return batch


def training_step(name: str) -> dict:
    """One fp32 step of case `name`: loss terms and, per trained parameter, (sum, norm, projection) of its
    grad."""
    kind, overrides, batch_options = CASES[name]
    policy = make_policy(kind, overrides)
    batch = make_batch(kind, **batch_options)
    torch.manual_seed(3)
    loss, info = policy.forward(batch)
    loss.backward()
    g = torch.Generator().manual_seed(4)
    grads = {}
    for pname, p in policy.model.named_parameters():
        if p.grad is None:
            grads[pname] = None
            continue
        r = torch.randn(p.shape, generator=g)
        grads[pname] = [float(p.grad.sum()), float(p.grad.norm()), float((p.grad * r).sum())]
    return {"loss": float(loss.detach()), "info": {k: float(v) for k, v in info.items()}, "grads": grads}


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.mark.parametrize("name", list(CASES))
def test_loss_and_gradients_equal_the_reference_step(name):
    reference = json.loads(REFERENCE.read_text())[name]
    new = training_step(name)
    torch.testing.assert_close(new["loss"], reference["loss"], rtol=1e-5, atol=1e-7)
    assert set(new["info"]) >= set(reference["info"]), (sorted(new["info"]), sorted(reference["info"]))
    for key, value in reference["info"].items():
        torch.testing.assert_close(new["info"][key], value, rtol=1e-5, atol=1e-7, msg=key)
    assert set(new["grads"]) == set(reference["grads"])
    for pname, ref in reference["grads"].items():
        got = new["grads"][pname]
        if ref is None:
            assert got is None, pname
            continue
        assert got is not None, pname
        scale = max(ref[1], 1e-12)  # the gradient's norm: sums and projections are compared relative to it
        torch.testing.assert_close(torch.tensor(got), torch.tensor(ref), rtol=1e-4, atol=1e-5 * scale,
                                   msg=lambda m, p=pname: f"{p}: {m}")


@pytest.mark.parametrize("dropout", [0.0, 0.3])
def test_cross_attention_to_the_memory_equals_attention_to_its_keys_and_values(dropout, monkeypatch):
    """`CrossAttention.attend_memory` (training) against SDPA on explicit keys and values (inference), with
    the same attention-dropout mask."""
    import torch.nn.functional as F  # noqa: N812

    from lerobot_bavo.policies.maniflow.modeling_maniflow import CrossAttention

    torch.manual_seed(0)
    attn = CrossAttention(dim=24, heads=3, dropout=dropout, memory_dim=20).train()
    with torch.no_grad():
        # biases matter: b_k shifts no score, b_v is weighted by the kept attention
        attn.kv_proj.bias.normal_()
    x, memory = torch.randn(5, 4, 24), torch.randn(5, 7, 20)
    mask = (torch.rand(5, 3, 4, 7) > dropout).float() / (1 - dropout)  # one dropout draw, used by both
    monkeypatch.setattr(F, "dropout", lambda a, p, *args, **kwargs: a * mask.view(a.shape))
    got = attn.attend_memory(x, memory)
    q = attn.q(x).view(5, 4, 3, 8).transpose(1, 2)
    k, v = attn.kv(memory)
    weights = (q @ k.transpose(-1, -2) / 8**0.5).softmax(-1) * mask
    expected = attn.out((weights @ v).transpose(1, 2).reshape(5, 4, 24))
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    if dropout == 0:  # and SDPA itself
        torch.testing.assert_close(got, attn.eval()(x, attn.kv(memory)), rtol=1e-5, atol=1e-6)


# ---- The step's mechanics: no host reads, LeRobot's logging, optimiser, mixed precision, compilation
# -------------


@pytest.fixture
def host_reads(monkeypatch):
    """Count the reads of a tensor's value on the host (what waits for a device) inside a `with` block."""
    import contextlib

    @contextlib.contextmanager
    def counting():
        reads: list[str] = []
        with monkeypatch.context() as m:
            for name in ("item", "tolist", "numpy", "__bool__", "__int__", "__float__", "__index__"):
                original = getattr(torch.Tensor, name)

                def counted(self, *args, _name=name, _original=original, **kwargs):
                    reads.append(_name)
                    return _original(self, *args, **kwargs)

                m.setattr(torch.Tensor, name, counted)
            yield reads

    return counting


@pytest.mark.parametrize("name", ["maniflow_padding_mask", "afar_invalid_samples_anchor_subset_fps_prefix",
                                  "afar_occluder_dropout"])
def test_a_training_step_reads_the_device_once(name, host_reads):
    """Each host read inside a CUDA step waits for the GPU to run everything queued (issue 28): forward,
    backward and the EMA update read only the logged values, all at once at the end of the forward pass."""
    kind, overrides, batch_options = CASES[name]
    policy = make_policy(kind, overrides)
    batch = make_batch(kind, **batch_options)
    policy.update()  # the first update reads the saved EMA step count once
    with host_reads() as reads:
        loss, info = policy.forward(batch)
        loss.backward()
        policy.update()
    assert reads == ["tolist"]
    assert all(isinstance(v, (float, int)) for v in info.values())
    assert info["loss"] == pytest.approx(float(loss.detach()))


def test_nonfinite_teacher_targets_raise():
    policy = make_policy("afar", {})
    batch = make_batch("afar")
    batch[Z0][2, -1, 5] = float("nan")
    with pytest.raises(ValueError, match="teacher cache is broken"):
        policy.forward(batch)


class CpuAccelerator:
    """What LeRobot's `update_policy` uses of `accelerate.Accelerator`, on the CPU, with autocast as
    Accelerate sets it up for `mixed_precision` (Accelerate's state is one per process: it cannot switch
    precision between tests)."""

    def __init__(self, mixed_precision: str):
        self.dtype = {"no": None, "bf16": torch.bfloat16}[mixed_precision]

    def autocast(self):
        return torch.autocast("cpu", dtype=self.dtype or torch.bfloat16, enabled=self.dtype is not None)

    def backward(self, loss):
        loss.backward()

    def clip_grad_norm_(self, params, max_norm):
        return torch.nn.utils.clip_grad_norm_(params, max_norm)

    def unwrap_model(self, model, keep_fp32_wrapper=True):
        return model


def lerobot_step(policy, batch, mixed_precision: str = "no") -> dict:
    """One step of LeRobot's own `update_policy` (as lerobot-train runs it); returns the tracked averages."""
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker

    opt_cfg = policy.config.get_optimizer_preset()
    opt = opt_cfg.build(policy.get_optim_params())
    meters = {k: AverageMeter(k) for k in ("loss", "grad_norm", "lr", "update_s")}
    tracker = MetricsTracker(8, 100, 2, meters)
    tracker, _ = update_policy(tracker, policy, batch, opt, opt_cfg.grad_clip_norm,
                               CpuAccelerator(mixed_precision))
    return {k: m.avg for k, m in tracker.metrics.items()}


def test_lerobot_update_policy_logs_every_loss_term():
    policy = make_policy("afar", {"relation_num_points": 12})
    logged = lerobot_step(policy, make_batch("afar", invalid=(1,)))
    assert {
        "loss_fm",
        "loss_ct",
        "loss_maniflow",
        "loss_cur",
        "loss_evo",
        "teacher_valid",
        "fusion_gate_abs",
    } <= set(logged)
    assert logged["teacher_valid"] == 7 and logged["loss"] > 0 and int(policy.ema_step) == 1


def test_training_preset_optimizer_is_fused_adamw_with_adamw_updates():
    import dataclasses

    import draccus
    from lerobot.optim import OptimizerConfig

    # The optimizer field of LeRobot's TrainPipelineConfig (made here with real, not string, annotations).
    TrainConfig = dataclasses.make_dataclass("TrainConfig", [("optimizer", OptimizerConfig | None, None)])

    policy = make_policy("afar", {})
    opt_cfg = policy.config.get_optimizer_preset()
    # saved with a checkpoint's train config, read back on resume
    encoded = draccus.encode(TrainConfig(opt_cfg))
    assert encoded["optimizer"]["type"] == "adamw_fused"
    assert draccus.decode(TrainConfig, encoded).optimizer == opt_cfg
    fused = opt_cfg.build(policy.get_optim_params())
    assert fused.defaults["fused"]
    # torch's plain AdamW on copies of the parameters, fed the same gradients: the same updates
    groups = policy.get_optim_params()
    copies = {id(p): torch.nn.Parameter(p.detach().clone()) for g in groups for p in g["params"]}
    plain = torch.optim.AdamW(
        [{**g, "params": [copies[id(p)] for p in g["params"]]} for g in groups],
        lr=opt_cfg.lr,
        betas=opt_cfg.betas,
        eps=opt_cfg.eps,
        weight_decay=opt_cfg.weight_decay,
        foreach=False,
    )
    batch = make_batch("afar")
    for seed in (5, 6, 7):
        torch.manual_seed(seed)
        policy.forward(batch)[0].backward()
        for p in policy.model.parameters():
            copies[id(p)].grad = None if p.grad is None else p.grad.clone()
        fused.step()
        plain.step()
        fused.zero_grad()
    for name, p in policy.model.named_parameters():
        torch.testing.assert_close(p, copies[id(p)], rtol=1e-6, atol=1e-7, msg=name)


def test_use_amp_is_bf16_autocast_and_trains_on_cpu():
    policy = make_policy("afar", {"use_amp": True})
    assert policy.config.use_amp and policy.config.dtype == "bfloat16"
    assert make_policy("afar", {}).config.dtype == "float32"
    torch.manual_seed(3)
    logged = lerobot_step(policy, make_batch("afar"), mixed_precision="bf16")
    assert all(math.isfinite(v) for v in logged.values())
    reference = json.loads(REFERENCE.read_text())["afar"]
    for key in ("loss", "loss_fm", "loss_ct", "loss_cur", "loss_evo"):  # bf16: the fp32 values to ~2 digits
        assert logged[key] == pytest.approx(reference["info"][key], rel=0.03), key
    assert all(p.dtype == torch.float32 for p in policy.parameters())


# the case of each policy type that the compiled (and CUDA-graph) steps are checked on
COMPILED_CASE = {"maniflow": "maniflow", "afar": "afar_invalid_samples_anchor_subset_fps_prefix"}


@pytest.mark.parametrize("kind", ["maniflow", "afar"])
def test_compile_waits_for_the_first_training_step(kind):
    """`compile=true` is a training setting: a policy built with it (as `from_pretrained` builds one from a
    checkpoint trained compiled) keeps eager networks until its first loss computation, which compiles both
    copies' sub-networks once (checked without running the compiler: `nn.Module.compile` only wraps)."""
    policy = make_policy(kind, {**CASES[COMPILED_CASE[kind]][1], "compile": True})
    modules = [m for model in (policy.model, policy.ema_model) for m in policy.compiled_modules(model)]
    assert modules and all(m._compiled_call_impl is None for m in modules)
    policy.begin_training_step()
    wrapped = [m._compiled_call_impl for m in modules]
    assert all(w is not None for w in wrapped)
    policy.begin_training_step()  # not wrapped again
    assert [m._compiled_call_impl for m in modules] == wrapped


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["maniflow", "afar"])
def test_compile_gives_the_eager_step(kind):
    """`--policy.compile=true`: same losses and gradients as eager (compilation takes ~1 min on 2 CPU
    cores)."""
    name = COMPILED_CASE[kind]
    _, overrides, batch_options = CASES[name]
    eager, compiled = make_policy(kind, overrides), make_policy(kind, {**overrides, "compile": True})
    batch = make_batch(kind, **batch_options)
    logged = {}
    for policy in (eager, compiled):
        torch.manual_seed(3)
        loss, logged[policy] = policy.forward(batch)
        loss.backward()
        policy.update()
    for key, value in logged[eager].items():
        assert logged[compiled][key] == pytest.approx(value, rel=1e-4, abs=1e-6), key
    for (pname, p), q in zip(compiled.model.named_parameters(), eager.model.parameters(), strict=True):
        if q.grad is None:
            assert p.grad is None, pname
        else:
            torch.testing.assert_close(p.grad, q.grad, rtol=1e-4, atol=1e-6, msg=pname)
    assert set(compiled.state_dict()) == set(eager.state_dict())  # checkpoints unchanged


@pytest.mark.slow
@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA device")
@pytest.mark.parametrize("kind", ["maniflow", "afar"])
def test_cuda_graphs_give_the_eager_steps(kind):
    """`--policy.compile_mode=reduce-overhead` (CUDA graphs, recorded in the first steps, replayed after): the
    eager step's losses and gradients over several optimiser steps on different batches, so a replay reads the
    current weights and batch, not those it was recorded with (run on a GPU: docs/gpu.md)."""
    name = COMPILED_CASE[kind]
    _, overrides, batch_options = CASES[name]
    tf32 = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    try:
        runs = {}
        for mode in ("eager", "graphs"):
            extra = {"compile": True, "compile_mode": "reduce-overhead"} if mode == "graphs" else {}
            policy = make_policy(kind, {**overrides, **extra, "device": "cuda"}).to("cuda")
            optimizer = torch.optim.SGD(policy.model.parameters(), lr=0.05)
            runs[mode] = []
            for step in range(4):
                batch = {k: (v + 0.1 * step if v.is_floating_point() and k in (PC, STATE, ACT) else v).cuda()
                         for k, v in make_batch(kind, **batch_options).items()}
                torch.manual_seed(3 + step)
                optimizer.zero_grad()
                loss, logged = policy.forward(batch)
                loss.backward()
                grads = [None if p.grad is None else p.grad.detach().cpu().clone()
                         for p in policy.model.parameters()]
                optimizer.step()
                policy.update()
                runs[mode].append((logged, grads))
    finally:
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = tf32
    for step, ((logged_e, grads_e), (logged_g, grads_g)) in enumerate(zip(runs["eager"], runs["graphs"])):
        for key, value in logged_e.items():
            assert logged_g[key] == pytest.approx(value, rel=1e-3, abs=1e-5), (step, key)
        for i, (ge, gg) in enumerate(zip(grads_e, grads_g, strict=True)):
            if ge is None:
                assert gg is None, (step, i)
            else:
                torch.testing.assert_close(gg, ge, rtol=1e-3, atol=1e-5, msg=f"step {step}, parameter {i}")


def test_benchmark_gpu_busy_fraction_is_the_union_of_kernel_intervals():
    """benchmarks/train_throughput.py's GPU busy figure (its CUDA path cannot run here; this part can)."""
    from _helpers import load_script

    bench = load_script("benchmarks/train_throughput.py")
    assert bench.busy_fraction([(0, 2), (1, 3), (5, 6), (5.5, 5.8)], wall=10) == pytest.approx(0.4)
    assert bench.busy_fraction([], wall=10) == 0.0
    assert bench.policy_overrides(["compile=true", "batch=3", "lr=1e-4", "mode=reduce-overhead"]) == {
        "compile": True, "batch": 3, "lr": 1e-4, "mode": "reduce-overhead"}
    bench.require_a_full_batch(num_frames=860, batch=860, root="v")  # exactly one full batch: fine
    with pytest.raises(SystemExit, match="1024 is larger than v's 860 frames"):
        bench.require_a_full_batch(num_frames=860, batch=1024, root="v")  # the loaders would never yield one


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        raise SystemExit(__doc__)
    torch.set_num_threads(1)
    REFERENCE.write_text(json.dumps({name: training_step(name) for name in CASES}, indent=1) + "\n")
    print(f"wrote {REFERENCE}")
