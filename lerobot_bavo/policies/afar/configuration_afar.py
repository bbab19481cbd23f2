"""Configuration of A-FAR (Active Future-Aware Recovery, BAVO-Bench paper Sec. 4 and Appendix B)."""

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig

from ..maniflow.configuration_maniflow import ManiFlowConfig

# A-FAR fields that follow the size preset. `paper`: Appendix B (WorldQueryFormer 128 wide, 2 blocks, 4 heads;
# FFN width not given, 4x as usual; relations over all N_q = 256 points). `cpu`: chosen with
# benchmarks/policy_speed.py so that an A-FAR training step stays within ~1.3x of ManiFlow's `cpu` preset on 2
# cores and a chunk stays under 20 ms: the WorldQueryFormer is scaled down like the DiT (64 wide, 1 block,
# still 4 heads, 2x FFN; its cost is dominated by attention among the 256 point queries and to the 256 point
# tokens), and each step's relational loss uses a random subset of 128 anchor points (a subsample of the
# pairs; the O(N^2) relation maps dominate otherwise). `--policy.wqf_num_blocks=2` restores the paper's depth
# at ~1.4-1.5x ManiFlow's step time.
AFAR_PRESETS: dict[str, dict] = {
    "paper": {"wqf_hidden_dim": 128, "wqf_num_blocks": 2, "wqf_ffn_ratio": 4.0, "relation_num_points": 0,
              "fusion_gate_lr_scale": 1.0},
    "cpu": {"wqf_hidden_dim": 64, "wqf_num_blocks": 1, "wqf_ffn_ratio": 2.0, "relation_num_points": 128,
            "fusion_gate_lr_scale": 1.0},
    "cpu_fast": {"wqf_hidden_dim": 64, "wqf_num_blocks": 1, "wqf_ffn_ratio": 2.0, "relation_num_points": 0,
                 "fusion_gate_lr_scale": 10.0},
}


@PreTrainedConfig.register_subclass("afar")
@dataclass
class AfarConfig(ManiFlowConfig):
    """Configuration class for AfarPolicy: ManiFlow + WorldQueryFormer + gated fusion + relational
    distillation.

    Every ManiFlow field (see `ManiFlowConfig`) is inherited with the same meaning and defaults; the fields
    below are A-FAR's. At deployment A-FAR needs only the current point cloud and state, like ManiFlow.

    Training-only inputs (from the dataset, never normalised, removed from `input_features`):
        - `observation.teacher.z0`, `observation.teacher.zf`: (N_q, d_T) float32 teacher features of the
          current and future queries, point-aligned with the current frame's points (N_q = N). With LeRobot's
          observation delta indices they arrive as (B, To, N_q, d_T); the last step is used. A flattened
          (N_q * d_T,) layout is accepted too.
        - `observation.teacher.valid` (optional): (1,) or scalar flag; samples with 0 are left out of the
          relational loss.

    Ablations of the paper (Table "Ablation study"): `use_fusion=False` keeps the predicted tokens only for
    the loss ("+ Future Evo."); `use_future_evolution_loss=False` drops L_evo;
    `use_current_relation_loss=False` drops L_cur; camera-frame observations ("(camera)" rows) are a data/env
    option (point clouds expressed in the camera frame), nothing changes in the policy.

    Args:
        wqf_hidden_dim: WorldQueryFormer width; None means from the preset (paper 128, cpu 64). Its output H^F
        is
            mapped back to the point-token width by W_F.
        wqf_num_blocks: Number of WorldQueryFormer blocks (query self-attention, cross-attention to the
        current
            point tokens H_t, FFN); None means from the preset (paper 2, cpu 1).
        wqf_num_heads: Attention heads per WorldQueryFormer block (paper: 4).
        wqf_ffn_ratio: FFN hidden width relative to wqf_hidden_dim; None means from the preset
            (`AFAR_PRESETS`: paper 4, cpu 2).
        wqf_dropout: Dropout inside the WorldQueryFormer.
        use_fusion: Fuse the predicted future tokens into the current point tokens of the DiT-X context,
            H_cond = H + tanh(gamma) * W_F H^F, gamma a learnable per-feature vector initialised to 0.
        use_current_relation_loss: Add L_cur = ||R^S - R^T||_1 on the current tokens.
        use_future_evolution_loss: Add the dynamics-weighted L_evo = ||dR^S - dR^T||_{1,w}.
        lambda_rel: Weight of the relational terms: L = L_ManiFlow + lambda_rel / 2 * (L_cur + L_evo).
        relation_num_points: Anchor points per sample entering the relational losses: 0 = all N_q points
        (paper),
            M = a random subset of M points per training step (same subset for the batch); None means from the
            preset (paper 0, cpu 128).
        relation_eps: eps of the relation operator R(Y|X) (mean pairwise distance + eps).
        fusion_gate_lr_scale: Learning-rate multiplier of the fusion gate gamma (its own AdamW parameter
        group,
            always without weight decay); None means from the preset (paper and cpu 1, cpu_fast 10). Why: with
            Adam, gamma moves at most ~lr per step, and its gradient changes sign often, so within a CPU
            budget (~1 % of the paper's 100K steps) tanh(gamma) stays near 0 and A-FAR acts as ManiFlow (0.004
            after 2000 steps in an earlier run). Weight decay is not the cause (decoupled AdamW shrinks gamma
            by lr * wd = 1e-7 of itself per step) but is still left off gamma, as for gains and biases. The
            gate's value is logged as `fusion_gate_abs` (mean |tanh(gamma)|).
    """

    wqf_hidden_dim: int | None = None
    wqf_num_blocks: int | None = None
    wqf_num_heads: int = 4
    wqf_ffn_ratio: float | None = None
    wqf_dropout: float = 0.0

    use_fusion: bool = True
    use_current_relation_loss: bool = True
    use_future_evolution_loss: bool = True
    lambda_rel: float = 0.01
    relation_num_points: int | None = None
    relation_eps: float = 1e-6
    fusion_gate_lr_scale: float | None = None

    def __post_init__(self):
        super().__post_init__()
        for name, value in AFAR_PRESETS[self.preset].items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        from lerobot_bavo.limits import check_config_bounds  # A-FAR's sizes, now filled from the preset

        check_config_bounds(self)
        if self.wqf_hidden_dim % self.wqf_num_heads != 0:
            raise ValueError(
                f"`wqf_hidden_dim` ({self.wqf_hidden_dim}) must be divisible by `wqf_num_heads` "
                f"({self.wqf_num_heads})."
            )
        if self.relation_num_points == 1 or self.relation_num_points < 0:
            raise ValueError(
                f"`relation_num_points` must be 0 (all) or >= 2. Got {self.relation_num_points}."
            )
        if self.fusion_gate_lr_scale <= 0:
            raise ValueError(f"`fusion_gate_lr_scale` must be > 0. Got {self.fusion_gate_lr_scale}.")
        if self.lambda_rel < 0:
            raise ValueError(f"`lambda_rel` must be >= 0. Got {self.lambda_rel}.")

    def validate_features(self) -> None:
        super().validate_features()
        if not self.uses_point_cloud:
            raise ValueError(
                "A-FAR distils point-aligned teacher relations, so it needs 'observation.point_cloud' among "
                "the "
                "input features; the privileged-state mode ('observation.environment_state' only) is "
                "ManiFlow's."
            )

    @property
    def uses_relational_loss(self) -> bool:
        return self.lambda_rel > 0 and (self.use_current_relation_loss or self.use_future_evolution_loss)
