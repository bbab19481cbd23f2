"""A-FAR: ManiFlow + WorldQueryFormer future tokens + zero-init gated fusion + relational distillation.

Paper Sec. 4.3-4.4 and Appendix B. The ManiFlow encoder gives current point tokens H_t (B, N, 128) (the last
observation step); the WorldQueryFormer predicts point-aligned future tokens H^F = F(H_t, s_t); the fused
tokens H_cond = H_t + tanh(gamma) * W_F H^F replace H_t in the DiT-X context (earlier observation steps are
unchanged). gamma starts at 0, so at initialisation A-FAR's context, and hence its actions, equal ManiFlow's
exactly.

Training loss: L = L_ManiFlow + lambda_rel / 2 * (L_cur + L_evo), with the teacher relations computed from the
cached teacher features in the batch (`lerobot_bavo.teacher.relations`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn

from lerobot_bavo.features import TEACHER_VALID, TEACHER_Z0, TEACHER_ZF, unflatten_points
from lerobot_bavo.teacher.relations import (
    relation_matrix,
    relational_losses,
    teacher_relations,
    weighted_l1,
)

from ..maniflow.modeling_maniflow import (
    CrossAttention,
    ManiFlowModel,
    ManiFlowPolicy,
    SelfAttention,
    read_logged_values,
)
from .configuration_afar import AfarConfig


class WorldQueryBlock(nn.Module):
    """Pre-norm block: query self-attention, cross-attention to the current point tokens, FFN."""

    def __init__(self, dim: int, heads: int, ffn_ratio: float, dropout: float, memory_dim: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.self_attn = SelfAttention(dim, heads, dropout)
        self.norm2 = nn.LayerNorm(dim)
        self.cross_attn = CrossAttention(dim, heads, dropout, memory_dim=memory_dim)
        self.norm3 = nn.LayerNorm(dim)
        hidden = int(dim * ffn_ratio)
        self.ffn = nn.Sequential(
            nn.Linear(dim, hidden),
            nn.GELU(),
            nn.Dropout(dropout),
            nn.Linear(hidden, dim),
            nn.Dropout(dropout),
        )

    def forward(self, q: Tensor, memory: Tensor) -> Tensor:
        q = q + self.self_attn(self.norm1(q))
        q = q + self.cross_attn(self.norm2(q), self.cross_attn.kv(memory))
        q = q + self.ffn(self.norm3(q))
        return q


class WorldQueryFormer(nn.Module):
    """Predicts point-aligned future tokens H^F (B, N, hidden) from H_t (B, N, Dp) and the encoded state (B,
    Ds).

    Future queries start as Linear(H_t) + Linear(state feature); H_t itself is the cross-attention memory.
    """

    def __init__(self, config: AfarConfig):
        super().__init__()
        d = config.wqf_hidden_dim
        self.query_in = nn.Linear(config.point_feature_dim, d)
        self.state_in = nn.Linear(config.state_feature_dim, d)
        self.blocks = nn.ModuleList(
            WorldQueryBlock(d, config.wqf_num_heads, config.wqf_ffn_ratio, config.wqf_dropout,
                            memory_dim=config.point_feature_dim)
            for _ in range(config.wqf_num_blocks)
        )
        self.out_norm = nn.LayerNorm(d)

    def forward(self, h_cur: Tensor, state_feat: Tensor) -> Tensor:
        q = self.query_in(h_cur) + self.state_in(state_feat)[:, None]
        for blk in self.blocks:
            q = blk(q, h_cur)
        return self.out_norm(q)


class AfarModel(ManiFlowModel):
    """ManiFlow network + WorldQueryFormer + gated fusion of the current step's point tokens."""

    def __init__(self, config: AfarConfig):
        super().__init__(config)
        self.world_query_former = WorldQueryFormer(config)
        self.fusion_proj = nn.Linear(config.wqf_hidden_dim, config.point_feature_dim)  # W_F
        self.fusion_gate = nn.Parameter(torch.zeros(config.point_feature_dim))  # gamma, zero-init

    def observation_tokens(
        self, point_cloud: Tensor, state: Tensor, need_future: bool = False
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Point tokens (the last step's fused) and state features of the DiT-X context, and {"h_cur": H_t (B,
        N, Dp), "h_fut": H^F (B, N, d) when computed}."""
        cfg: AfarConfig = self.config
        if not (cfg.use_fusion or need_future):
            point_feats, state_feats = self.encode_observations(point_cloud, state)  # (B,To,N,Dp), (B,To,Ds)
            return point_feats, state_feats, {"h_cur": point_feats[:, -1]}
        # The current step's tokens encoded on their own (the encoder works point by point): the backward pass
        # then adds no full-size zero-filled gradients for a slice of all steps' tokens.
        earlier = self.point_encoder(point_cloud[:, :-1])  # (B, To - 1, N, Dp)
        h_cur = self.point_encoder(point_cloud[:, -1])  # (B, N, Dp)
        state_feats = self.state_encoder(state)  # (B, To, Ds)
        h_fut = self.world_query_former(h_cur, state_feats[:, -1])
        aux = {"h_cur": h_cur, "h_fut": h_fut}
        if cfg.use_fusion:
            h_cur = h_cur + torch.tanh(self.fusion_gate) * self.fusion_proj(h_fut)  # H_cond
        return torch.cat([earlier, h_cur[:, None]], dim=1), state_feats, aux


def _teacher_tokens(x: Tensor, batch_size: int, num_points: int, key: str) -> Tensor:
    """Teacher features as (B, N_q, d_T) from (B, N_q, d_T), (B, To, N_q, d_T) or flattened variants."""
    if x.ndim == 4 or x.ndim == 3 and x.shape[1] != num_points:  # (B, To, N, d): take the current (last) step
        x = x[:, -1]
    if x.ndim == 2:  # (B, N * d)
        if x.shape[1] % num_points:
            raise ValueError(f"'{key}' of shape {tuple(x.shape)} cannot be split into {num_points} points.")
        x = unflatten_points(x, num_points, x.shape[1] // num_points)
    if x.ndim != 3 or x.shape[0] != batch_size or x.shape[1] != num_points:
        raise ValueError(
            f"'{key}' must be (B, N_q, d_T) or (B, To, N_q, d_T) with N_q = {num_points} (the point count). "
            f"Got {tuple(x.shape)}."
        )
    return x.float()


class AfarPolicy(ManiFlowPolicy):
    """A-FAR policy (paper Sec. 4). Same interface and inference as ManiFlowPolicy; teacher keys are training-
    only (select_action never reads them)."""

    config_class = AfarConfig
    name = "afar"
    # The relational loss terms; compiled with the networks when `config.compile` (many small operations).
    _relational_losses = staticmethod(relational_losses)

    def _make_model(self, config: AfarConfig) -> AfarModel:
        return AfarModel(config)

    def compiled_modules(self, model: AfarModel) -> list[nn.Module]:
        return super().compiled_modules(model) + [model.world_query_former]

    def _compile(self, mode: str) -> None:
        super()._compile(mode)
        self._relational_losses = torch.compile(relational_losses, mode=mode)

    def get_optim_params(self) -> list[dict]:
        """Two AdamW groups: every weight as configured, and the fusion gate gamma without weight decay at
        `fusion_gate_lr_scale` x the learning rate (see `AfarConfig.fusion_gate_lr_scale`)."""
        gate = self.model.fusion_gate
        rest = [p for p in self.model.parameters() if p is not gate]
        return [
            {"params": rest},
            {
                "params": [gate],
                "weight_decay": 0.0,
                "lr": self.config.optimizer_lr * self.config.fusion_gate_lr_scale,
            },
        ]

    def forward(self, batch: dict[str, Tensor], reduction: str = "mean") -> tuple[Tensor, dict]:
        """L = L_ManiFlow + lambda_rel / 2 * (L_cur + L_evo); logging dict of floats (read from the device
        once, at the end, with the teacher-finiteness checks: `read_logged_values`).

        In training mode the teacher keys are required when a relational loss is enabled; in eval mode (e.g.
        validation without teacher data) the relational terms are skipped when the keys are absent.
        """
        if reduction != "mean":
            raise NotImplementedError(f"{type(self).__name__}.forward supports reduction='mean' only.")
        self.begin_training_step()
        cfg: AfarConfig = self.config
        use_rel = cfg.uses_relational_loss
        if use_rel:
            missing = [k for k in (TEACHER_Z0, TEACHER_ZF) if k not in batch]
            if missing and self.training:
                raise KeyError(
                    f"A-FAR training needs the teacher targets {missing} in the batch (dataset features "
                    f"'{TEACHER_Z0}' and '{TEACHER_ZF}', shape (N_q, d_T)). Add them to the dataset, or "
                    "disable the relational losses (--policy.use_current_relation_loss=false "
                    "--policy.use_future_evolution_loss=false)."
                )
            use_rel = not missing

        batch = self.training_batch(batch)
        pc, state = self._observation_tensors(batch)
        need_future = use_rel and cfg.use_future_evolution_loss
        points, states, aux = self.model.observation_tokens(pc, state, need_future=need_future)
        loss_mf, info = self.flow_loss(points, states, batch)
        loss = loss_mf
        info["loss_maniflow"] = loss_mf.detach()
        checks = []
        if use_rel:
            loss_cur, loss_evo, n_valid = self.relational_loss(batch, aux, checks)
            loss = loss + cfg.lambda_rel / 2 * (loss_cur + loss_evo)
            info.update(loss_cur=loss_cur.detach(), loss_evo=loss_evo.detach(), teacher_valid=n_valid)
        info["fusion_gate_abs"] = torch.tanh(self.model.fusion_gate.detach()).abs().mean()
        info["loss"] = loss.detach()
        return loss, read_logged_values(info, checks)

    def relational_loss(
        self, batch: dict[str, Tensor], aux: dict[str, Tensor], checks: list | None = None
    ) -> tuple[Tensor, Tensor, Tensor | int]:
        """(L_cur, L_evo, number of valid samples) on the current step's tokens; disabled terms are 0.

        Each term is the mean of the per-sample terms over the valid samples (`observation.teacher.valid`), 0
        when there are none: computed for every sample and masked, so that the batch's shapes never depend on
        its values (no device sync). The teacher targets must be finite: checked here when `checks` is None,
        else the check is appended to `checks`, to be read with the step's logged values
        (`read_logged_values`).
        """
        cfg: AfarConfig = self.config
        h_cur = aux["h_cur"]  # (B, M, Dp): the first M of the N points (`points_per_step`)
        b, n = h_cur.shape[0], cfg.num_points
        z0 = _teacher_tokens(batch[TEACHER_Z0], b, n, TEACHER_Z0)[:, : h_cur.shape[1]]
        zf = _teacher_tokens(batch[TEACHER_ZF], b, n, TEACHER_ZF)[:, : h_cur.shape[1]]
        for key, z in ((TEACHER_Z0, z0), (TEACHER_ZF, zf)):
            finite = torch.isfinite(z).all()
            message = (
                f"'{key}' holds NaN or inf in this batch: the dataset's teacher cache is broken (recompute "
                "it with lerobot_bavo.teacher, or train without the relational losses)"
            )
            if checks is None:
                if not bool(finite):
                    raise ValueError(message)
            else:
                checks.append((finite, message))
        n = h_cur.shape[1]
        zero = h_cur.new_zeros(())
        valid = None
        if TEACHER_VALID in batch:
            valid = batch[TEACHER_VALID].reshape(b, -1)[:, -1] > 0.5
        h_fut = aux.get("h_fut")
        m = cfg.relation_num_points
        if m and m < n and self.training:  # random anchor subset (CPU preset)
            pts = torch.randperm(n, device=h_cur.device)[:m]
            h_cur, z0, zf = h_cur[:, pts], z0[:, pts], zf[:, pts]
            h_fut = None if h_fut is None else h_fut[:, pts]
        with torch.no_grad():
            r_t, dr_t = teacher_relations(z0, zf, eps=cfg.relation_eps)
        if cfg.use_future_evolution_loss:
            loss_cur, loss_evo = self._relational_losses(h_cur, h_fut, r_t, dr_t, eps=cfg.relation_eps,
                                                         per_sample=True)
            loss_cur = valid_mean(loss_cur, valid) if cfg.use_current_relation_loss else zero
            loss_evo = valid_mean(loss_evo, valid)
        else:  # L_cur only: no future tokens needed
            hn = F.normalize(h_cur, dim=-1)
            loss_cur = valid_mean(
                weighted_l1(relation_matrix(hn, hn, eps=cfg.relation_eps) - r_t, per_sample=True), valid
            )
            loss_evo = zero
        return loss_cur, loss_evo, b if valid is None else valid.sum()


def valid_mean(per_sample: Tensor, valid: Tensor | None) -> Tensor:
    """Mean of a (B,) per-sample loss over the samples where `valid` (B,) bool is True; 0 when none is (and
    the plain mean when `valid` is None). Invalid samples' values are replaced, not multiplied, by 0, so that
    a non-finite value there cannot reach the loss."""
    if valid is None:
        return per_sample.mean()
    kept = torch.where(valid, per_sample, torch.zeros_like(per_sample))
    return kept.sum() / valid.sum().clamp_min(1).to(per_sample.dtype)
