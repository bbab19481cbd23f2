"""Configuration of the ManiFlow point-cloud policy (Yan et al., CoRL 2025) for LeRobot 0.6.1."""

import math
from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim.schedulers import CosineAnnealingWithWarmupSchedulerConfig
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_bavo.features import OBS_ENV_STATE, OBS_POINT_CLOUD, POSE_CHANNELS, TEACHER_PREFIX
from lerobot_bavo.policies.optim import FusedAdamWConfig
from lerobot_bavo.policies.smoothing import check_smoothing
from lerobot_bavo.policies.switches import check_min_run

# OBS_ENV_STATE: the privileged-state alternative to the point cloud, K object poses (POSE_CHANNELS = 7 each:
# xyz + wxyz quaternion), one token per object; used by the first rung of the failure ladder
# (docs/results/ladder_cube_handoff.md). Training-only targets ride along under TEACHER_PREFIX (see
# `validate_features`).
from lerobot_bavo.sim.constants import ACTION_DIM, ACTION_NAMES, GRIPPER_INDICES

# Size presets. `paper` is ManiFlow's DiT-X (768 wide, 12 layers, 8 heads; ~180 M parameters) with the
# xyz+rgb PointNet (6->64->128->256->512->128). `cpu` keeps the PointNet and shrinks DiT-X to 192 wide x 3
# layers x 4 heads (~3.3 M parameters): on the project's 2-core machines a batch-32 training step takes ~0.7 s
# and one action chunk at batch 1 on one thread ~10-14 ms with 1-2 flow steps (benchmarks/policy_speed.py; the
# cross- attention keys/values of the 2 x 256 point tokens dominate both). See DESIGN.md "CPU budget".
MANIFLOW_PRESETS: dict[str, dict] = {
    "paper": {
        "dit_hidden_dim": 768,
        "dit_num_layers": 12,
        "dit_num_heads": 8,
        "time_embed_hidden_dim": 512,
        "point_encoder_hidden_dims": (64, 128, 256, 512),
        "dropout": 0.1,
    },
    "cpu": {
        "dit_hidden_dim": 192,
        "dit_num_layers": 3,
        "dit_num_heads": 4,
        "time_embed_hidden_dim": 256,
        "point_encoder_hidden_dims": (64, 128, 256, 512),
        "dropout": 0.1,
    },
    "cpu_fast": {
        "dit_hidden_dim": 128,
        "dit_num_layers": 3,
        "dit_num_heads": 4,
        "time_embed_hidden_dim": 128,
        "point_encoder_hidden_dims": (64, 128),
        "points_per_step": 64,
        "dropout": 0.0,
    },
}


def check_chunk_execution(horizon: int, n_obs_steps: int, n_action_steps: int,
                          temporal_ensemble_coeff: float | None = None) -> None:
    """Raise ValueError unless chunks of `horizon` steps (the first `n_obs_steps - 1` of them in the past) can
    be executed `n_action_steps` at a time, and ensembled when `temporal_ensemble_coeff` is set. The config's
    own check, and that of scripts editing these settings in a saved config.json (`ship_checkpoint.py`)."""
    future = horizon - n_obs_steps + 1  # predicted actions from the current step on
    if not 1 <= n_action_steps <= future:
        raise ValueError(
            f"`n_action_steps` must be in [1, horizon - n_obs_steps + 1] = [1, {future}]. "
            f"Got {n_action_steps}."
        )
    if temporal_ensemble_coeff is not None:
        if not math.isfinite(temporal_ensemble_coeff):
            raise ValueError(
                f"`temporal_ensemble_coeff` must be a finite number or None. Got {temporal_ensemble_coeff}."
            )
        if n_action_steps >= future:
            raise ValueError(
                "`temporal_ensemble_coeff` blends overlapping chunks, so a chunk must be generated before "
                f"the last one runs out: `n_action_steps` must be < horizon - n_obs_steps + 1 = {future}. "
                f"Got {n_action_steps}."
            )


def default_binary_action_dims(names=None, action_dim: int | None = None) -> tuple[int, ...]:
    """The action dimensions snapped to open / closed by default: BAVO's gripper commands when the action is
    BAVO's (its entry names when known, else its size), none for any other robot's action."""
    if names is not None:
        return GRIPPER_INDICES if tuple(names) == ACTION_NAMES else ()
    return GRIPPER_INDICES if action_dim == ACTION_DIM else ()


@PreTrainedConfig.register_subclass("maniflow")
@dataclass
class ManiFlowConfig(PreTrainedConfig):
    """Configuration class for ManiFlowPolicy: per-point tokens + DiT-X + consistency flow matching.

    Defaults follow ManiFlow (arXiv 2509.01819) at the BAVO-Bench settings of the A-FAR paper (256 colored
    points, observation horizon 2, action horizon 16, 21-d state and action).

    Inputs and outputs:
        - `observation.point_cloud` (N, C) with C = `point_channels` (6: xyz + rgb in [0, 1]; 3: xyz).
          The flat row-major layout (N * C,) of BAVO datasets is accepted too (the processor reshapes env
          observations to the trained layout; the model unflattens).
        - or, when the input features have no point cloud, `observation.environment_state` (7 K,): the
          privileged object poses (xyz + wxyz quaternion per object). Each object becomes one token through
          the same per-token encoder (the privileged-state ManiFlow of the failure ladder: perfect perception,
          same DiT-X and flow objective).
        - `observation.state` (S,), required.
        - `action` (A,), required output.
        - Keys under `observation.teacher.*` are training-only targets (used by A-FAR) and are removed from
          `input_features` by `validate_features`, so they are never normalised and never needed at eval.
        - Other `observation.*` keys (e.g. `observation.point_pixels`) are ignored by the model.
        - The frame of the point cloud (robot base by default, camera frame for the ablation) is a data/env
          option; the policy is agnostic to it.

    Normalisation: ManiFlow's `limits` mode maps every last-axis channel to [-1, 1]; LeRobot's MIN_MAX does
    the same. LeRobot stores stats of a (N, 6) feature per channel, shape (6,), which broadcast over (B, To,
    N, 6), so the default normaliser handles the point cloud (it is a STATE-typed feature). A flat (N * 6,)
    feature has element-wise (N * 6,) stats: they must be per-channel stats tiled N times (as BAVO datasets
    write them, `lerobot_bavo.datasets.schema.tile_channel_stats`), otherwise each point slot gets its own
    scale. Difference: ManiFlow maps channels whose range is < 1e-4 to 0, LeRobot divides by eps and maps them
    to -1.

    Size presets: the architecture fields left at `None` are filled from `MANIFLOW_PRESETS[preset]`; fields
    set explicitly (e.g. `--policy.dit_num_layers=2`) override the preset. `preset="paper"` is ManiFlow's size
    (GPU only, ~46 s per step on 2 CPU cores); `preset="cpu"` is 192 wide x 3 layers x 4 heads.

    Args:
        n_obs_steps: Number of observation steps given to the policy (current one and the ones before it).
            Their point tokens are concatenated into one context of n_obs_steps * N tokens.
        horizon: Number of action steps predicted per chunk, counted from the first observation step
            (the chunk covers steps t - n_obs_steps + 1 ... t - n_obs_steps + horizon).
        n_action_steps: Number of predicted actions executed per policy call, starting at the current step.
            Must be <= horizon - n_obs_steps + 1. Default 8: replans every 8 control steps (0.32 s at 25 Hz),
            reactive enough for random-time occlusions while executing a coherent half of the chunk, and
            halves eval-time policy calls compared with 4.
        temporal_ensemble_coeff: None (default) executes each chunk's `n_action_steps` actions as they are.
            A number turns on ACT's temporal ensembling (`policies/ensemble.py`, inference only): a chunk is
            still generated every `n_action_steps` steps, but every chunk's predictions from the current step
            on are kept (horizon - n_obs_steps + 1 of them) and the action executed at each step is their
            weighted mean, w_i = exp(-coeff * i) with i = 0 the oldest (the ACT paper's 0.01); gripper
            dimensions are snapped after the mean. Why: overlapping chunks are blended instead of cut over.
            Needs `n_action_steps` < horizon - n_obs_steps + 1 (chunks must overlap); cost: one policy call
            per `n_action_steps` steps, as without it.
        smoothed_action_dims: Action dimensions whose commands are low-pass filtered at inference (default:
            none): each sent command is a_t = a_{t-1} + action_smoothing_alpha * (u_t - a_{t-1}), u_t the
            policy's (`policies/smoothing.py`). Why: a joint whose position is in the state (the camera arm's,
            dims 14-20 on BAVO-Bench) turns step-to-step command jitter into a random walk of what the policy
            sees. Inference only; gripper (binary) dimensions cannot be smoothed.
        action_smoothing_alpha: The filter's gain in (0, 1]; 1 (default) sends the policy's commands as they
            are. Its time constant is about (1 - alpha) / alpha control steps.
        normalization_mapping: FeatureType name -> NormalizationMode. STATE (state and point cloud) and ACTION
            use MIN_MAX (ManiFlow's `limits`); VISUAL is IDENTITY because images are not used.
        push_to_hub: Whether lerobot-train pushes the checkpoint to the Hub. False here (LeRobot's default is
            True, which fails offline with "'repo_id' argument missing").
        point_channels: Channels per point of `observation.point_cloud` (6 = xyz + rgb, 3 = xyz); needed to
            unflatten a flat (N * C,) feature.
        preset: Size preset, one of `MANIFLOW_PRESETS` ("paper", "cpu").
        point_encoder_hidden_dims: Hidden widths of the per-point MLP (Linear + LayerNorm + ReLU each); None
            means from the preset (paper and cpu: (64, 128, 256, 512)).
        point_feature_dim: Width of each point token after the final Linear + LayerNorm (paper: 128).
        state_feature_dim: Width of the state MLP (S -> d -> ReLU -> d; paper: 64). The state feature of each
            observation step is concatenated to every point token of that step.
        dit_hidden_dim: DiT-X width; None means from the preset (paper 768, cpu 192).
        dit_num_layers: Number of DiT-X blocks; None means from the preset (paper 12, cpu 3).
        dit_num_heads: Attention heads per DiT-X block; None means from the preset (paper 8, cpu 4).
        dit_mlp_ratio: Hidden width of the block MLP relative to dit_hidden_dim (paper 4).
        dropout: Dropout in DiT-X attention and MLPs; None means from the preset (paper and cpu 0.1, cpu_fast
        0:
            on CPU, attention dropout forces PyTorch's unfused attention and the Bernoulli masks cost ~30 % of
            a training step, measured with torch.profiler).
        time_freq_dim: Size of the sinusoidal embedding of t and of dt (paper 128; raw t in [0, 1]).
        time_embed_hidden_dim: Hidden width of the time MLP (sinusoid -> hidden -> Mish -> width); None means
            from the preset (paper 512, cpu 256).
        points_per_step: Points per observation step the policy reads: the first M of the cloud's N points;
            0 = all N. BAVO clouds are stored in farthest-point-sampling order (`envs/pointcloud.py`), so the
            first M points are exactly the M-point FPS sample of the same view, and the point-aligned teacher
            features are cut the same way. None means from the preset (paper and cpu: 0; cpu_fast: 64).
        ignored_state_dims: Dimensions of `observation.state` the policy never sees: they are set to 0 (the
            middle of the MIN_MAX-normalised range) before the state encoder, in training and at inference
            alike, so the network gets no information from them and its shapes (and checkpoints) stay those
            of the full state. Why: a state without the camera-arm joints
            (`--policy.ignored_state_dims=[14,15,16,17,18,19,20]` on BAVO's 21-dim state; docs/training.md)
            tests whether the policy reads the task's phase from where the camera arm is instead of from
            the cloud. Empty (default): the whole state.
        num_inference_steps: Euler steps from noise (t = 0) to data (t = 1) at inference. Default 10, as
            ManiFlow's released scripts (its paper claims 1-2 steps thanks to the consistency objective).
            Measured on the CPU-scale A-FAR of docs/results/ladder_cube_handoff.md (same checkpoint, Stage, 20
            episodes): 2 steps SR 10 / TPS 53, 10 steps 35 / 75, 20 steps 45 / 75. The paper does not fix it.
            A checkpoint's config.json keeps the value it was trained with (`--policy.num_inference_steps=N`
            in lerobot-eval overrides it).
        noise_scale: Standard deviation of the Gaussian noise the Euler integration starts from at inference
            (a sampling temperature; training always draws standard noise). 1 (default) samples the learned
            distribution; below 1 the sample moves towards the flow's deterministic path from the noise's
            mean (0: no noise, the same chunk for the same observation). Why: on the grasp-limited tasks two
            draws for the same observation differ by about as much as a draw differs from the demonstrated
            action, and this tests whether that spread costs grasps (at 0.5 it did not; the fit's own bias
            does: docs/results/sampling_noise.md). A checkpoint without the field samples at 1;
            `--policy.noise_scale=X` in lerobot-eval, or the field in a copy's config.json for bavo-eval,
            sets it.
        use_ema_for_inference: Predict actions with the EMA copy (ManiFlow's eval model). The EMA copy is
        always
            kept, since it is the consistency teacher.
        clip_actions: Clamp sampled chunks to [-1, 1], the range every MIN_MAX-normalised action of the
        dataset
            lies in, before unnormalising (as Diffusion Policy's `clip_sample`). Why: a 1-2 step flow sample
            can overshoot the data range (measured: gripper commands of -0.4 on a [0, 1] gripper), which no
            demonstration ever shows.
        binary_action_dims: Action dimensions executed as binary commands. None (default) follows the dataset:
            BAVO's two gripper commands (`sim.constants.GRIPPER_INDICES`, 0 closed .. 1 open) when the
            dataset's action names are BAVO's (or, with no names known, when the action is BAVO's 21-dim one),
            none otherwise; the resolved value is saved with the checkpoint. At inference each of them is
            snapped to the nearer end of its training range (normalised value > 0 -> +1, else -1: fully open
            or fully closed). Why: the experts' gripper commands are open (1) until a grasp and then ramp to
            closed (0); a 1-2 step flow sample drifts off 1 during the approach (measured: 0.9 to 0.4 while
            the arm is still 10 cm above the cube), the half-closed gripper then shows in the state as the
            start of a grasp, and the policy closes on the cube's top (15 of 20 privileged-state episodes
            stopped at M1). Snapping keeps the gripper open until the sampled chunk commits to closing
            (privileged-state ManiFlow, same checkpoint, 20 episodes: Clean SR 15 % -> 90 %, Stage 10 % -> 100
            %; docs/results/ladder_cube_handoff.md). Needs MIN_MAX action normalisation;
            `--policy.binary_action_dims=[]` turns it off. Training is unchanged.
        binary_action_levels: The command levels `binary_action_dims` snap to, in MIN_MAX-normalised
            units (-1: the dimension's lowest value in the training data, +1 its highest; a BAVO gripper
            command g in [0, 1] is 2 g - 1), increasing, each in [-1, 1]. Default (-1, 1): fully closed or
            open. Why others: an expert that holds a gripper part-open needs that level too. Drawer Stowing's
            straddles the handle bar and lets go of it at 0.45 (-0.1) and releases the block at 0.7 (0.4);
            snapped to the two ends, the 0.45 release becomes "closed", the right gripper never lets go of
            the bar and every policy stopped at M2 (docs/results/first_grasp.md). Inference only, like the
            snapping itself.
        binary_min_run: None (default, off) or a number of control steps >= 2: when a chunk is sampled, a
            switch of a snapped `binary_action_dims` command away from the level executed last is kept only
            if the chunk plans the new level for at least this many steps (or to the end of its horizon); a
            shorter run that comes back is replaced by the executed level (`policies/switches.py`). Why: a
            policy holding the cube can sample, at a new chunk's first action, the start of the experts'
            closing ramp from part-open; snapped, it opens the gripper for a few steps, chunk after chunk
            (docs/results/learning_rate.md). Inference only; not with `temporal_ensemble_coeff`.
        relative_action_dims: Action dimensions the network predicts relative to the current state (the
            state entry of the same index, last observation step), in MIN_MAX units and divided by
            `relative_action_scales`: r = (a_n - s_n) / scale (`policies/relative.py`). Training turns the
            dataset's chunks into r, inference turns the sampled r back into absolute targets before the
            clipping and snapping, so the executed actions and the checkpoint's interface are unchanged.
            Why: a step from the current state spans a fraction of the joint's range, so a network that errs
            by a fixed fraction of what it predicts errs less in radians (docs/results/relative_actions.md).
            Empty (default): absolute targets. Needs the state and action to share their layout on these
            dimensions (BAVO's do; the grippers, commands against finger positions, must stay absolute):
            `python -m lerobot_bavo.datasets.relative_actions --root DATASET` prints BAVO's arm joints'
            flags.
        relative_action_scales: One scale per entry of `relative_action_dims` (or one for all), > 0, in
            MIN_MAX units: about the largest |a_n - s_n| in the training chunks (the command above reads the
            0.99 quantile from the dataset), so that r is about unit-sized like the absolute targets.
        ema_power: EMA warm-up power: decay at update k is clip(1 - (1 + k) ** -ema_power, 0, ema_max_decay).
        ema_max_decay: Upper bound of the EMA decay.
        flow_batch_ratio: Fraction of each batch trained with plain flow matching; the remaining
            int((1 - ratio) * B) samples are trained with the consistency objective.
        flow_t_scale: Flow-matching times are t = flow_t_scale * Beta(flow_t_beta_a, flow_t_beta_b).
        flow_t_beta_a: First Beta parameter of the flow-matching time distribution.
        flow_t_beta_b: Second Beta parameter of the flow-matching time distribution.
        consistency_t_bins: Consistency times are drawn from {0, 1/bins, ..., (bins - 1)/bins}.
        do_mask_loss_for_padding: Mask actions beyond the episode ends out of the loss (`action_is_pad`).
            ManiFlow trains on edge-padded chunks, so False by default.
        optimizer_lr: AdamW learning rate of the training preset.
        optimizer_betas: AdamW betas.
        optimizer_eps: AdamW epsilon.
        optimizer_weight_decay: AdamW weight decay.
        optimizer_grad_clip_norm: Gradient clipping used by lerobot-train; 0 disables it (ManiFlow clips
        none). scheduler_warmup_steps: Linear warm-up steps of the cosine learning-rate schedule.
        occluder_dropout: Probability, per training sample, that the cloud's points on the benchmark occluder
            are moved behind the points the policy reads (`policies/augment.py`), so that the sample looks
            like the same scene without the panel. Why: the Stage occluder sits on the line of sight to the
            current target, a position cue a policy can learn instead of the target
            (docs/results/occluder_shortcut.md). Needs the training-only label `observation.teacher.occluder`
            of the `points` training view, and `points_per_step` below the cloud's N (reading all points, the
            moved points are still read: training refuses it); 0 (default) turns it off. Inference is
            unchanged.
        occluder_dropout_in_recovery: Whether occluder dropout may also drop the panel from the samples whose
            frame the demonstrator spent recovering the view (default True, the recipe's). False keeps the
            panel in those samples (training-only label `observation.teacher.recovering`): there the panel
            is what the camera moves for, so dropping it leaves the recovery explained only by when in the
            task it happens (docs/results/random_time.md: the learned cameras move at the Stage events'
            phases, not because the target is hidden). Dropout elsewhere still hides the panel as a position
            cue.
        recovery_weight: Weight, in the flow-matching and consistency losses, of the training samples whose
            frame the demonstrator spent recovering the view after an occlusion event (the training-only
            label `observation.teacher.recovering` of the `points` view, a copy of the dataset's
            `annotation.occlusion_active`), against 1 for every other sample. Why: the learned cameras regain
            the view far less often than the expert at some events (docs/results/first_grasp.md, "Where
            Drawer Stowing's Stage episodes stop"). 1 (default) weights all samples alike; inference is
            unchanged.
        sample_weights: Weight each training sample in the flow-matching and consistency losses by its
            frame's training-only label `observation.teacher.sample_weight` (times `recovery_weight`'s
            weight), which `scripts/mix_views.py --source ROOT:EPISODES:WEIGHT` writes when it joins a view
            whose frames outside the demonstrator's view recoveries (or, `--weigh recovery`, whose recovery
            frames) should count differently. Why: demonstrations of another occlusion condition can then
            teach the recovery without also teaching all of their manipulation (docs/results/random_time.md:
            Random-time demonstrations cost the Stage handoff).
            False (default) ignores the label; inference is unchanged.
        loss_weight_dims: The action dimensions that the per-sample weights above (`recovery_weight`,
            `sample_weights`) apply to; the others weigh 1 in every sample. None (default): all of them.
            Why: one frame can teach one part of the action and not another, e.g. a recovery teaches BAVO's
            camera arm (dims 14-20) what to do while the two arms (0-13) wait, a wait the Stage episodes only
            show at their phase transitions (docs/results/random_time.md).
        compile: Compile the networks with `torch.compile` (point and state encoders, DiT-X, and A-FAR's
            WorldQueryFormer and relational losses; online and EMA copies): fewer, fused kernels, for CUDA
            training where a step is bound by kernel launches and Python (docs/gpu.md). Off by default: the
            first steps then wait for the compiler (again for each new batch size), and on the CPU it needs a
            C++ compiler. Parameter names, checkpoints and losses are those of the eager networks. Compiled at
            the first training step, so a checkpoint trained with it is evaluated (`bavo-eval`,
            `lerobot-eval`) with eager networks, on any device, without a compiler.
        compile_mode: `torch.compile`'s mode when `compile` is on: "default", "reduce-overhead" (CUDA graphs:
            also removes the launch cost of the kernels left, at the price of fixed input shapes and more GPU
            memory), "max-autotune" or "max-autotune-no-cudagraphs".

    Mixed precision: LeRobot's `--policy.use_amp=true` runs the training step under bf16 autocast (the `dtype`
    property below tells lerobot-train so; without it LeRobot would pick fp16 with loss scaling on CUDA).
    The relational losses compute distances in fp32 whatever the autocast.
    """

    # Input / output structure.
    n_obs_steps: int = 2
    horizon: int = 16
    n_action_steps: int = 8
    temporal_ensemble_coeff: float | None = None
    smoothed_action_dims: tuple[int, ...] = ()
    action_smoothing_alpha: float = 1.0

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.MIN_MAX,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    push_to_hub: bool = False  # type: ignore[assignment]

    # Architecture.
    point_channels: int = 6
    preset: str = "paper"
    point_encoder_hidden_dims: tuple[int, ...] | None = None
    point_feature_dim: int = 128
    state_feature_dim: int = 64
    dit_hidden_dim: int | None = None
    dit_num_layers: int | None = None
    dit_num_heads: int | None = None
    dit_mlp_ratio: float = 4.0
    dropout: float | None = None
    time_freq_dim: int = 128
    time_embed_hidden_dim: int | None = None
    points_per_step: int | None = None
    ignored_state_dims: tuple[int, ...] = ()

    # Inference.
    num_inference_steps: int = 10
    noise_scale: float = 1.0
    use_ema_for_inference: bool = True
    clip_actions: bool = True
    binary_action_dims: tuple[int, ...] | None = None
    binary_action_levels: tuple[float, ...] = (-1.0, 1.0)
    binary_min_run: int | None = None

    # Action parametrisation (training and inference alike).
    relative_action_dims: tuple[int, ...] = ()
    relative_action_scales: tuple[float, ...] = ()

    # Training objective and EMA.
    ema_power: float = 0.75
    ema_max_decay: float = 0.9999
    flow_batch_ratio: float = 0.75
    flow_t_scale: float = 0.999
    flow_t_beta_a: float = 1.0
    flow_t_beta_b: float = 1.5
    consistency_t_bins: int = 10
    do_mask_loss_for_padding: bool = False

    # Training preset.
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.9, 0.95)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-3
    optimizer_grad_clip_norm: float = 0.0
    scheduler_warmup_steps: int = 500

    # Training-time augmentation and sample weighting.
    occluder_dropout: float = 0.0
    occluder_dropout_in_recovery: bool = True
    recovery_weight: float = 1.0
    sample_weights: bool = False
    loss_weight_dims: tuple[int, ...] | None = None

    # Training speed (docs/gpu.md).
    compile: bool = False
    compile_mode: str = "default"

    def __post_init__(self):
        super().__post_init__()
        if self.preset not in MANIFLOW_PRESETS:
            raise ValueError(f"`preset` must be one of {sorted(MANIFLOW_PRESETS)}. Got {self.preset!r}.")
        for name, value in MANIFLOW_PRESETS[self.preset].items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        for name in ("points_per_step",):  # fields newer presets set; older presets mean "all"
            if getattr(self, name) is None:
                setattr(self, name, 0)
        from lerobot_bavo.limits import (
            check_config_bounds,  # sizes from a checkpoint's config.json, before any build
        )

        check_config_bounds(self)
        self.point_encoder_hidden_dims = tuple(int(d) for d in self.point_encoder_hidden_dims)
        if self.points_per_step < 0:
            raise ValueError(f"`points_per_step` must be >= 0 (0 = all points). Got {self.points_per_step}.")

        if self.dit_hidden_dim % self.dit_num_heads != 0:
            raise ValueError(
                f"`dit_hidden_dim` ({self.dit_hidden_dim}) must be divisible by `dit_num_heads` "
                f"({self.dit_num_heads})."
            )
        if self.n_obs_steps < 1:
            raise ValueError(f"`n_obs_steps` must be >= 1. Got {self.n_obs_steps}.")
        check_chunk_execution(self.horizon, self.n_obs_steps, self.n_action_steps,
                              self.temporal_ensemble_coeff)
        if self.point_channels not in (3, 6):
            raise ValueError(f"`point_channels` must be 3 (xyz) or 6 (xyz + rgb). Got {self.point_channels}.")
        if self.num_inference_steps < 1:
            raise ValueError(f"`num_inference_steps` must be >= 1. Got {self.num_inference_steps}.")
        if not (math.isfinite(self.noise_scale) and self.noise_scale >= 0):
            raise ValueError(f"`noise_scale` must be a finite number >= 0. Got {self.noise_scale}.")
        action_mode = self.normalization_mapping.get("ACTION")
        if self.clip_actions and action_mode != NormalizationMode.MIN_MAX:
            raise ValueError(
                "`clip_actions=True` clamps normalised actions to [-1, 1], which is their range only under "
                "MIN_MAX "
                f"normalisation; ACTION is normalised with {action_mode}. Set `--policy.clip_actions=false`."
            )
        if self.binary_action_dims is not None:
            self.binary_action_dims = tuple(int(d) for d in self.binary_action_dims)
        self._check_binary_action_dims_mode()
        levels = tuple(float(v) for v in self.binary_action_levels)
        if len(levels) < 2 or list(levels) != sorted(set(levels)) or not all(-1 <= v <= 1 for v in levels):
            raise ValueError(
                "`binary_action_levels` must be at least two distinct, increasing levels in [-1, 1] "
                f"(MIN_MAX-normalised). Got {list(self.binary_action_levels)}."
            )
        self.binary_action_levels = levels
        check_min_run(self.binary_min_run, self.binary_action_dims, self.temporal_ensemble_coeff)
        self._check_relative_actions()
        self.smoothed_action_dims = tuple(int(d) for d in self.smoothed_action_dims)
        check_smoothing(self.smoothed_action_dims, self.action_smoothing_alpha, self.binary_action_dims or ())
        if not 0.0 <= self.occluder_dropout <= 1.0:
            raise ValueError(
                f"`occluder_dropout` must be a probability in [0, 1]. Got {self.occluder_dropout}."
            )
        if not (math.isfinite(self.recovery_weight) and self.recovery_weight > 0.0):
            raise ValueError(f"`recovery_weight` must be a finite number > 0. Got {self.recovery_weight}.")
        if not 0.0 <= self.flow_batch_ratio <= 1.0:
            raise ValueError(f"`flow_batch_ratio` must be in [0, 1]. Got {self.flow_batch_ratio}.")
        if self.consistency_t_bins < 1:
            raise ValueError(f"`consistency_t_bins` must be >= 1. Got {self.consistency_t_bins}.")

    # LeRobot interface.
    @property
    def dtype(self) -> str:
        """Precision of lerobot-train's autocast, read by lerobot-train: "bfloat16" when `use_amp`, else
        "float32". Why: lerobot-train takes the autocast type from a policy's `dtype` when it has one, else
        from `use_amp` with torch's default for the device, fp16 on CUDA, which needs loss scaling (a
        host-device sync per step) and has a narrower range than bf16."""
        return "bfloat16" if self.use_amp else "float32"

    def get_optimizer_preset(self) -> FusedAdamWConfig:
        return FusedAdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> CosineAnnealingWithWarmupSchedulerConfig:
        # LeRobot's `diffuser` cosine scheduler needs the optional `diffusers` package; this one has the same
        # shape (linear warm-up, then cosine to zero over the remaining steps) with no extra dependency.
        return CosineAnnealingWithWarmupSchedulerConfig(num_warmup_steps=self.scheduler_warmup_steps)

    def _check_relative_actions(self) -> None:
        """Normalise and check `relative_action_dims` / `relative_action_scales` (one scale per dimension,
        a single scale broadcast); the checks against the features are in `validate_features`."""
        dims = tuple(int(d) for d in self.relative_action_dims)
        scales = tuple(float(v) for v in self.relative_action_scales)
        if len(set(dims)) != len(dims) or any(d < 0 for d in dims):
            raise ValueError(f"`relative_action_dims` must be distinct indices >= 0. Got {list(dims)}.")
        if dims and len(scales) == 1:
            scales = scales * len(dims)
        if len(scales) != len(dims):
            raise ValueError(
                "`relative_action_scales` needs one scale per entry of `relative_action_dims` "
                f"({len(dims)}) or one for all; got {len(scales)}. `python -m "
                "lerobot_bavo.datasets.relative_actions --root DATASET` prints both flags for a dataset."
            )
        if not all(math.isfinite(v) and v > 0 for v in scales):
            raise ValueError(f"`relative_action_scales` must be finite and > 0. Got {list(scales)}.")
        if dims:
            modes = {k: self.normalization_mapping.get(k) for k in ("ACTION", "STATE")}
            if any(m != NormalizationMode.MIN_MAX for m in modes.values()):
                raise ValueError("`relative_action_dims` subtracts the MIN_MAX-normalised state from the "
                                 f"MIN_MAX-normalised action; ACTION and STATE are normalised with {modes}.")
        self.relative_action_dims, self.relative_action_scales = dims, scales

    def _check_binary_action_dims_mode(self) -> None:
        action_mode = self.normalization_mapping.get("ACTION")
        if self.binary_action_dims and action_mode != NormalizationMode.MIN_MAX:
            raise ValueError(
                "`binary_action_dims` snaps normalised actions to -1 / +1, the ends of their range only "
                "under MIN_MAX "
                f"normalisation; ACTION is normalised with {action_mode}. Set "
                "`--policy.binary_action_dims=[]`."
            )

    def set_dataset_feature_metadata(self, features: dict) -> None:
        """Called by LeRobot's `make_policy` with the dataset's feature dict: resolves the dataset-dependent
        defaults (`binary_action_dims`) from the action's names."""
        if self.binary_action_dims is None:
            names = (features.get(ACTION) or {}).get("names")
            self.binary_action_dims = default_binary_action_dims(names=names)
            self._check_binary_action_dims_mode()
            check_min_run(self.binary_min_run, self.binary_action_dims, self.temporal_ensemble_coeff)

    def validate_features(self) -> None:
        if self.input_features:
            for key in [k for k in self.input_features if k.startswith(TEACHER_PREFIX)]:
                del self.input_features[key]
        inputs = self.input_features or {}
        if OBS_POINT_CLOUD not in inputs and OBS_ENV_STATE not in inputs:
            raise ValueError(
                f"{type(self).__name__} needs '{OBS_POINT_CLOUD}' (or, privileged-state mode, "
                f"'{OBS_ENV_STATE}') "
                f"among the input features. Got {sorted(inputs)}."
            )
        shape = tuple(inputs[self.observation_key].shape)
        c = self.token_channels
        if not (
            (len(shape) == 2 and shape[1] == c) or (len(shape) == 1 and shape[0] % c == 0 and shape[0] >= c)
        ):
            raise ValueError(
                f"'{self.observation_key}' must have shape (N, {c}) or the flat (N * {c},). Got {shape}."
            )
        if OBS_STATE not in inputs:
            raise ValueError(f"{type(self).__name__} needs '{OBS_STATE}' among the input features.")
        state_dim = int(math.prod(inputs[OBS_STATE].shape))
        bad = [d for d in self.ignored_state_dims if not 0 <= d < state_dim]
        if bad or len(set(self.ignored_state_dims)) != len(self.ignored_state_dims):
            raise ValueError(
                f"`ignored_state_dims` {list(self.ignored_state_dims)} must be distinct indices of the "
                f"{state_dim}-dim '{OBS_STATE}'" + (f"; {bad} are not." if bad else "; some repeat.")
            )
        if self.output_features and ACTION in self.output_features and self.loss_weight_dims is not None:
            self.loss_weight_dims = tuple(int(d) for d in self.loss_weight_dims)
            action_dim = int(self.output_features[ACTION].shape[0])
            bad = [d for d in self.loss_weight_dims if not 0 <= d < action_dim]
            if bad or len(set(self.loss_weight_dims)) != len(self.loss_weight_dims):
                raise ValueError(
                    f"`loss_weight_dims` {list(self.loss_weight_dims)} must be distinct indices of the "
                    f"{action_dim}-dim '{ACTION}'" + (f"; {bad} are not." if bad else "; some repeat.")
                )
        if self.output_features and ACTION not in self.output_features:
            raise ValueError(f"{type(self).__name__} needs '{ACTION}' among the output features.")
        if self.output_features:
            action_dim = int(self.output_features[ACTION].shape[0])
            if self.binary_action_dims is None:  # no dataset names seen (built from an env or an old config)
                self.binary_action_dims = default_binary_action_dims(action_dim=action_dim)
                self._check_binary_action_dims_mode()
                check_min_run(self.binary_min_run, self.binary_action_dims, self.temporal_ensemble_coeff)
            bad = [d for d in self.binary_action_dims if not 0 <= d < action_dim]
            if bad:
                raise ValueError(
                    f"`binary_action_dims` {list(self.binary_action_dims)} must index the {action_dim}-dim "
                    "action; "
                    f"{bad} do not. Set them to the action's gripper dimensions, or [] for none."
                )
            check_smoothing(self.smoothed_action_dims, self.action_smoothing_alpha, self.binary_action_dims)
            if bad := [d for d in self.smoothed_action_dims if d >= action_dim]:
                raise ValueError(f"`smoothed_action_dims` {list(self.smoothed_action_dims)} must index the "
                                 f"{action_dim}-dim action; {bad} do not.")
        if self.relative_action_dims:
            action_dim = int(self.output_features[ACTION].shape[0]) if self.output_features else None
            problems = [f"{d} is not an index of the {state_dim}-dim state" for d in self.relative_action_dims
                        if d >= state_dim]
            if action_dim is not None:
                problems += [f"{d} is not an index of the {action_dim}-dim action"
                             for d in self.relative_action_dims if d >= action_dim]
            problems += [f"{d} is snapped as a binary command (`binary_action_dims`)"
                         for d in self.relative_action_dims if d in (self.binary_action_dims or ())]
            problems += [f"{d} is hidden from the policy (`ignored_state_dims`)"
                         for d in self.relative_action_dims if d in self.ignored_state_dims]
            if problems:
                raise ValueError(f"`relative_action_dims` {list(self.relative_action_dims)}: "
                                 + "; ".join(problems))
        expected = {
            OBS_STATE: FeatureType.STATE,
            OBS_POINT_CLOUD: FeatureType.STATE,
            OBS_ENV_STATE: FeatureType.ENV,
        }
        for key in (self.observation_key, OBS_STATE):
            if inputs[key].type is not expected[key]:
                raise ValueError(f"'{key}' must be a {expected[key].name} feature. Got {inputs[key].type}.")

    @property
    def observation_key(self) -> str:
        """The observation the tokens come from: the point cloud, else the privileged object poses."""
        inputs = self.input_features or {}
        return OBS_POINT_CLOUD if OBS_POINT_CLOUD in inputs or OBS_ENV_STATE not in inputs else OBS_ENV_STATE

    @property
    def uses_point_cloud(self) -> bool:
        return self.observation_key == OBS_POINT_CLOUD

    @property
    def token_channels(self) -> int:
        """Channels per observation token: `point_channels` per point, 7 per object pose."""
        return self.point_channels if self.uses_point_cloud else POSE_CHANNELS

    @property
    def num_points(self) -> int:
        """Observation entities per step in the data: N points ((N, C) or flat (N * C,)), or K objects."""
        shape = self.input_features[self.observation_key].shape
        return int(math.prod(shape)) // self.token_channels

    @property
    def num_tokens(self) -> int:
        """Observation tokens per step the model reads: `points_per_step` of the N points (all if 0), or K."""
        n = self.num_points
        if not self.uses_point_cloud or not self.points_per_step:
            return n
        if self.points_per_step > n:
            raise ValueError(f"`points_per_step` ({self.points_per_step}) exceeds the cloud's {n} points.")
        return self.points_per_step

    @property
    def observation_delta_indices(self) -> list:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list:
        return list(range(1 - self.n_obs_steps, 1 - self.n_obs_steps + self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None
