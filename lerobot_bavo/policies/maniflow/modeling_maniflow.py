"""ManiFlow: per-point tokens + DiT-X trained with consistency flow matching (arXiv 2509.01819).

Layout (LeRobot habit): `ManiFlowPolicy` is a thin `PreTrainedPolicy` holding the queues, the loss and the EMA
copy; `ManiFlowModel` is the network (point encoder, state MLP, DiT-X).

Conventions (one throughout): flow time t = 0 is Gaussian noise, t = 1 is data; x_t = (1 - t) x0 + t x1 and
the network predicts the velocity x1 - x0 given (x_t, t, dt), dt being the step size (0 for plain flow
matching).
"""

from __future__ import annotations

import copy
import math
from collections import deque

import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION, OBS_STATE
from torch import Tensor, nn

from lerobot_bavo.features import (
    TEACHER_OCCLUDER,
    TEACHER_RECOVERING,
    TEACHER_SAMPLE_WEIGHT,
    TEACHER_VISIBLE,
    TEACHER_Z0,
    TEACHER_ZF,
    unflatten_points,
)
from lerobot_bavo.policies.augment import occluder_dropout
from lerobot_bavo.policies.ensemble import ChunkEnsemble
from lerobot_bavo.policies.heap import keep_freed_heap
from lerobot_bavo.policies.relative import as_index, to_absolute, to_relative
from lerobot_bavo.policies.smoothing import ActionLowPass
from lerobot_bavo.policies.switches import hold_short_switches

from .configuration_maniflow import ManiFlowConfig

# Teacher targets with one entry per cloud point: reordered with the cloud by `occluder_dropout`.
POINT_ALIGNED_TEACHER_KEYS = (TEACHER_Z0, TEACHER_ZF, TEACHER_VISIBLE)

# ------------------------------------------------------------------------------------------------------------
# Observation encoder.
# ------------------------------------------------------------------------------------------------------------


class PointEncoder(nn.Module):
    """DP3/ManiFlow PointNet without pooling: (Linear + LayerNorm + ReLU) per hidden width, then Linear +
    LayerNorm to `out_dim`. Applied to each point independently, so it yields one token per point."""

    def __init__(self, in_channels: int, hidden_dims: tuple[int, ...], out_dim: int):
        super().__init__()
        layers: list[nn.Module] = []
        c = in_channels
        for h in hidden_dims:
            layers += [nn.Linear(c, h), nn.LayerNorm(h), nn.ReLU()]
            c = h
        self.mlp = nn.Sequential(*layers)
        self.proj = nn.Sequential(nn.Linear(c, out_dim), nn.LayerNorm(out_dim))

    def forward(self, points: Tensor) -> Tensor:
        """(..., N, C) -> (..., N, out_dim)."""
        return self.proj(self.mlp(points))


class StateEncoder(nn.Module):
    """S -> d -> ReLU -> d."""

    def __init__(self, state_dim: int, out_dim: int):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(state_dim, out_dim), nn.ReLU(), nn.Linear(out_dim, out_dim))

    def forward(self, state: Tensor) -> Tensor:
        return self.net(state)


# ------------------------------------------------------------------------------------------------------------
# DiT-X.
# ------------------------------------------------------------------------------------------------------------


def sinusoidal_embedding(t: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """(B,) raw times -> (B, dim) [cos, sin] features."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    if dim % 2:
        emb = F.pad(emb, (0, 1))
    return emb


class TimeEmbedding(nn.Module):
    """Sinusoid(freq_dim) -> Linear -> Mish -> Linear(out_dim)."""

    def __init__(self, freq_dim: int, hidden_dim: int, out_dim: int):
        super().__init__()
        self.freq_dim = freq_dim
        self.mlp = nn.Sequential(nn.Linear(freq_dim, hidden_dim), nn.Mish(), nn.Linear(hidden_dim, out_dim))

    def forward(self, t: Tensor) -> Tensor:
        return self.mlp(sinusoidal_embedding(t, self.freq_dim).to(self.mlp[0].weight.dtype))


def _split_heads(x: Tensor, heads: int) -> Tensor:
    b, n, d = x.shape
    return x.view(b, n, heads, d // heads).transpose(1, 2)  # (B, h, N, d/h)


def _merge_heads(x: Tensor) -> Tensor:
    b, h, n, d = x.shape
    return x.transpose(1, 2).reshape(b, n, h * d)


class SelfAttention(nn.Module):
    def __init__(self, dim: int, heads: int, dropout: float):
        super().__init__()
        self.heads = heads
        self.dropout = dropout
        self.qkv = nn.Linear(dim, 3 * dim)
        self.out = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        q, k, v = (_split_heads(z, self.heads) for z in self.qkv(x).chunk(3, dim=-1))
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.out(_merge_heads(y))


class MemoryAttention(torch.autograd.Function):
    """softmax(q_memory memory^T + q_bias) memory, (B, M, Dm) from q_bias (B, M, 1), q_memory (B, M, Dm) and
    memory (B, L, Dm): the core of `CrossAttention.attend_memory` without attention dropout, with its
    gradients written out.

    Why: the memory enters twice (scores and values), and autograd's gradient of the scores' use comes out
    transposed, (B, Dm, L) laid out as (B, L, Dm), so adding the two costs a strided pass over (B, L, Dm);
    here the second product is accumulated into the first by the matrix multiply itself (`baddbmm_`). The
    forward pass is the same operations; the gradients are autograd's up to rounding (the softmax's is
    written out).
    """

    @staticmethod
    def forward(ctx, q_bias: Tensor, q_memory: Tensor, memory: Tensor) -> Tensor:
        attn = torch.baddbmm(q_bias, q_memory, memory.transpose(1, 2)).softmax(dim=-1)  # (B, M, L)
        ctx.save_for_backward(q_memory, memory, attn)
        return torch.bmm(attn, memory)

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        q_memory, memory, attn = ctx.saved_tensors
        grad_attn = torch.bmm(grad_out, memory.transpose(1, 2))
        # softmax: attn * (g - sum_l g_l attn_l)
        weighted = attn * grad_attn
        grad_scores = torch.addcmul(weighted, attn, weighted.sum(dim=-1, keepdim=True), value=-1.0)
        grad_memory = torch.bmm(attn.transpose(1, 2), grad_out)  # (B, L, Dm): values' use, then scores'
        grad_memory.baddbmm_(grad_scores.transpose(1, 2), q_memory)
        return grad_scores.sum(dim=-1, keepdim=True), torch.bmm(grad_scores, memory), grad_memory


class CrossAttention(nn.Module):
    """Queries from x, keys/values from a memory. `kv(memory)` can be computed once and reused (the
    observation context is the same for every flow step)."""

    def __init__(self, dim: int, heads: int, dropout: float, memory_dim: int | None = None):
        super().__init__()
        self.heads = heads
        self.dropout = dropout
        self.q = nn.Linear(dim, dim)
        self.kv_proj = nn.Linear(memory_dim or dim, 2 * dim)
        self.out = nn.Linear(dim, dim)

    def kv(self, memory: Tensor) -> tuple[Tensor, Tensor]:
        k, v = self.kv_proj(memory).chunk(2, dim=-1)
        # Contiguous once here rather than inside every attention call that reuses them.
        return _split_heads(k, self.heads).contiguous(), _split_heads(v, self.heads).contiguous()

    def forward(self, x: Tensor, kv: tuple[Tensor, Tensor]) -> Tensor:
        q = _split_heads(self.q(x), self.heads)
        y = F.scaled_dot_product_attention(q, kv[0], kv[1], dropout_p=self.dropout if self.training else 0.0)
        return self.out(_merge_heads(y))

    def attend_memory(self, x: Tensor, memory: Tensor) -> Tensor:
        """`forward(x, self.kv(memory))` for x (B, H, D) and memory (B, L, Dm), without computing the memory's
        keys and values.

        Why: the score of a query q against the key W_k m + b_k is (W_k^T q) . m + q . b_k, and the
        attention-weighted sum of the values W_v m + b_v is (A m) W_v^T + b_v (A's rows sum to 1; with
        attention dropout they are summed and weight b_v). So the H queries are taken into the memory's space
        instead of the L memory rows into key and value space: per sample and head O(H D Dm + H L Dm)
        multiply-adds instead of O(L D Dm + H L D / heads), fewer when H is small next to L (DiT-X: 16 action
        tokens attend to To * N context tokens). Used where the keys and values would serve one call only
        (training); inference reuses `kv(memory)` over its flow steps.
        """
        b, h_len, _ = x.shape
        heads = self.heads
        # (heads, D/heads, Dm) each
        w_k, w_v = self.kv_proj.weight.view(2, heads, -1, memory.shape[-1]).unbind(0)
        b_k, b_v = self.kv_proj.bias.view(2, heads, -1).unbind(0)  # (heads, D/heads) each
        q = self.q(x).view(b * h_len, heads, -1) * w_k.shape[1] ** -0.5  # SDPA's 1/sqrt(head width)
        # Per head, the (B H) queries times W_k: one batched product over the heads (fewer operations than
        # the equivalent einsum), then rows ordered (head, query) per sample.
        q_memory = torch.bmm(q.transpose(0, 1), w_k).view(heads, b, h_len, -1)
        q_memory = q_memory.transpose(0, 1).reshape(b, heads * h_len, -1)  # (B, heads * H, Dm)
        q_bias = (q * b_k).sum(dim=-1).view(b, h_len, heads).transpose(1, 2).reshape(b, heads * h_len, 1)
        dropout = self.training and self.dropout > 0
        # MemoryAttention computes in its inputs' dtype: not under autocast
        if not dropout and not torch.is_autocast_enabled(memory.device.type):
            attended = MemoryAttention.apply(q_bias, q_memory, memory)  # (B, heads * H, Dm)
        else:
            # (B, heads * H, L)
            attn = torch.baddbmm(q_bias, q_memory, memory.transpose(1, 2)).softmax(dim=-1)
            if dropout:
                attn = F.dropout(attn, self.dropout)
            attended = torch.bmm(attn, memory)
        # back per head: (heads, B H, Dm) times W_v^T, then (B, H, heads, D/heads)
        attended = attended.view(b, heads, h_len, -1).transpose(0, 1).reshape(heads, b * h_len, -1)
        if dropout:
            y = torch.bmm(attended, w_v.transpose(1, 2)).view(heads, b, h_len, -1).permute(1, 2, 0, 3)
            y = y + attn.sum(dim=-1).view(b, heads, h_len).transpose(1, 2)[..., None] * b_v
        else:
            y = torch.baddbmm(b_v[:, None], attended, w_v.transpose(1, 2)).view(heads, b, h_len, -1)
            y = y.permute(1, 2, 0, 3)
        return self.out(y.reshape(b, h_len, -1))


def split_modulation(modulation: Tensor) -> tuple[Tensor, ...]:
    """adaln(c) (B, 9 D) -> (shift, 1 + scale, gate) x 3, each (B, 1, D)."""
    sh1, sc1, g1, sh2, sc2, g2, sh3, sc3, g3 = modulation[:, None].chunk(9, dim=-1)
    return sh1, 1 + sc1, g1, sh2, 1 + sc2, g2, sh3, 1 + sc3, g3


class DiTXBlock(nn.Module):
    """AdaLN-Zero block: self-attention over action tokens, cross-attention to the observation context, MLP.
    Shift/scale/gate of each sub-layer come from the (t, dt) conditioning; the modulation Linear is zero-init,
    so every block starts as the identity."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, dropout: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.self_attn = SelfAttention(dim, heads, dropout)
        self.norm2 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.cross_attn = CrossAttention(dim, heads, dropout)
        self.norm3 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(
            nn.Linear(dim, hidden),
            nn.GELU(approximate="tanh"),
            nn.Dropout(dropout),
            nn.Linear(hidden, dim),
            nn.Dropout(dropout),
        )
        self.adaln = nn.Sequential(nn.SiLU(), nn.Linear(dim, 9 * dim))

    def forward(
        self, x: Tensor, modulation: tuple[Tensor, ...], kv: tuple[Tensor, Tensor] | Tensor
    ) -> Tensor:
        """x (B, H, D) action tokens; modulation = split_modulation(adaln(c)), batch B or 1; kv per-head
        context keys/values, or the projected context (B, L, D) itself (`CrossAttention.attend_memory`)."""
        sh1, sc1, g1, sh2, sc2, g2, sh3, sc3, g3 = modulation
        x = torch.addcmul(x, g1, self.self_attn(torch.addcmul(sh1, self.norm1(x), sc1)))
        h = torch.addcmul(sh2, self.norm2(x), sc2)
        x = torch.addcmul(x, g2, self.cross_attn.attend_memory(h, kv) if isinstance(kv, Tensor)
                          else self.cross_attn(h, kv))
        x = torch.addcmul(x, g3, self.mlp(torch.addcmul(sh3, self.norm3(x), sc3)))
        return x


class DiTX(nn.Module):
    """DiT-X velocity network f(x_t, t, dt | context)."""

    def __init__(self, config: ManiFlowConfig, action_dim: int, context_dim: int, context_len: int):
        super().__init__()
        d = config.dit_hidden_dim
        self.action_in = nn.Linear(action_dim, d)
        self.action_pos = nn.Parameter(torch.zeros(1, config.horizon, d))
        self.context_in = nn.Linear(context_dim, d)
        self.context_pos = nn.Parameter(torch.zeros(1, context_len, d))  # zero-init (ManiFlow)
        self.t_embed = TimeEmbedding(config.time_freq_dim, config.time_embed_hidden_dim, d)
        self.dt_embed = TimeEmbedding(config.time_freq_dim, config.time_embed_hidden_dim, d)
        self.cond_proj = nn.Linear(2 * d, d)
        self.blocks = nn.ModuleList(
            DiTXBlock(d, config.dit_num_heads, config.dit_mlp_ratio, config.dropout)
            for _ in range(config.dit_num_layers)
        )
        self.out_norm = nn.RMSNorm(d, eps=1e-6)
        self.out_mlp = nn.Sequential(nn.Linear(d, d), nn.GELU(approximate="tanh"), nn.Linear(d, action_dim))
        self._init_weights()

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)
        nn.init.normal_(self.action_pos, std=0.02)
        for blk in self.blocks:  # AdaLN-Zero
            nn.init.zeros_(blk.adaln[-1].weight)
            nn.init.zeros_(blk.adaln[-1].bias)
        nn.init.zeros_(self.out_mlp[-1].weight)  # zero-init output layer
        nn.init.zeros_(self.out_mlp[-1].bias)

    def encode_context(self, context: Tensor) -> list[tuple[Tensor, Tensor]]:
        """(B, L, context_dim) observation tokens -> per-block cross-attention keys/values."""
        ctx = self.context_in(context) + self.context_pos
        return [blk.cross_attn.kv(ctx) for blk in self.blocks]

    def project_context(self, points: Tensor, states: Tensor) -> Tensor:
        """The projected context context_in(c) + pos (B, To * N, D) of the context c made of point tokens
        `points` (B, To, N, Dp) and state features `states` (B, To, Ds), i.e. of
        `ManiFlowModel.build_context(points, states)`: the state part of context_in is applied once per step
        rather than once per token, and the concatenated (B, To * N, Dp + Ds) context is never written."""
        b, to, n, dp = points.shape
        w_points, w_states = self.context_in.weight[:, :dp], self.context_in.weight[:, dp:]
        per_step = F.linear(states, w_states, self.context_in.bias)[:, :, None]  # (B, To, 1, D)
        # In the projections' dtype (bf16 under autocast), which every block's attention reads it in.
        per_position = self.context_pos.view(1, to, n, -1).to(per_step.dtype)
        # added in place: no (B, To, N, D) temporary for their sum
        return F.linear(points, w_points).add_(per_step).add_(per_position).view(b, to * n, -1)

    def modulations(self, t: Tensor, dt: Tensor) -> list[tuple[Tensor, ...]]:
        """AdaLN-Zero (shift, 1 + scale, gate) x 3 of every block, (B, 1, D) each, from c = proj([emb(t),
        emb(dt)])."""
        c = self.cond_proj(torch.cat([self.t_embed(t), self.dt_embed(dt)], dim=-1))
        return [split_modulation(blk.adaln(c)) for blk in self.blocks]

    def forward(
        self,
        x: Tensor,
        t: Tensor,
        dt: Tensor,
        context_kv: list[tuple[Tensor, Tensor]] | Tensor,
        modulations: list[tuple[Tensor, ...]] | None = None,
    ) -> Tensor:
        """x (B, H, A) noisy normalised chunk, t and dt (B,) -> velocity (B, H, A).

        `context_kv`: every block's cross-attention keys/values (`encode_context`, worth it when reused over
        flow steps), or the projected context (B, L, D) (`project_context`) that every block attends to
        without keys and values (one pass, as in training). `modulations` (from `self.modulations(t, dt)`,
        batch B or 1) may be passed to skip their computation.
        """
        h = self.action_in(x) + self.action_pos
        if modulations is None:
            modulations = self.modulations(t, dt)
        if isinstance(context_kv, Tensor):
            context_kv = [context_kv] * len(self.blocks)
        for blk, kv, mod in zip(self.blocks, context_kv, modulations, strict=True):
            h = blk(h, mod, kv)
        return self.out_mlp(self.out_norm(h))


# ------------------------------------------------------------------------------------------------------------
# Network.
# ------------------------------------------------------------------------------------------------------------


def weighted_loss_mask(weights: Tensor, dims: tuple[int, ...] | None, action_dim: int,
                       mask: Tensor) -> Tensor:
    """The (B, H, A) element weights of the action losses: `mask` (1 where an action step is real, 0 where
    padded) times each sample's weight (`weights`, (B,)) on the action dimensions `dims` (None: all of them);
    the other dimensions keep weight 1."""
    w = weights[:, None, None].expand(-1, 1, action_dim)
    if dims is not None:
        on = torch.zeros(action_dim, dtype=torch.bool, device=weights.device)
        on[list(dims)] = True
        w = torch.where(on, w, torch.ones_like(w))
    return mask * w


def snap_binary_dims(actions: Tensor, dims: tuple[int, ...],
                     levels: tuple[float, ...] = (-1.0, 1.0)) -> Tensor:
    """MIN_MAX-normalised actions (..., A) with the given dimensions snapped to the nearest of `levels`
    (normalised units; by default the two ends of the range, > 0 -> +1, else -1: for a gripper command fully
    open or fully closed; a tie goes to the lower level). Other dimensions are returned as they are. Why: see
    `ManiFlowConfig.binary_action_dims` and `binary_action_levels`."""
    if not dims:
        return actions
    out = actions.clone()
    idx = list(dims)
    grid = torch.tensor(sorted(levels), dtype=actions.dtype, device=actions.device)
    # nearest level; argmin takes the first of equal distances, so exact midpoints go down (0 -> -1 for two)
    nearest = (actions[..., idx, None] - grid).abs().argmin(dim=-1)
    out[..., idx] = grid[nearest]
    return out


def inference_weight_prefixes(use_ema_for_inference: bool) -> tuple[str, str]:
    """(prefix of the weight copy inference reads, prefix of the one it does not) in a policy's state dict."""
    return ("ema_model.", "model.") if use_ema_for_inference else ("model.", "ema_model.")


def _fill_missing_copy(state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys, error_msgs):
    """Load-time hook of the policies: a checkpoint that holds only one of the two weight copies (`model.*`,
    `ema_model.*`; an inference-only checkpoint holds the EMA copy) gives its weights to the other as well."""
    names = {"model.": "ema_model.", "ema_model.": "model."}
    for have, lack in names.items():
        held = [k for k in state_dict if k.startswith(prefix + have)]
        if held and not any(k.startswith(prefix + lack) for k in state_dict):
            for key in held:
                state_dict[prefix + lack + key[len(prefix + have):]] = state_dict[key]
            return


def _invalidate_after_load(module: ManiFlowModel, incompatible_keys) -> None:
    module.invalidate_modulation_cache()


def _forget_host_ema_step(policy: ManiFlowPolicy, incompatible_keys) -> None:
    policy._ema_step_host = None


def read_logged_values(info: dict, checks: list[tuple[Tensor, str]] = ()) -> dict:
    """`info` with its 0-dim tensors turned into Python floats (in place), after raising the message of any
    failed check (a 0-dim bool tensor that is False): one device-to-host copy for all of them.

    Why: each read of a device tensor on the host (`.item()`, `bool()`) waits until the device has run
    everything
    queued so far, so a training step reads its logged values once, at the end of the forward pass. Not later:
    LeRobot's metrics tracker keeps Python numbers only, and under mixed precision Accelerate hands
    lerobot-train a copy of the returned dict.
    """
    keys = [k for k, v in info.items() if isinstance(v, Tensor)]
    if not keys and not checks:
        return info
    values = [info[k].detach().float().reshape(()) for k in keys] + [
        ok.float().reshape(()) for ok, _ in checks
    ]
    host = torch.stack(values).tolist()
    for (_, message), ok in zip(checks, host[len(keys):], strict=True):
        if not ok:
            raise ValueError(message)
    info.update(zip(keys, host[: len(keys)], strict=True))
    return info


class ManiFlowModel(nn.Module):
    """Point encoder + state MLP -> (B, To * N, Dp + Ds) context -> DiT-X."""

    def __init__(self, config: ManiFlowConfig):
        super().__init__()
        self.config = config
        state_dim = int(config.input_features[OBS_STATE].shape[0])
        action_dim = int(config.output_features[ACTION].shape[0])
        self.point_encoder = PointEncoder(
            config.token_channels, config.point_encoder_hidden_dims, config.point_feature_dim
        )
        self.state_encoder = StateEncoder(state_dim, config.state_feature_dim)
        self.dit = DiTX(
            config,
            action_dim=action_dim,
            context_dim=config.point_feature_dim + config.state_feature_dim,
            context_len=config.n_obs_steps * config.num_tokens,
        )
        # Inference-time AdaLN modulations by (num_steps, device, dtype); see `schedule_modulations`.
        self._modulation_cache: dict[tuple, list] = {}
        self.register_load_state_dict_post_hook(_invalidate_after_load)

    def encode_observations(self, point_cloud: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        """point_cloud (B, To, N, C), state (B, To, S) -> point tokens (B, To, N, Dp), state feats (B, To,
        Ds)."""
        return self.point_encoder(point_cloud), self.state_encoder(state)

    @staticmethod
    def build_context(point_feats: Tensor, state_feats: Tensor) -> Tensor:
        """Concatenate each step's state feature to every point token of that step: (B, To * N, Dp + Ds)."""
        b, to, n, _ = point_feats.shape
        tokens = torch.cat([point_feats, state_feats[:, :, None].expand(-1, -1, n, -1)], dim=-1)
        return tokens.reshape(b, to * n, tokens.shape[-1])

    def observation_tokens(
        self, point_cloud: Tensor, state: Tensor, need_future: bool = False
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """The context's parts, point tokens (B, To, N, Dp) and state features (B, To, Ds), plus intermediate
        features (subclasses add theirs and may change the point tokens)."""
        point_feats, state_feats = self.encode_observations(point_cloud, state)
        return point_feats, state_feats, {"h_cur": point_feats[:, -1]}

    def observation_context(
        self, point_cloud: Tensor, state: Tensor, need_future: bool = False
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Context tokens (B, To * N, Dp + Ds) for DiT-X plus intermediate features (see
        `observation_tokens`)."""
        point_feats, state_feats, aux = self.observation_tokens(point_cloud, state, need_future=need_future)
        return self.build_context(point_feats, state_feats), aux

    def schedule_modulations(
        self, num_steps: int, device: torch.device, dtype: torch.dtype
    ) -> list[list[tuple[Tensor, ...]]]:
        """AdaLN modulations of the Euler schedule (t_i = i/N, dt = 1/N), batch 1, for every step.

        They depend only on the schedule and on the conditioning weights, so outside autograd they are cached
        per (num_steps, device, dtype) and reused across calls (at batch 1 their weights are ~40% of what a
        flow step reads). Whoever changes the weights calls `invalidate_modulation_cache()`: `ManiFlowPolicy`
        does in `forward` (a training step follows), `update` (EMA), `train()` and after `load_state_dict`.
        """
        key = (num_steps, device, dtype)
        if key in self._modulation_cache and not torch.is_grad_enabled():
            return self._modulation_cache[key]
        step = 1.0 / num_steps
        dt = torch.full((1,), step, device=device, dtype=dtype)
        mods = [
            [
                tuple(m.contiguous() for m in block_mods)
                for block_mods in self.dit.modulations(
                    torch.full((1,), i * step, device=device, dtype=dtype), dt
                )
            ]
            for i in range(num_steps)
        ]
        if not torch.is_grad_enabled():
            self._modulation_cache[key] = mods
        return mods

    def invalidate_modulation_cache(self) -> None:
        """Forget the cached AdaLN modulations (call after changing the conditioning weights in place)."""
        self._modulation_cache.clear()

    def sample(self, context: Tensor, noise: Tensor, num_steps: int) -> Tensor:
        """Euler integration from noise (t = 0) to data (t = 1): x += (1/N) f(x, i/N, 1/N)."""
        kv = self.dit.encode_context(context)
        mods = self.schedule_modulations(num_steps, noise.device, noise.dtype)
        x = noise
        b = x.shape[0]
        step = 1.0 / num_steps
        dt = torch.full((b,), step, device=x.device, dtype=x.dtype)
        for i in range(num_steps):
            t = torch.full((b,), i * step, device=x.device, dtype=x.dtype)
            x = x + step * self.dit(x, t, dt, kv, modulations=mods[i])
        return x


# ------------------------------------------------------------------------------------------------------------
# Policy.
# ------------------------------------------------------------------------------------------------------------


def recovering_frames(batch: dict[str, Tensor], option: str, opt_out: str) -> Tensor:
    """(B,) bool: the samples whose current frame (last observation step) the demonstrator spent recovering
    the view in, from the training-only label of the `points` view; a KeyError naming `option` if missing."""
    if TEACHER_RECOVERING not in batch:
        raise KeyError(
            f"{option} needs the per-frame label '{TEACHER_RECOVERING}' in the batch: make the training view "
            f"again with `python -m lerobot_bavo.datasets.views --view points` (a dataset with occlusion "
            f"annotations), or {opt_out}."
        )
    return last_observation_step(batch[TEACHER_RECOVERING]) > 0.5


def last_observation_step(label: Tensor) -> Tensor:
    """(B,) the current frame's value of a per-frame training label batched as (B, To, 1) or (B, 1)."""
    return label.reshape(label.shape[0], -1)[:, -1]


class ManiFlowPolicy(PreTrainedPolicy):
    """ManiFlow policy (consistency flow matching with an EMA teacher, 1-2 step Euler inference).

    `self.model` is trained; `self.ema_model` is its EMA copy (updated in `update()`, which lerobot-train
    calls after every optimiser step), the consistency teacher and, by default, the model used for inference.
    Both are saved in `model.safetensors`.
    """

    config_class = ManiFlowConfig
    name = "maniflow"

    def __init__(self, config: ManiFlowConfig, **kwargs):
        """
        Args:
            config: Policy configuration; `input_features` / `output_features` must be set (`make_policy`
            does). kwargs: `dataset_stats` / `dataset_meta` from `make_policy`; unused (normalisation lives in
            the
                processors).
        """
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.model = self._make_model(config)
        self.ema_model = copy.deepcopy(self.model)
        self.ema_model.requires_grad_(False)
        self.ema_model.eval()
        # Number of EMA updates done so far (k of the decay schedule); saved so that resuming continues it.
        self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))
        self._register_load_state_dict_pre_hook(_fill_missing_copy)
        # Its value on the host (None: read it from the buffer at the next update), so that `update` needs no
        # device sync; loading weights resets it.
        self._ema_step_host: int | None = None
        self.register_load_state_dict_post_hook(_forget_host_ema_step)
        self._queues: dict[str, deque] = {}
        # `config.ignored_state_dims` as an index tensor that moves with the policy (no host-to-device copy
        # inside a step); not saved: the config holds the dims
        self.register_buffer("ignored_state_index", torch.tensor(config.ignored_state_dims, dtype=torch.long),
                             persistent=False)
        # `config.relative_action_dims` / `_scales` likewise (the config holds them)
        self.register_buffer("relative_action_index", as_index(config.relative_action_dims), persistent=False)
        scales = torch.tensor(config.relative_action_scales, dtype=torch.float32)
        self.register_buffer("relative_action_scale", scales, persistent=False)
        self.reset()
        # `config.compile` takes effect at the first loss computation (`begin_training_step`), not here, so
        # loading a checkpoint trained compiled for inference (bavo-eval, lerobot-eval) runs eager networks
        # and needs no compiler.
        self._networks_compiled = False

    def inference_state_keys(self) -> list[str]:
        """The state-dict entries `select_action` reads: the EMA copy's weights (the trained model's when
        `use_ema_for_inference` is off). A shipped checkpoint may hold only these
        (`scripts/ship_checkpoint.py`); loading one fills the other copy from it, so it can also be
        fine-tuned."""
        _, unused = inference_weight_prefixes(self.config.use_ema_for_inference)
        return [k for k in self.state_dict() if not k.startswith(unused)]

    def _make_model(self, config: ManiFlowConfig) -> ManiFlowModel:
        return ManiFlowModel(config)

    def compiled_modules(self, model: ManiFlowModel) -> list[nn.Module]:
        """The sub-networks `compile` compiles (subclasses add theirs)."""
        return [model.point_encoder, model.state_encoder, model.dit]

    def _compile(self, mode: str) -> None:
        """`torch.compile` the sub-networks of both copies in place (`nn.Module.compile`: parameter names, and
        so checkpoints, are unchanged); see `ManiFlowConfig.compile`."""
        for model in (self.model, self.ema_model):
            for module in self.compiled_modules(model):
                module.compile(mode=mode)

    # ---- LeRobot API
    # ----------------------------------------------------------------------------------------

    def get_optim_params(self):
        return self.model.parameters()

    def reset(self):
        """Clear the observation and action queues (and the stored chunks of temporal ensembling, the
        command low-pass's last action and the last executed action); call on env.reset()."""
        self._queues = {
            self.config.observation_key: deque(maxlen=self.config.n_obs_steps),
            OBS_STATE: deque(maxlen=self.config.n_obs_steps),
            ACTION: deque(maxlen=self.config.n_action_steps),
        }
        coeff = self.config.temporal_ensemble_coeff
        self._ensemble = None if coeff is None else ChunkEnsemble(coeff, self.config.n_action_steps)
        self._low_pass = ActionLowPass(self.config.smoothed_action_dims, self.config.action_smoothing_alpha)
        self._last_executed: Tensor | None = None  # (B, A) normalised: what `binary_min_run` holds back to

    def train(self, mode: bool = True):
        super().train(mode)
        self.ema_model.eval()  # the EMA copy never uses dropout
        self.invalidate_modulation_cache()
        if mode:  # training steps reuse the memory the previous one freed (once per process)
            keep_freed_heap()
        return self

    def begin_training_step(self) -> None:
        """Called first by `forward` in training: the weights are about to change (an optimiser step follows),
        so cached inference modulations are forgotten; with CUDA graphs (`compile_mode` "reduce-overhead" or
        "max-autotune") the previous step's graph outputs are declared dead, so the graphs may reuse their
        memory. With `compile` on, the first call compiles the networks (training is what compiling is for;
        inference alone stays eager)."""
        self.invalidate_modulation_cache()
        if self.config.compile and not self._networks_compiled:
            self._compile(self.config.compile_mode)
            self._networks_compiled = True
        if self.config.compile and self.config.compile_mode in ("reduce-overhead", "max-autotune"):
            torch.compiler.cudagraph_mark_step_begin()

    def invalidate_modulation_cache(self) -> None:
        """Forget both networks' cached inference modulations; call after changing weights in place outside
        `forward` / `update` / `load_state_dict` (which call it)."""
        self.model.invalidate_modulation_cache()
        self.ema_model.invalidate_modulation_cache()

    def ema_decay(self, step: int) -> float:
        """clip(1 - (1 + k) ** -power, 0, max_decay) at update k (0-based), as ManiFlow / diffusers
        EMAModel."""
        return float(min(max(1.0 - (1.0 + step) ** -self.config.ema_power, 0.0), self.config.ema_max_decay))

    @torch.no_grad()
    def update(self):
        """EMA update, called by lerobot-train after each optimiser step: ema = d * ema + (1 - d) * online."""
        if self._ema_step_host is None:
            self._ema_step_host = int(self.ema_step.item())
        decay = self.ema_decay(self._ema_step_host)
        # (no_grad: the online parameters need no detached copies)
        torch._foreach_lerp_(list(self.ema_model.parameters()), list(self.model.parameters()), 1.0 - decay)
        ema_buffers, buffers = list(self.ema_model.buffers()), list(self.model.buffers())
        if buffers:
            torch._foreach_copy_(ema_buffers, buffers)
        self.ema_step += 1
        self._ema_step_host += 1
        self.invalidate_modulation_cache()

    # ---- Inputs
    # ---------------------------------------------------------------------------------------------

    def _points(self, pc: Tensor) -> Tensor:
        """(..., N * C) flat (dataset layout) or (..., N, C) -> (..., M, C): the first M = `num_tokens` points
        (an exact M-point FPS subsample, clouds being FPS-ordered); object poses: (..., K, 7)."""
        c = self.config.token_channels
        # flat: not yet (..., N, C) (nor the first M points of it)
        if not (pc.ndim >= 2 and pc.shape[-1] == c):
            pc = unflatten_points(pc, self.config.num_points, c)
        m = self.config.num_tokens
        return pc[..., :m, :] if m < pc.shape[-2] else pc

    def _observation_tensors(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Point cloud (B, To, N, C) and state (B, To, S); single-step inputs are repeated To times."""
        to = self.config.n_obs_steps
        key = self.config.observation_key
        pc, state = self._points(batch[key]), batch[OBS_STATE]
        if pc.ndim == 2:  # (N, C), unbatched
            pc = pc[None]
        if pc.ndim == 3:  # (B, N, C), no time axis
            pc = pc[:, None].expand(-1, to, -1, -1)
        if state.ndim == 1:
            state = state[None]
        if state.ndim == 2:
            state = state[:, None].expand(-1, to, -1)
        if pc.ndim != 4 or pc.shape[1] != to or state.ndim != 3 or state.shape[1] != to:
            raise ValueError(
                f"Expected '{key}' (B, {to}, N, C) and '{OBS_STATE}' (B, {to}, S); got "
                f"{tuple(batch[key].shape)} and {tuple(batch[OBS_STATE].shape)}."
            )
        if self.config.ignored_state_dims:
            state = state.index_fill(-1, self.ignored_state_index, 0.0)
        return pc, state

    # ---- Inference
    # ------------------------------------------------------------------------------------------

    def _inference_model(self) -> ManiFlowModel:
        return self.ema_model if self.config.use_ema_for_inference else self.model

    @torch.no_grad()
    def generate_actions(
        self,
        batch: dict[str, Tensor],
        noise: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Full normalised chunk (B, horizon, A) from observations (B, To, ...) or (B, ...)."""
        model = self._inference_model()
        pc, state = self._observation_tensors(batch)
        context, _ = model.observation_context(pc, state, need_future=False)
        b = context.shape[0]
        action_dim = int(self.config.output_features[ACTION].shape[0])
        shape = (b, self.config.horizon, action_dim)
        if noise is None:
            noise = torch.randn(shape, generator=generator, device=context.device, dtype=context.dtype)
            noise = noise * self.config.noise_scale
        elif tuple(noise.shape) != shape:
            raise ValueError(f"`noise` must have shape {shape}. Got {tuple(noise.shape)}.")
        actions = model.sample(context, noise.to(device=context.device, dtype=context.dtype),
                               self.config.num_inference_steps)
        # the state as given (`ignored_state_dims` cannot be relative ones: the config refuses it)
        actions = to_absolute(actions, batch[OBS_STATE], self.relative_action_index,
                              self.relative_action_scale)
        if self.config.clip_actions:
            actions = actions.clamp(-1.0, 1.0)
        return snap_binary_dims(actions, self.config.binary_action_dims, self.config.binary_action_levels)

    @torch.no_grad()
    def predict_action_chunk(
        self,
        batch: dict[str, Tensor],
        noise: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """The `n_action_steps` actions to execute from the current step, (B, n_action_steps, A), normalised.

        Uses the observation queues when `select_action` filled them, else the batch as given (B, To, ...).
        With `binary_min_run` set, short planned switches of the snapped dimensions are held back against the
        last action `select_action` executed (none yet: the plan's own first level).
        """
        if (queued := self._queued_observations()) is not None:
            batch = queued
        actions = self.generate_actions(batch, noise=noise, generator=generator)
        plan = actions[:, self.config.n_obs_steps - 1:]  # from the current step to the horizon's end
        if self.config.binary_min_run is not None:
            plan = hold_short_switches(plan, self.config.binary_action_dims, self.config.binary_min_run,
                                       self._last_executed)
        return plan[:, : self.config.n_action_steps]

    def _queued_observations(self) -> dict[str, Tensor] | None:
        """The observation queues `select_action` fills, stacked (B, n_obs_steps, ...); None while they are
        empty (a batch given straight to `predict_action_chunk`)."""
        keys = (self.config.observation_key, OBS_STATE)
        if not any(len(self._queues[k]) > 0 for k in keys):
            return None
        return {k: torch.stack(list(self._queues[k]), dim=1) for k in keys}

    @torch.no_grad()
    def select_action(
        self,
        batch: dict[str, Tensor],
        noise: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """One action (B, A) per call; a new chunk is generated every `n_action_steps` calls. Needs only the
        current `observation.point_cloud` (or object poses) and `observation.state` (teacher keys are never
        read here). With `temporal_ensemble_coeff` set, the action is the ensembled mean of the stored chunks'
        predictions for this step (`policies/ensemble.py`) and the action queue stays empty. With
        `smoothed_action_dims` set, those dimensions are low-pass filtered last (`policies/smoothing.py`)."""
        key = self.config.observation_key
        obs = {key: self._points(batch[key]), OBS_STATE: batch[OBS_STATE]}
        for name, unbatched_ndim in ((key, 2), (OBS_STATE, 1)):
            if obs[name].ndim == unbatched_ndim:
                obs[name] = obs[name][None]
        self._queues = populate_queues(self._queues, obs)
        if self._ensemble is not None:
            if self._ensemble.needs_chunk():
                chunk = self.generate_actions(self._queued_observations(), noise=noise, generator=generator)
                self._ensemble.add(chunk[:, self.config.n_obs_steps - 1:])
            action = self._ensemble.pop()
            levels = self.config.binary_action_levels
            return self._low_pass(snap_binary_dims(action, self.config.binary_action_dims, levels))
        if len(self._queues[ACTION]) == 0:
            actions = self.predict_action_chunk(obs, noise=noise, generator=generator)
            self._queues[ACTION].extend(actions.transpose(0, 1))
        self._last_executed = self._queues[ACTION].popleft()
        return self._low_pass(self._last_executed)

    # ---- Training
    # -------------------------------------------------------------------------------------------

    def forward(self, batch: dict[str, Tensor], reduction: str = "mean") -> tuple[Tensor, dict]:
        """Consistency flow-matching loss L_FM + L_CT; returns (loss, logging dict of floats).

        The logged values are read from the device once, at the end (`read_logged_values`).
        """
        if reduction != "mean":
            raise NotImplementedError(f"{type(self).__name__}.forward supports reduction='mean' only.")
        self.begin_training_step()
        batch = self.training_batch(batch)
        pc, state = self._observation_tensors(batch)
        points, states, _ = self.model.observation_tokens(pc, state, need_future=False)
        loss, info = self.flow_loss(points, states, batch)
        info["loss"] = loss.detach()
        return loss, read_logged_values(info)

    def training_batch(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The batch a training step reads: with `occluder_dropout` > 0 (training mode only), some samples'
        occluder points moved behind the points the policy reads (`policies/augment.occluder_dropout`), never
        those of recovery frames with `occluder_dropout_in_recovery` false."""
        p = self.config.occluder_dropout
        if not (self.training and p > 0 and self.config.uses_point_cloud):
            return batch
        if TEACHER_OCCLUDER not in batch:
            raise KeyError(
                f"`occluder_dropout` needs the per-point label '{TEACHER_OCCLUDER}' in the batch: make the "
                "training "
                "view again with `python -m lerobot_bavo.datasets.views --view points` (base-frame clouds of "
                "a "
                "dataset with `annotation.occluder_pose`), or set --policy.occluder_dropout=0."
            )
        if self.config.num_tokens >= self.config.num_points:
            # moved behind the points read, the panel's points would still be read: the cue stays
            raise ValueError(
                f"`occluder_dropout` moves the occluder's points behind the {self.config.num_tokens} points "
                f"the policy reads; it reads all {self.config.num_points}, so the dropout would change "
                "nothing (measured: Drawer Stowing at 256 of 256 points lost Clean as without dropout). Read "
                "fewer points (--policy.points_per_step) or set --policy.occluder_dropout=0."
            )
        keep = None
        if not self.config.occluder_dropout_in_recovery:
            keep = recovering_frames(batch, "`occluder_dropout_in_recovery=false`",
                                     "leave --policy.occluder_dropout_in_recovery at true")
        keys = [self.config.observation_key] + [k for k in POINT_ALIGNED_TEACHER_KEYS if k in batch]
        return occluder_dropout(batch, batch[TEACHER_OCCLUDER] > 0.5, keys, p, keep=keep)

    def recovery_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """(B,) loss weights: `recovery_weight` for the samples whose current frame the demonstrator spent
        recovering the view (the training-only label of the `points` view, last observation step), 1 for the
        others; None when `recovery_weight` is 1 (nothing to weight)."""
        w = self.config.recovery_weight
        if w == 1.0:
            return None
        recovering = recovering_frames(batch, "`recovery_weight`", "set --policy.recovery_weight=1")
        return torch.where(recovering, torch.full_like(recovering, w, dtype=torch.float32),
                           torch.ones_like(recovering, dtype=torch.float32))

    def loss_weights(self, batch: dict[str, Tensor]) -> Tensor | None:
        """(B,) weights of the samples in the action losses: `recovery_weights` times, with `sample_weights`
        on, each sample's per-frame label `observation.teacher.sample_weight` (last observation step; written
        by `scripts/mix_views.py`); None when neither weights anything."""
        weights = self.recovery_weights(batch)
        if not self.config.sample_weights:
            return weights
        if TEACHER_SAMPLE_WEIGHT not in batch:
            raise KeyError(
                f"`sample_weights` needs the per-frame label '{TEACHER_SAMPLE_WEIGHT}' in the batch: join "
                "the training view with `scripts/mix_views.py --source ROOT:EPISODES:WEIGHT`, or set "
                "--policy.sample_weights=false."
            )
        label = last_observation_step(batch[TEACHER_SAMPLE_WEIGHT]).to(torch.float32)
        return label if weights is None else weights * label

    def flow_loss(self, points: Tensor, states: Tensor, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """ManiFlow's objective on a shared context, given as its point tokens (B, To, N, Dp) and state
        features (B, To, Ds) (`ManiFlowModel.observation_tokens`; the encoder runs once, with gradients).

        The first B - int((1 - flow_batch_ratio) B) samples: flow matching, t ~ scale * Beta(a, b), dt = 0,
        target x1 - x0. The rest: consistency, t ~ U{0, 1/K, ..., (K-1)/K}, dt ~ U(0, 1), t' = min(t + dt, 1);
        the EMA DiT (online context, no gradient) gives v^ = f_ema(x_t', t', dt), x1^ = x_t' + (1 - t') v^,
        target (x1^ - x_t) / (1 - t).
        """
        cfg = self.config
        x1 = batch[ACTION]  # (B, H, A), normalised
        if x1.ndim != 3 or x1.shape[1] != cfg.horizon:
            raise ValueError(f"Expected '{ACTION}' (B, {cfg.horizon}, A). Got {tuple(x1.shape)}.")
        # what the network predicts: absolute targets, or for `relative_action_dims` the scaled step from the
        # current state
        x1 = to_relative(x1, batch[OBS_STATE], self.relative_action_index, self.relative_action_scale)
        b = x1.shape[0]
        n_ct = int(b * (1.0 - cfg.flow_batch_ratio))
        n_fm = b - n_ct
        dev, dtype = x1.device, x1.dtype

        x0 = torch.randn_like(x1)
        # Parameters made on the device (a tensor copied from the host waits for the device) and checked here
        # on the host (the distribution's own check reads them back from the device).
        if not (cfg.flow_t_beta_a > 0 and cfg.flow_t_beta_b > 0):
            raise ValueError(f"`flow_t_beta_a` and `flow_t_beta_b` must be > 0. Got {cfg.flow_t_beta_a}, "
                             f"{cfg.flow_t_beta_b}.")
        beta = torch.distributions.Beta(torch.full((), cfg.flow_t_beta_a, device=dev),
                                        torch.full((), cfg.flow_t_beta_b, device=dev), validate_args=False)
        t_fm = cfg.flow_t_scale * beta.sample((n_fm,)).to(dtype)
        t_ct = (
            torch.randint(0, cfg.consistency_t_bins, (n_ct,), device=dev).to(dtype) / cfg.consistency_t_bins
        )
        dt_ct = torch.rand(n_ct, device=dev, dtype=dtype)
        t = torch.cat([t_fm, t_ct])
        dt = torch.cat([torch.zeros_like(t_fm), dt_ct])
        x_t = (1 - t[:, None, None]) * x0 + t[:, None, None] * x1

        v = self.model.dit(x_t, t, dt, self.model.dit.project_context(points, states))

        mask = None
        if cfg.do_mask_loss_for_padding and "action_is_pad" in batch:
            mask = (~batch["action_is_pad"]).to(dtype)[:, :, None].expand_as(x1)
        weights = self.loss_weights(batch)
        if weights is not None:  # a weighted mean: each sample's elements count `weight` times
            mask = weighted_loss_mask(weights.to(dtype), cfg.loss_weight_dims, x1.shape[-1],
                                      torch.ones_like(x1) if mask is None else mask)

        def mse(pred: Tensor, target: Tensor, sl: slice) -> Tensor:
            err = (pred - target) ** 2
            if mask is None:
                return err.mean()
            m = mask[sl]
            return (err * m).sum() / m.sum().clamp_min(1.0)

        loss_fm = mse(v[:n_fm], x1[:n_fm] - x0[:n_fm], slice(0, n_fm)) if n_fm > 0 else x1.new_zeros(())
        if n_ct > 0:
            with torch.no_grad():
                x0c, x1c = x0[n_fm:], x1[n_fm:]
                t2 = (t_ct + dt_ct).clamp(max=1.0)
                x_t2 = (1 - t2[:, None, None]) * x0c + t2[:, None, None] * x1c
                ema_dit = self.ema_model.dit
                v_hat = ema_dit(x_t2, t2, dt_ct, ema_dit.project_context(points[n_fm:], states[n_fm:]))
                x1_hat = x_t2 + (1 - t2[:, None, None]) * v_hat
                target_ct = (x1_hat - x_t[n_fm:]) / (1 - t_ct[:, None, None])
            loss_ct = mse(v[n_fm:], target_ct, slice(n_fm, b))
        else:
            loss_ct = x1.new_zeros(())
        loss = loss_fm + loss_ct
        return loss, {"loss_fm": loss_fm.detach(), "loss_ct": loss_ct.detach()}
