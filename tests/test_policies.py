"""ManiFlow and A-FAR policies on synthetic batches (tiny configs; the whole file runs in well under a
minute)."""

from __future__ import annotations

import copy
import dataclasses
from types import SimpleNamespace

import draccus
import pytest
import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.configs import FeatureType, PolicyFeature, PreTrainedConfig

import lerobot_bavo.policies  # noqa: F401  (registers "maniflow" and "afar")
from lerobot_bavo.policies import AfarConfig, AfarPolicy, ManiFlowConfig, ManiFlowPolicy
from lerobot_bavo.sim.constants import CAMERA_ARM
from lerobot_bavo.teacher.relations import relational_losses, teacher_relations


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Tiny models: one thread is as fast, and immune to OpenMP stalls when the machine is busy."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


N_POINTS = 32
STATE_DIM = ACTION_DIM = 21
TEACHER_DIM = 8
PC, STATE, ACT = "observation.point_cloud", "observation.state", "action"
Z0, ZF, VALID = "observation.teacher.z0", "observation.teacher.zf", "observation.teacher.valid"

TINY = dict(
    preset="cpu",
    device="cpu",
    point_encoder_hidden_dims=(16, 32),
    point_feature_dim=32,
    state_feature_dim=16,
    dit_hidden_dim=32,
    dit_num_layers=2,
    dit_num_heads=2,
    time_freq_dim=16,
    time_embed_hidden_dim=32,
    dropout=0.0,
)
TINY_AFAR = dict(TINY, wqf_hidden_dim=16, wqf_num_blocks=2, wqf_num_heads=2, relation_num_points=0)


def features(with_teacher: bool = False) -> tuple[dict, dict]:
    inputs = {
        PC: PolicyFeature(FeatureType.STATE, (N_POINTS, 6)),
        STATE: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
    }
    if with_teacher:
        inputs[Z0] = PolicyFeature(FeatureType.STATE, (N_POINTS, TEACHER_DIM))
        inputs[ZF] = PolicyFeature(FeatureType.STATE, (N_POINTS, TEACHER_DIM))
    return inputs, {ACT: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))}


def make_maniflow(**overrides) -> ManiFlowPolicy:
    inputs, outputs = features()
    return ManiFlowPolicy(
        ManiFlowConfig(input_features=inputs, output_features=outputs, **{**TINY, **overrides})
    )


def make_afar(**overrides) -> AfarPolicy:
    inputs, outputs = features()
    return AfarPolicy(
        AfarConfig(input_features=inputs, output_features=outputs, **{**TINY_AFAR, **overrides})
    )


def synthetic_batch(b: int = 8, to: int = 2, seed: int = 0, teacher: bool = True) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    batch = {
        PC: torch.rand(b, to, N_POINTS, 6, generator=g) * 2 - 1,
        STATE: torch.rand(b, to, STATE_DIM, generator=g) * 2 - 1,
        ACT: torch.rand(b, 16, ACTION_DIM, generator=g) * 2 - 1,
    }
    if teacher:  # with the time axis LeRobot's observation delta indices add
        batch[Z0] = torch.randn(b, to, N_POINTS, TEACHER_DIM, generator=g)
        batch[ZF] = batch[Z0] + 0.3 * torch.randn(b, to, N_POINTS, TEACHER_DIM, generator=g)
    return batch


def observation(seed: int = 1) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        PC: torch.rand(1, N_POINTS, 6, generator=g) * 2 - 1,
        STATE: torch.rand(1, STATE_DIM, generator=g) * 2 - 1,
    }


def randomize_zero_init(policy: ManiFlowPolicy, seed: int = 0) -> None:
    """Give the zero-initialised DiT layers random values (else every velocity is 0 and all policies
    agree)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for model in (policy.model, policy.ema_model):
            for name, p in model.dit.named_parameters():
                if "adaln" in name or "out_mlp.2" in name or "context_pos" in name:
                    p.copy_(0.2 * torch.randn(p.shape, generator=g))


# (a)
# -----------------------------------------------------------------------------------------------------------


def fixed_seed_loss(policy, batch, seed: int = 123, reps: int = 4) -> float:
    """The training loss with pinned noise / flow times, so that before and after are comparable."""
    with torch.random.fork_rng(), torch.no_grad():
        torch.manual_seed(seed)
        return sum(policy.forward(batch)[0].item() for _ in range(reps)) / reps


def fit(policy, batch, steps: int, lr: float = 5e-3) -> tuple[float, float, dict]:
    """Adam on one batch for `steps` steps (EMA updated each step); (loss before, loss after, last info)."""
    opt = torch.optim.Adam(policy.get_optim_params(), lr=lr)
    start = fixed_seed_loss(policy, batch)
    policy.train()
    info = {}
    for _ in range(steps):
        loss, info = policy.forward(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        policy.update()
        assert torch.isfinite(loss)
    return start, fixed_seed_loss(policy, batch), info


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_overfits_one_batch(make):
    torch.manual_seed(0)
    policy = make()
    policy.train()
    batch = synthetic_batch()
    # Demonstration-like targets: each chunk moves smoothly from the current state to another state-dependent
    # pose, so the chunk is a function of the observation (random chunks take thousands of steps to memorise).
    s, h = batch[STATE][:, -1, None], torch.linspace(0, 1, 16)[None, :, None]
    batch[ACT] = (1 - h) * s + h * s.roll(1, dims=-1)
    start, end, info = fit(policy, batch, 200)
    assert end < 0.3 * start, (start, end)
    assert {"loss_fm", "loss_ct", "loss"} <= set(info)
    if isinstance(policy, AfarPolicy):
        assert {"loss_cur", "loss_evo", "loss_maniflow"} <= set(info)
        assert all(isinstance(v, (float, int)) for v in info.values())


# (b)
# -----------------------------------------------------------------------------------------------------------


def test_afar_equals_maniflow_at_init():
    torch.manual_seed(0)
    maniflow = make_maniflow().eval()
    randomize_zero_init(maniflow)
    afar = make_afar().eval()
    missing, unexpected = afar.load_state_dict(maniflow.state_dict(), strict=False)
    assert not unexpected
    assert missing and all(("world_query_former" in k) or ("fusion" in k) for k in missing)
    assert torch.all(afar.model.fusion_gate == 0) and torch.all(afar.ema_model.fusion_gate == 0)

    batch = synthetic_batch(b=2, teacher=False)
    pc, st = maniflow._observation_tensors(batch)
    ctx_m, _ = maniflow.model.observation_context(pc, st)
    ctx_a, aux = afar.model.observation_context(pc, st)
    assert "h_fut" in aux  # the future branch ran, and the zero gate removed its contribution exactly
    torch.testing.assert_close(ctx_a, ctx_m, rtol=0, atol=0)

    noise = torch.randn(1, 16, ACTION_DIM, generator=torch.Generator().manual_seed(3))
    obs = observation()
    a_m = maniflow.select_action(dict(obs), noise=noise)
    a_a = afar.select_action(dict(obs), noise=noise)
    assert a_m.abs().max() > 0
    torch.testing.assert_close(a_a, a_m, rtol=0, atol=1e-6)

    # The comparison is sensitive: opening the gate changes the action.
    with torch.no_grad():
        afar.ema_model.fusion_gate.fill_(1.0)
    afar.reset()
    assert not torch.allclose(afar.select_action(dict(obs), noise=noise), a_m, atol=1e-4)


# (c)
# -----------------------------------------------------------------------------------------------------------


def test_relational_loss_zero_iff_relations_match():
    g = torch.Generator().manual_seed(0)
    h_cur = torch.randn(3, N_POINTS, 16, generator=g)
    h_fut = h_cur + 0.5 * torch.randn(3, N_POINTS, 16, generator=g)
    # Teacher features whose relations equal the student's (the student side L2-normalises its tokens).
    r_t, dr_t = teacher_relations(F.normalize(h_cur, dim=-1), F.normalize(h_fut, dim=-1))
    l_cur, l_evo = relational_losses(h_cur, h_fut, r_t, dr_t)
    assert l_cur.item() == pytest.approx(0.0, abs=1e-5) and l_evo.item() == pytest.approx(0.0, abs=1e-5)
    # Unrelated teacher features: both terms positive.
    z0 = torch.randn(3, N_POINTS, TEACHER_DIM, generator=g)
    zf = z0 + torch.randn(3, N_POINTS, TEACHER_DIM, generator=g)
    l_cur, l_evo = relational_losses(h_cur, h_fut, *teacher_relations(z0, zf))
    assert l_cur.item() > 1e-3 and l_evo.item() > 1e-3


def test_afar_relational_loss_masks_invalid_samples_and_reads_both_layouts():
    torch.manual_seed(0)
    policy = make_afar().train()
    batch = synthetic_batch(b=4)
    pc, st = policy._observation_tensors(batch)
    _, aux = policy.model.observation_context(pc, st, need_future=True)
    full = policy.relational_loss(batch, aux)
    # Without the time axis (B, N, d) the same targets give the same loss.
    flat = dict(batch, **{Z0: batch[Z0][:, -1], ZF: batch[ZF][:, -1]})
    torch.testing.assert_close(policy.relational_loss(flat, aux)[0], full[0])
    # Invalid samples are left out: corrupting them changes nothing.
    valid = torch.tensor([[1.0], [0.0], [1.0], [0.0]])
    corrupted = dict(batch, **{VALID: valid})
    corrupted[Z0] = batch[Z0].clone()
    corrupted[Z0][1] = 100 * torch.randn_like(corrupted[Z0][1])
    masked = dict(batch, **{VALID: valid})
    l1, l2 = policy.relational_loss(masked, aux), policy.relational_loss(corrupted, aux)
    assert l1[2] == l2[2] == 2
    torch.testing.assert_close(l1[0], l2[0])
    assert policy.relational_loss(dict(batch, **{VALID: torch.zeros(4)}), aux)[2] == 0


# (d)
# -----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls_cfg", [(ManiFlowPolicy, ManiFlowConfig), (AfarPolicy, AfarConfig)],
                         ids=["maniflow", "afar"])
def test_teacher_keys_are_training_only(cls_cfg):
    policy_cls, config_cls = cls_cfg
    inputs, outputs = features(with_teacher=True)
    kwargs = TINY_AFAR if config_cls is AfarConfig else TINY
    config = config_cls(input_features=inputs, output_features=outputs, **kwargs)
    config.validate_features()
    assert set(config.input_features) == {PC, STATE}
    policy = policy_cls(config).eval()
    obs = observation()  # no teacher keys
    for _ in range(config.n_action_steps + 1):  # crosses a chunk boundary
        action = policy.select_action(dict(obs))
        assert action.shape == (1, ACTION_DIM) and torch.isfinite(action).all()
    chunk = policy.predict_action_chunk({PC: obs[PC][:, None].repeat(1, 2, 1, 1), STATE: obs[STATE][:, None]
                                         .repeat(1, 2, 1)})
    assert chunk.shape == (1, config.n_action_steps, ACTION_DIM)
    full = policy.generate_actions(synthetic_batch(b=3, teacher=False))
    assert full.shape == (3, 16, ACTION_DIM)


def test_afar_training_without_teacher_keys_raises():
    policy = make_afar().train()
    with pytest.raises(KeyError, match="observation.teacher.z0"):
        policy.forward(synthetic_batch(teacher=False))
    # Evaluation-mode loss (validation without teacher data) skips the relational terms.
    loss, info = policy.eval().forward(synthetic_batch(teacher=False))
    assert torch.isfinite(loss) and "loss_cur" not in info
    # Ablation with both relational losses off needs no teacher.
    policy = make_afar(use_current_relation_loss=False, use_future_evolution_loss=False).train()
    loss, _ = policy.forward(synthetic_batch(teacher=False))
    assert torch.isfinite(loss)


def test_presets_and_overrides():
    paper = AfarConfig(preset="paper", device="cpu")
    assert (paper.dit_hidden_dim, paper.dit_num_layers, paper.dit_num_heads) == (768, 12, 8)
    assert paper.point_encoder_hidden_dims == (64, 128, 256, 512) and paper.time_embed_hidden_dim == 512
    assert (paper.wqf_hidden_dim, paper.wqf_num_blocks, paper.wqf_num_heads, paper.relation_num_points) == (
        128, 2, 4, 0)
    cpu = AfarConfig(preset="cpu", device="cpu", dit_num_layers=2, wqf_num_blocks=2)
    assert (cpu.dit_hidden_dim, cpu.dit_num_layers, cpu.wqf_num_blocks, cpu.wqf_hidden_dim) == (192, 2, 2, 64)
    assert ManiFlowConfig(device="cpu").preset == "paper" and not ManiFlowConfig(device="cpu").push_to_hub
    with pytest.raises(ValueError, match="preset"):
        ManiFlowConfig(preset="huge", device="cpu")
    with pytest.raises(ValueError, match="n_action_steps"):
        ManiFlowConfig(device="cpu", n_action_steps=16)  # > horizon - n_obs_steps + 1
    assert ManiFlowConfig(device="cpu").action_delta_indices == list(range(-1, 15))
    assert ManiFlowConfig(device="cpu").observation_delta_indices == [-1, 0]


@dataclasses.dataclass
class _Cli:
    policy: PreTrainedConfig | None = None


def test_cli_parsing_like_lerobot_train():
    args = ["--policy.type=afar", "--policy.preset=cpu", "--policy.device=cpu", "--policy.dit_num_layers=3",
            "--policy.use_fusion=false", "--policy.point_encoder_hidden_dims=[32,64]"]
    cfg = draccus.parse(_Cli, args=args).policy
    assert type(cfg) is AfarConfig and cfg.type == "afar"
    assert (cfg.dit_hidden_dim, cfg.dit_num_layers, cfg.use_fusion) == (192, 3, False)
    assert cfg.point_encoder_hidden_dims == (32, 64)


def test_validate_features_requires_point_cloud_and_state():
    inputs, outputs = features()
    for missing in (PC, STATE):
        cfg = ManiFlowConfig(input_features={k: v for k, v in inputs.items() if k != missing},
                             output_features=outputs, **TINY)
        with pytest.raises(ValueError, match=missing):
            cfg.validate_features()


@pytest.mark.parametrize(
    "flags",
    [dict(use_fusion=False), dict(use_future_evolution_loss=False), dict(use_current_relation_loss=False),
     dict(relation_num_points=8)],
    ids=["no_fusion", "no_evo", "no_cur", "anchor_subset"],
)
def test_afar_ablations_train(flags):
    torch.manual_seed(0)
    policy = make_afar(**flags).train()
    loss, info = policy.forward(synthetic_batch())
    loss.backward()
    assert torch.isfinite(loss)
    if not flags.get("use_fusion", True):
        assert policy.model.fusion_gate.grad is None
    policy.eval()
    assert policy.select_action(observation()).shape == (1, ACTION_DIM)


# (e)
# -----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_save_and_load_pretrained(make, tmp_path):
    torch.manual_seed(0)
    policy = make()
    randomize_zero_init(policy)
    if isinstance(policy, AfarPolicy):
        with torch.no_grad():
            policy.ema_model.fusion_gate.fill_(0.5)
    policy.ema_step.fill_(7)
    policy.eval()
    policy.save_pretrained(tmp_path)
    loaded = type(policy).from_pretrained(tmp_path)
    assert type(loaded.config) is type(policy.config) and loaded.config.dit_hidden_dim == 32
    assert int(loaded.ema_step) == 7
    noise = torch.randn(1, 16, ACTION_DIM, generator=torch.Generator().manual_seed(5))
    obs = observation()
    torch.testing.assert_close(loaded.select_action(dict(obs), noise=noise),
                               policy.select_action(dict(obs), noise=noise), rtol=0, atol=0)
    # Seeded generator instead of explicit noise.
    loaded.reset()
    policy.reset()
    a1 = policy.select_action(dict(obs), generator=torch.Generator().manual_seed(9))
    a2 = loaded.select_action(dict(obs), generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(a1, a2, rtol=0, atol=0)


# (f)
# -----------------------------------------------------------------------------------------------------------


def test_ema_update_follows_decay_schedule():
    torch.manual_seed(0)
    policy = make_maniflow().train()
    assert policy.ema_decay(0) == 0.0
    assert policy.ema_decay(1) == pytest.approx(1 - 2**-0.75)
    assert policy.ema_decay(10**9) == pytest.approx(0.9999)
    opt = torch.optim.Adam(policy.get_optim_params(), lr=1e-2)
    assert not any(p.requires_grad for p in policy.ema_model.parameters())
    assert not policy.ema_model.training

    def step():
        loss, _ = policy.forward(synthetic_batch(teacher=False))
        opt.zero_grad()
        loss.backward()
        opt.step()

    step()
    policy.update()  # k = 0: decay 0, the EMA copy becomes the online model
    for pe, p in zip(policy.ema_model.parameters(), policy.model.parameters(), strict=True):
        torch.testing.assert_close(pe, p)
    for _ in range(2):
        step()
        k = int(policy.ema_step)
        d = policy.ema_decay(k)
        before = [pe.clone() for pe in policy.ema_model.parameters()]
        online = [p.detach().clone() for p in policy.model.parameters()]
        policy.update()
        moved = 0
        for pe, b, p in zip(policy.ema_model.parameters(), before, online, strict=True):
            torch.testing.assert_close(pe, d * b + (1 - d) * p, rtol=1e-5, atol=1e-7)
            moved += int(not torch.equal(b, p))
            # Toward the online weights, never past them.
            assert torch.all((pe - p).abs() <= (b - p).abs() + 1e-7)
        assert moved > 0
    assert int(policy.ema_step) == 3
    # policy.train() keeps the EMA copy in eval mode (no dropout in the consistency teacher).
    policy.train()
    assert not policy.ema_model.training


def test_inference_modulation_cache_is_exact_and_invalidated():
    torch.manual_seed(0)
    policy = make_maniflow(clip_actions=False, binary_action_dims=()).eval()  # compares raw Euler samples
    randomize_zero_init(policy)
    model = policy.ema_model
    batch = synthetic_batch(b=3, teacher=False)
    noise = torch.randn(3, 16, ACTION_DIM)

    def reference(num_steps: int) -> torch.Tensor:  # Euler without any cache
        pc, st = policy._observation_tensors(batch)
        ctx, _ = model.observation_context(pc, st)
        kv, x = model.dit.encode_context(ctx), noise
        for i in range(num_steps):
            t = torch.full((3,), i / num_steps)
            x = x + model.dit(x, t, torch.full((3,), 1 / num_steps), kv) / num_steps
        return x

    with torch.no_grad():
        for steps in (1, 2, 1):
            policy.config.num_inference_steps = steps
            for _ in range(2):  # second call hits the cache
                torch.testing.assert_close(policy.generate_actions(batch, noise=noise), reference(steps))
        with torch.no_grad():  # an in-place weight change is explicit: the changer invalidates the cache
            model.dit.blocks[0].adaln[-1].bias.add_(0.3)
        # stale until told
        assert not torch.allclose(policy.generate_actions(batch, noise=noise), reference(1))
        policy.invalidate_modulation_cache()
        torch.testing.assert_close(policy.generate_actions(batch, noise=noise), reference(1))
        # the policy's own weight changes invalidate it: EMA updates and loading weights
        policy.generate_actions(batch, noise=noise)
        with torch.no_grad():
            policy.model.dit.blocks[0].adaln[-1].bias.add_(0.5)
        policy.update()
        torch.testing.assert_close(policy.generate_actions(batch, noise=noise), reference(1))
        state = {k: v.clone() for k, v in model.state_dict().items()}
        state["dit.blocks.0.adaln.1.bias"] += 0.2
        policy.generate_actions(batch, noise=noise)
        model.load_state_dict(state)
        torch.testing.assert_close(policy.generate_actions(batch, noise=noise), reference(1))


# (g)
# -----------------------------------------------------------------------------------------------------------


def synthetic_stats() -> dict[str, dict[str, torch.Tensor]]:
    return {
        PC: {"min": torch.tensor([-0.5, -0.4, 0.0, 0.0, 0.0, 0.0]),
             "max": torch.tensor([0.5, 0.4, 0.6, 1.0, 1.0, 1.0])},
        STATE: {"min": -torch.ones(STATE_DIM) * 2, "max": torch.ones(STATE_DIM) * 2},
        ACT: {"min": -torch.ones(ACTION_DIM) * 3, "max": torch.ones(ACTION_DIM) * 3},
        Z0: {"min": torch.zeros(TEACHER_DIM), "max": torch.ones(TEACHER_DIM)},
        ZF: {"min": torch.zeros(TEACHER_DIM), "max": torch.ones(TEACHER_DIM)},
    }


@pytest.mark.parametrize("name", ["maniflow", "afar"])
def test_lerobot_factory_and_processors(name, tmp_path):
    from lerobot.policies.factory import (
        get_policy_class,
        make_policy,
        make_policy_config,
        make_pre_post_processors,
    )

    assert {"maniflow", "afar"} <= set(PreTrainedConfig.get_known_choices())
    assert get_policy_class(name) is {"maniflow": ManiFlowPolicy, "afar": AfarPolicy}[name]

    # make_policy from dataset-like metadata that carries the teacher features (typed STATE by LeRobot).
    tiny = TINY_AFAR if name == "afar" else TINY
    cfg = make_policy_config(name, **tiny)
    ds_features = {
        PC: {"dtype": "float32", "shape": (N_POINTS, 6), "names": None},
        STATE: {"dtype": "float32", "shape": (STATE_DIM,), "names": None},
        ACT: {"dtype": "float32", "shape": (ACTION_DIM,), "names": None},
        Z0: {"dtype": "float32", "shape": (N_POINTS, TEACHER_DIM), "names": None},
        ZF: {"dtype": "float32", "shape": (N_POINTS, TEACHER_DIM), "names": None},
    }
    stats = synthetic_stats()
    meta = SimpleNamespace(features=ds_features, stats=stats)
    policy = make_policy(cfg, ds_meta=meta)
    assert set(cfg.input_features) == {PC, STATE} and set(cfg.output_features) == {ACT}
    assert cfg.get_scheduler_preset().num_warmup_steps == 500
    opt_cfg = cfg.get_optimizer_preset()
    assert (opt_cfg.lr, tuple(opt_cfg.betas), opt_cfg.weight_decay) == (1e-4, (0.9, 0.95), 1e-3)

    opt = opt_cfg.build(policy.get_optim_params())
    sched = cfg.get_scheduler_preset().build(opt, num_training_steps=1000)
    assert sched.get_last_lr()[0] == 0.0  # linear warm-up from 0

    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    raw = synthetic_batch(b=4)
    raw[PC][..., :3] *= 0.4
    raw[PC][..., 3:] = raw[PC][..., 3:].abs()
    raw[ACT] = raw[ACT] * 3
    out = pre(copy.deepcopy(raw))
    assert out[PC].shape == (4, 2, N_POINTS, 6)
    lo, hi = stats[PC]["min"], stats[PC]["max"]
    torch.testing.assert_close(out[PC], 2 * (raw[PC] - lo) / (hi - lo) - 1)
    torch.testing.assert_close(out[STATE], raw[STATE] / 2)
    torch.testing.assert_close(out[ACT], raw[ACT] / 3)
    torch.testing.assert_close(out[Z0], raw[Z0])  # teacher targets pass through unnormalised
    policy.train()
    loss, _ = policy.forward(out)
    assert torch.isfinite(loss)

    # Saved processors reload through LeRobot's registry (as lerobot-eval does) and normalise identically.
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    pre2, _ = make_pre_post_processors(cfg, pretrained_path=str(tmp_path))
    torch.testing.assert_close(pre2(copy.deepcopy(raw))[PC], out[PC])

    # Eval path: single-step observation without teacher keys -> action in dataset units.
    policy.eval()
    obs = pre({PC: raw[PC][:1, -1], STATE: raw[STATE][:1, -1]})
    action = post(policy.select_action(obs))
    assert action.shape == (1, ACTION_DIM)
    assert action.abs().max() <= 3 * 5  # unnormalised from [-1, 1]-scale outputs


@pytest.mark.parametrize("name", ["maniflow", "afar"])
def test_bavo_flat_dataset_layout_and_env_layout(name):
    """BAVO datasets store (N, C) arrays flat with tiled per-channel stats; the env returns (N, 6) clouds."""
    from lerobot.policies.factory import make_policy, make_policy_config, make_pre_post_processors

    from lerobot_bavo.datasets import schema

    ds_features = schema.build_features(
        schema.ObservationSettings(32, 32, n_points=N_POINTS), use_videos=True
    )
    assert tuple(ds_features[PC]["shape"]) == (N_POINTS * 6,)
    g = torch.Generator().manual_seed(0)
    cloud = torch.rand(500, N_POINTS, 6, generator=g) * torch.tensor([1.0, 0.8, 0.6, 1, 1, 1])
    stats = {
        PC: schema.tile_channel_stats(schema.channel_stats(cloud.numpy()), N_POINTS),
        STATE: schema.channel_stats(torch.rand(500, STATE_DIM, generator=g).numpy() * 4 - 2),
        ACT: schema.channel_stats(torch.rand(500, ACTION_DIM, generator=g).numpy() * 4 - 2),
    }
    cfg = make_policy_config(name, **(TINY_AFAR if name == "afar" else TINY))
    policy = make_policy(cfg, ds_meta=SimpleNamespace(features=ds_features, stats=stats))
    assert not any(k.startswith("observation.teacher") for k in cfg.input_features)
    assert cfg.num_points == N_POINTS
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)

    # Training batch in the dataset layout (with the time axis LeRobot adds to every observation key).
    b, to = 4, 2
    raw = {
        PC: cloud[:b * to].reshape(b, to, N_POINTS * 6),
        STATE: torch.rand(b, to, STATE_DIM, generator=g),
        ACT: torch.rand(b, 16, ACTION_DIM, generator=g),
        schema.TEACHER_Z0: torch.randn(b, to, N_POINTS * 3, generator=g),
        schema.TEACHER_ZF: torch.randn(b, to, N_POINTS * 3, generator=g),
        schema.TEACHER_VALID: torch.tensor([1.0, 1.0, 0.0, 1.0]).reshape(b, 1, 1).expand(b, to, 1),
        schema.TEACHER_VISIBLE: torch.ones(b, to, N_POINTS),
    }
    batch = pre(copy.deepcopy(raw))
    lo = torch.as_tensor(stats[PC]["min"][:6], dtype=torch.float32)
    hi = torch.as_tensor(stats[PC]["max"][:6], dtype=torch.float32)
    per_channel = 2 * (raw[PC].reshape(b, to, N_POINTS, 6) - lo) / (hi - lo) - 1
    torch.testing.assert_close(batch[PC].reshape(b, to, N_POINTS, 6), per_channel)
    policy.train()
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss)
    if name == "afar":
        assert info["teacher_valid"] == 3

    # Evaluation: the env's (B, N, 6) cloud and (B, N, 2) pixels go through the same preprocessor.
    policy.eval()
    env_obs = {PC: cloud[:1, :, :].clone(), STATE: raw[STATE][:1, -1],
               schema.OBS_POINT_PIXELS: torch.rand(1, N_POINTS, 2) * 32}
    obs = pre(env_obs)
    noise = torch.randn(1, 16, ACTION_DIM, generator=g)
    a_env = post(policy.select_action(obs, noise=noise))
    # Same observation in the flat layout: same action.
    policy.reset()
    flat = pre({PC: cloud[:1].reshape(1, -1), STATE: raw[STATE][:1, -1]})
    torch.testing.assert_close(post(policy.select_action(flat, noise=noise)), a_env)
    assert a_env.shape == (1, ACTION_DIM)


# (h) privileged-state mode
# -------------------------------------------------------------------------------------

ENV = "observation.environment_state"


def test_privileged_state_maniflow_tokens_objects_trains_and_acts():
    """With object poses instead of a point cloud, ManiFlow makes one token per object (7-d pose) and keeps
    the DiT-X / flow objective; A-FAR refuses (its relations are point-aligned)."""
    inputs = {
        ENV: PolicyFeature(FeatureType.ENV, (14,)),
        STATE: PolicyFeature(FeatureType.STATE, (STATE_DIM,)),
    }
    outputs = {ACT: PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))}
    cfg = ManiFlowConfig(input_features=dict(inputs), output_features=outputs, **TINY)
    assert (cfg.observation_key, cfg.num_points, cfg.token_channels) == (ENV, 2, 7)
    torch.manual_seed(0)
    policy = ManiFlowPolicy(cfg)
    assert policy.model.point_encoder.mlp[0].in_features == 7
    g = torch.Generator().manual_seed(0)
    batch = {
        ENV: torch.rand(8, 2, 14, generator=g) * 2 - 1,
        STATE: torch.rand(8, 2, STATE_DIM, generator=g) * 2 - 1,
    }
    # the chunk depends on the object poses only: the model must read them to fit
    batch[ACT] = batch[ENV][:, -1, None, :].repeat(1, 16, 2)[..., :ACTION_DIM]
    start, end, _ = fit(policy, batch, 150)
    assert end < 0.3 * start, (start, end)
    policy.eval()
    policy.reset()
    action = policy.select_action({ENV: batch[ENV][:1, -1], STATE: batch[STATE][:1, -1]})
    assert action.shape == (1, ACTION_DIM) and torch.isfinite(action).all()
    with pytest.raises(ValueError, match="point_cloud"):
        AfarPolicy(AfarConfig(input_features=dict(inputs), output_features=outputs, **TINY_AFAR))
    with pytest.raises(ValueError, match="ENV feature"):
        ManiFlowConfig(input_features={**inputs, ENV: PolicyFeature(FeatureType.STATE, (14,))},
                       output_features=outputs, **TINY).validate_features()


def test_point_cloud_stats_reduce_to_per_channel_whatever_the_layout():
    """Element-wise (per-slot) stats, as LeRobot's tools rebuild them after an edit, normalise exactly like
    the per-channel stats computed from all points; mean/std combine exactly for equal slot counts."""
    from lerobot_bavo.policies.maniflow.processor_maniflow import per_channel_point_stats

    g = torch.Generator().manual_seed(0)
    frames = torch.rand(50, N_POINTS, 6, generator=g, dtype=torch.float64) * torch.linspace(0.5, 2, 6)
    per_slot = {"min": frames.amin(0).reshape(-1), "max": frames.amax(0).reshape(-1),
                "mean": frames.mean(0).reshape(-1), "std": frames.std(0, unbiased=False).reshape(-1),
                "count": torch.tensor([50])}
    out = per_channel_point_stats(per_slot, N_POINTS, 6)
    flat = frames.reshape(-1, 6)
    torch.testing.assert_close(out["min"].reshape(N_POINTS, 6), flat.amin(0).expand(N_POINTS, 6))
    torch.testing.assert_close(out["max"].reshape(N_POINTS, 6), flat.amax(0).expand(N_POINTS, 6))
    torch.testing.assert_close(out["mean"].reshape(N_POINTS, 6), flat.mean(0).expand(N_POINTS, 6))
    torch.testing.assert_close(
        out["std"].reshape(N_POINTS, 6), flat.std(0, unbiased=False).expand(N_POINTS, 6)
    )
    assert out["count"].tolist() == [50]
    # already-tiled stats are a fixed point
    again = per_channel_point_stats(out, N_POINTS, 6)
    for k in ("min", "max", "mean", "std"):
        torch.testing.assert_close(again[k], out[k])


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_points_per_step_reads_exactly_the_fps_prefix(make):
    """`points_per_step` = M: the policy reads the first M of the N (FPS-ordered) points and nothing else; the
    teacher features are cut to the same points, so A-FAR's relational loss stays point-aligned."""
    policy = make(points_per_step=8)
    assert policy.config.num_points == N_POINTS and policy.config.num_tokens == 8
    assert policy.model.dit.context_pos.shape[1] == 2 * 8
    randomize_zero_init(policy)
    policy.eval()
    batch = synthetic_batch(b=2)
    other = copy.deepcopy(batch)
    other[PC][:, :, 8:] = torch.rand_like(other[PC][:, :, 8:])  # points the policy must not read
    noise = torch.randn(2, 16, ACTION_DIM, generator=torch.Generator().manual_seed(0))
    a = policy.generate_actions(batch, noise=noise)
    torch.testing.assert_close(a, policy.generate_actions(other, noise=noise))
    other[PC][:, :, 3] += 0.5  # a point it does read
    assert not torch.allclose(a, policy.generate_actions(other, noise=noise))
    policy.train()
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss)
    with pytest.raises(ValueError, match="exceeds"):
        make(points_per_step=N_POINTS + 1)


def test_afar_fusion_gate_has_its_own_optimizer_group():
    """gamma is optimised without weight decay at `fusion_gate_lr_scale` x lr; everything else as
    configured."""
    policy = make_afar(fusion_gate_lr_scale=10.0)
    groups = policy.get_optim_params()
    opt = policy.config.get_optimizer_preset().build(groups)
    gate_group = next(g for g in opt.param_groups if any(p is policy.model.fusion_gate for p in g["params"]))
    assert gate_group["weight_decay"] == 0.0 and gate_group["lr"] == pytest.approx(
        10 * policy.config.optimizer_lr
    )
    others = [g for g in opt.param_groups if g is not gate_group]
    assert len(others) == 1 and others[0]["weight_decay"] == policy.config.optimizer_weight_decay
    n_params = sum(p.numel() for g in opt.param_groups for p in g["params"])
    assert n_params == sum(p.numel() for p in policy.model.parameters())
    assert (
        AfarConfig(preset="paper").fusion_gate_lr_scale == 1.0
        and AfarConfig(preset="cpu_fast").fusion_gate_lr_scale == 10.0
    )


def test_gripper_dims_are_snapped_to_open_or_closed_and_nothing_else_changes():
    """binary_action_dims (default: BAVO's grippers, 6 and 13) snaps each sampled normalised gripper command
    to the nearer end of its range, -1 (closed) or +1 (open); every other dimension is the plain sample.
    Checked against the same weights and noise with snapping off, and by hand on a small tensor."""
    from lerobot_bavo.policies.maniflow.modeling_maniflow import snap_binary_dims
    from lerobot_bavo.sim.constants import GRIPPER_INDICES

    x = torch.tensor([[0.3, -0.2, 0.0, -1.0, 0.95]])
    torch.testing.assert_close(snap_binary_dims(x, (0, 1, 2)), torch.tensor([[1.0, -1.0, -1.0, -1.0, 0.95]]))
    assert snap_binary_dims(x, ()) is x
    torch.manual_seed(0)
    snapped, plain = make_maniflow(), make_maniflow(binary_action_dims=())
    assert snapped.config.binary_action_dims == GRIPPER_INDICES == (6, 13)
    randomize_zero_init(snapped, seed=0)
    plain.load_state_dict(snapped.state_dict())
    batch = synthetic_batch(b=4, teacher=False)
    noise = torch.randn(4, 16, ACTION_DIM, generator=torch.Generator().manual_seed(3))
    a, b = snapped.generate_actions(batch, noise=noise), plain.generate_actions(batch, noise=noise)
    grip = list(GRIPPER_INDICES)
    torch.testing.assert_close(a[..., grip], torch.where(b[..., grip] > 0, 1.0, -1.0))
    others = [d for d in range(ACTION_DIM) if d not in grip]
    torch.testing.assert_close(a[..., others], b[..., others], rtol=0, atol=0)
    assert make_afar().config.binary_action_dims == (6, 13)  # A-FAR inherits it
    with pytest.raises(ValueError, match="binary_action_dims"):
        make_maniflow(binary_action_dims=(21,))
    with pytest.raises(ValueError, match="binary_action_dims"):
        make_maniflow(clip_actions=False,
                      normalization_mapping={"VISUAL": "IDENTITY", "STATE": "MIN_MAX", "ACTION": "MEAN_STD"})


def test_gripper_dims_snap_to_the_nearest_held_level_when_levels_are_given():
    """binary_action_levels adds part-open levels (Drawer Stowing's 0.45 and 0.7, normalised -0.1 and 0.4):
    each snapped dimension goes to the nearest level, by hand; other dimensions and the default two-level
    behaviour are unchanged; levels must be increasing, distinct and inside [-1, 1]."""
    from lerobot_bavo.policies.maniflow.modeling_maniflow import snap_binary_dims

    levels = (-1.0, -0.1, 0.4, 1.0)
    x = torch.tensor([[-0.6, -0.5, 0.1, 0.2, 0.71, 0.69, 0.3]])
    # midpoints between levels: -0.55, 0.15, 0.7; dimension 6 is not snapped
    expected = torch.tensor([[-1.0, -0.1, -0.1, 0.4, 1.0, 0.4, 0.3]])
    torch.testing.assert_close(snap_binary_dims(x, tuple(range(6)), levels), expected)
    torch.testing.assert_close(snap_binary_dims(x, tuple(range(6)), (-1.0, 1.0)),
                               snap_binary_dims(x, tuple(range(6))))
    torch.manual_seed(0)
    policy = make_maniflow(binary_action_levels=[-1, -0.1, 0.4, 1])
    assert policy.config.binary_action_levels == levels
    randomize_zero_init(policy, seed=0)
    noise = torch.randn(2, 16, ACTION_DIM, generator=torch.Generator().manual_seed(3))
    grip = policy.generate_actions(synthetic_batch(b=2, teacher=False), noise=noise)[..., [6, 13]]
    assert set(grip.unique().tolist()) <= {torch.tensor(v).item() for v in levels}  # float32 levels
    for bad in ([1.0], [-1.0, 1.0, 0.5], [-1.0, -1.0, 1.0], [-1.5, 1.0]):
        with pytest.raises(ValueError, match="binary_action_levels"):
            make_maniflow(binary_action_levels=bad)


def test_sampled_chunks_are_clipped_to_the_normalised_data_range():
    """A 1-2 step flow sample can leave [-1, 1]; with clip_actions (default) the chunk is clamped there, and
    without it the raw sample comes back unchanged. A large random init makes the raw sample overshoot."""
    torch.manual_seed(0)
    clipped, raw = (
        make_maniflow(binary_action_dims=()),
        make_maniflow(clip_actions=False, binary_action_dims=()),
    )
    randomize_zero_init(clipped, seed=0)
    raw.load_state_dict(clipped.state_dict())
    for p in clipped.ema_model.parameters():
        p.data.mul_(8.0)
    raw.load_state_dict(clipped.state_dict())
    batch = synthetic_batch(b=4, teacher=False)
    noise = torch.randn(4, 16, ACTION_DIM, generator=torch.Generator().manual_seed(3)) * 3
    a_raw = raw.generate_actions(batch, noise=noise)
    a_clip = clipped.generate_actions(batch, noise=noise)
    assert a_raw.abs().max() > 1.0  # the case the clamp exists for
    torch.testing.assert_close(a_clip, a_raw.clamp(-1.0, 1.0))
    with pytest.raises(ValueError, match="clip_actions"):
        make_maniflow(normalization_mapping={"VISUAL": "IDENTITY", "STATE": "MIN_MAX", "ACTION": "MEAN_STD"})


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_noise_scale_scales_the_starting_noise_only(make):
    """`noise_scale` s samples exactly what an explicit start s * z gives, z being the standard draw the same
    generator makes (so 1 is the old sampler, bit for bit); at 0 the chunk no longer depends on the draw."""
    torch.manual_seed(0)
    scaled, plain = make(noise_scale=0.5, binary_action_dims=()), make(binary_action_dims=())
    randomize_zero_init(scaled, seed=0)
    plain.load_state_dict(scaled.state_dict())
    batch = synthetic_batch(b=2, teacher=False)
    z = torch.randn(2, 16, ACTION_DIM, generator=torch.Generator().manual_seed(7))
    drawn = scaled.generate_actions(batch, generator=torch.Generator().manual_seed(7))
    torch.testing.assert_close(drawn, plain.generate_actions(batch, noise=0.5 * z), rtol=0, atol=0)
    torch.testing.assert_close(plain.generate_actions(batch, generator=torch.Generator().manual_seed(7)),
                               plain.generate_actions(batch, noise=z), rtol=0, atol=0)
    assert not torch.allclose(drawn, plain.generate_actions(batch, noise=z))
    scaled.config.noise_scale = 0.0
    a = scaled.generate_actions(batch, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(a, scaled.generate_actions(batch, generator=torch.Generator().manual_seed(2)),
                               rtol=0, atol=0)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="noise_scale"):
            make(noise_scale=bad)


# ignored_state_dims (issue 27's "state without the camera-arm joints" variant)
# -----------------------------------------------------------------------------------------------------------

CAMERA_ARM_DIMS = tuple(range(CAMERA_ARM.start, CAMERA_ARM.stop))  # 14-20


@pytest.mark.parametrize("make", [make_maniflow, make_afar], ids=["maniflow", "afar"])
def test_ignored_state_dims_carry_no_information(make, tmp_path):
    torch.manual_seed(0)
    policy = make(ignored_state_dims=CAMERA_ARM_DIMS).eval()
    randomize_zero_init(policy)
    batch = synthetic_batch(b=3, teacher=False)
    noise = torch.randn(3, 16, ACTION_DIM, generator=torch.Generator().manual_seed(1))
    moved = dict(batch)
    moved[STATE] = batch[STATE].clone()
    moved[STATE][..., 14:21] = torch.rand(3, 2, 7) * 2 - 1  # another camera-arm pose
    reference = policy.generate_actions(batch, noise=noise)
    torch.testing.assert_close(policy.generate_actions(moved, noise=noise), reference, rtol=0, atol=0)
    arm = dict(batch)
    arm[STATE] = batch[STATE].clone()
    arm[STATE][..., 0] += 0.5  # a manipulator joint is still read
    assert not torch.equal(policy.generate_actions(arm, noise=noise), reference)
    # the training loss ignores them too (same sampled noise and times)
    policy.train()
    train_batch, train_moved = synthetic_batch(b=3), synthetic_batch(b=3)
    train_moved[STATE][..., 14:21] = 0.9
    torch.manual_seed(3)
    loss, _ = policy.forward(train_batch)
    torch.manual_seed(3)
    loss_moved, _ = policy.forward(train_moved)
    torch.testing.assert_close(loss_moved, loss, rtol=0, atol=0)
    # the setting travels with a checkpoint
    policy.eval()
    policy.save_pretrained(tmp_path)
    loaded = type(policy).from_pretrained(tmp_path)
    assert tuple(loaded.config.ignored_state_dims) == CAMERA_ARM_DIMS
    torch.testing.assert_close(loaded.generate_actions(moved, noise=noise), reference, rtol=0, atol=0)


@pytest.mark.parametrize("dims", [(21,), (-1,), (3, 3)])
def test_ignored_state_dims_outside_the_state_or_repeated_are_refused(dims):
    with pytest.raises(ValueError, match="ignored_state_dims"):
        make_maniflow(ignored_state_dims=dims)
