"""Relational distillation math for A-FAR (paper Sec. 4.2, Sec. 4.4 and Appendix B).

Pure torch functions shared by the teacher cache writer and the A-FAR loss. Every function takes
point-aligned token sets with an optional leading batch dimension: ``(N, D)`` or ``(B, N, D)``
(relation matrices are then ``(N, N)`` or ``(B, N, N)``).

- ``relation_matrix``   paper Eq. 4: R(Y|X)_ij = ||y_i - y_j||_2 / (mean_{p<q} ||x_p - x_q||_2 + eps)
- ``teacher_relations`` paper Eq. 4: R^T = R(Z^0|Z^0), dR^T = R(Z^F|Z^0) - R^T
- ``dynamics_weights``  Appendix B, Eq. afar_dynamic_weight: a_i, q_i, b_i, w_ij = sqrt(b_i b_j)
- ``weighted_l1``       Appendix B: ||A||_{1,w} = sum_{i<j} w_ij |A_ij| / sum_{i<j} w_ij
- ``relational_losses`` paper Eq. 6: L_cur (uniform) and L_evo (dynamics-weighted)

Only the strict upper triangle (i < j) enters the losses: relation matrices are symmetric with a
zero diagonal, so it carries all the information.
"""

from __future__ import annotations

import torch

__all__ = [
    "pairwise_distances",
    "relation_matrix",
    "teacher_relations",
    "dynamics_weights",
    "weighted_l1",
    "student_relations",
    "relational_losses",
]


def _check_points(X: torch.Tensor, name: str) -> None:
    if X.ndim not in (2, 3):
        raise ValueError(f"{name} must be (N, D) or (B, N, D), got shape {tuple(X.shape)}")
    if X.shape[-2] < 2:
        raise ValueError(f"{name} needs at least 2 points to form a pair, got N={X.shape[-2]}")


def _check_square(A: torch.Tensor, name: str) -> None:
    if A.ndim not in (2, 3) or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"{name} must be (N, N) or (B, N, N), got shape {tuple(A.shape)}")
    if A.shape[-1] < 2:
        raise ValueError(f"{name} needs N >= 2, got N={A.shape[-1]}")


def _upper_mask(A: torch.Tensor) -> torch.Tensor:
    """(N, N) of A's dtype: 1 on the strict upper triangle (i < j), else 0.

    The sums over pairs i < j below are masked sums over the whole matrix rather than sums of the gathered
    triangle: same values, and elementwise products instead of a gather (and a scatter in the backward pass),
    which cost several times more on the CPU.
    """
    n = A.shape[-1]
    return torch.ones(n, n, dtype=A.dtype, device=A.device).triu_(diagonal=1)


def pairwise_distances(X: torch.Tensor) -> torch.Tensor:
    """Euclidean distances ||x_i - x_j||_2 among the rows of X, with gradients safe at zero.

    Args:
        X: (N, D) or (B, N, D).

    Returns:
        (N, N) or (B, N, N); exactly zero on the diagonal and for pairs whose squared distance
        is at or below the floor ``eps(dtype)**2``.

    Memory is O(B N^2): squared distances come from the Gram matrix of the centred points (pairwise
    distances are translation invariant; centring shrinks the norms and so the cancellation error of
    |x_i|^2 + |x_j|^2 - 2 x_i.x_j). Where the squared distance is at or below the floor the distance
    is set to exactly 0 and its gradient to 0, so identical points never produce inf/NaN gradients
    (the gradient of sqrt is infinite at 0). Half-precision inputs are computed in float32 with
    autocast disabled, and the result is float32.
    """
    _check_points(X, "X")
    if X.dtype in (torch.float16, torch.bfloat16):
        X = X.float()
    return _PairwiseDistances.apply(X)


def _gram_update(X: torch.Tensor):
    """torch.baddbmm for batched (B, N, D) operands, torch.addmm for (N, D) ones."""
    return torch.baddbmm if X.ndim == 3 else torch.addmm


class _PairwiseDistances(torch.autograd.Function):
    """`pairwise_distances` of float32/64 X, with the gradient written out.

    Why: autograd's gradient goes back through the square root, the clamp, the Gram product (twice, one of
    them transposed) and the squared norms and the centring, a dozen passes over (B, N, D) and (B, N, N).
    Written out, with S = dL/d(squared distance) = dL/dD / (2 D) where D > 0 (else 0) and G = S + S^T:
    dL/dXc_i = 2 (sum_j G_ij) Xc_i - 2 sum_j G_ij Xc_j, one batched matrix multiply-add; and dL/dX = dL/dXc,
    since these sum to zero over the points (G is symmetric), which is what the centring's gradient would
    remove. Same gradient up to rounding. Not twice differentiable.
    """

    @staticmethod
    def forward(ctx, X: torch.Tensor) -> torch.Tensor:
        with torch.autocast(device_type=X.device.type, enabled=False):
            Xc = X - X.mean(dim=-2, keepdim=True)  # (..., N, D)
            sq = (Xc * Xc).sum(dim=-1)  # (..., N)
            # |x_i|^2 + |x_j|^2 - 2 x_i.x_j in one (batched) matrix multiply-add
            norms = sq.unsqueeze(-1) + sq.unsqueeze(-2)
            sqdist = _gram_update(X)(norms, Xc, Xc.transpose(-1, -2), alpha=-2.0)
            floor = torch.finfo(sqdist.dtype).eps ** 2
            positive = sqdist > floor
            positive.diagonal(dim1=-2, dim2=-1).fill_(False)
            D = torch.where(positive, torch.sqrt(sqdist.clamp_min(floor)), 0.0)
        ctx.save_for_backward(Xc, D)
        return D

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_D: torch.Tensor) -> torch.Tensor:
        Xc, D = ctx.saved_tensors
        with torch.autocast(device_type=Xc.device.type, enabled=False):
            S = torch.where(D > 0, grad_D / (2.0 * D), 0.0)  # D > 0 exactly where the distance is kept
            G = S + S.transpose(-1, -2)
            return _gram_update(Xc)(Xc * G.sum(dim=-1, keepdim=True), G, Xc, beta=2.0, alpha=-2.0)


def _mean_pair_distance(D: torch.Tensor) -> torch.Tensor:
    """mean_{p<q} D_pq of a (..., N, N) distance matrix (`pairwise_distances`), shape (..., 1, 1) for
    broadcasting.

    D is symmetric with a zero diagonal, so this is the mean over all N (N - 1) ordered pairs: a plain sum,
    without masking the upper triangle (same value up to rounding).
    """
    n = D.shape[-1]
    return D.sum(dim=(-2, -1), keepdim=True) / (n * (n - 1))


def _relation_from_distances(D_Y: torch.Tensor, D_X: torch.Tensor, eps: float) -> torch.Tensor:
    return D_Y / (_mean_pair_distance(D_X) + eps)


def relation_matrix(Y: torch.Tensor, X: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Paper Eq. 4: R(Y|X)_ij = ||y_i - y_j||_2 / (mean_{p<q} ||x_p - x_q||_2 + eps).

    Args:
        Y: (N, D) or (B, N, D), the points whose pairwise distances are measured.
        X: same leading shape as Y (feature width may differ), the points giving the scale.
        eps: added to the mean pairwise distance of X.

    Returns:
        (N, N) or (B, N, N).
    """
    _check_points(Y, "Y")
    _check_points(X, "X")
    if Y.shape[:-1] != X.shape[:-1]:
        raise ValueError(f"Y and X must share (B,) N; got Y {tuple(Y.shape)} and X {tuple(X.shape)}")
    return _relation_from_distances(pairwise_distances(Y), pairwise_distances(X), eps)


def teacher_relations(
    Z0: torch.Tensor, ZF: torch.Tensor, eps: float = 1e-6
) -> tuple[torch.Tensor, torch.Tensor]:
    """Paper Eq. 4: R^T = R(Z^0|Z^0) and dR^T = R(Z^F|Z^0) - R^T.

    Args:
        Z0: (N, d_T) or (B, N, d_T) teacher features of the current queries q^0.
        ZF: same shape, teacher features of the future queries q^F (point-aligned with Z0).

    Returns:
        (R, dR), each (N, N) or (B, N, N). Both are normalised by the *current* mean distance.
    """
    _check_points(Z0, "Z0")
    _check_points(ZF, "ZF")
    if Z0.shape[:-1] != ZF.shape[:-1]:
        raise ValueError(f"Z0 and ZF must be point-aligned; got {tuple(Z0.shape)} and {tuple(ZF.shape)}")
    D0 = pairwise_distances(Z0)
    scale = _mean_pair_distance(D0) + eps  # the current one, for both
    R = D0 / scale
    return R, pairwise_distances(ZF) / scale - R


def dynamics_weights(dR: torch.Tensor) -> torch.Tensor:
    """Appendix B dynamics-aware pair weights from the teacher relation change dR.

        a_i  = 1/(N-1) sum_{j != i} |dR_ij|
        q_i  = N a_i / sum_k a_k          (unit mean over the N points)
        b_i  = 0.5 + 0.5 q_i
        w_ij = sqrt(b_i b_j)

    Convention for a static sample (sum_k a_k == 0, i.e. dR == 0): the paper's q is 0/0 there; we
    set q_i = 1 for every point, the unit-mean uniform weighting, so w_ij = 1. This is decided per
    sample in a batch.

    Args:
        dR: (N, N) or (B, N, N).

    Returns:
        w: (N, N) or (B, N, N), symmetric, every entry >= 0.5.
    """
    _check_square(dR, "dR")
    b = _point_weights(dR)
    return torch.sqrt(b.unsqueeze(-1) * b.unsqueeze(-2))


def _point_weights(dR: torch.Tensor) -> torch.Tensor:
    """b (..., N) of `dynamics_weights` (w_ij = sqrt(b_i b_j)), from dR (..., N, N)."""
    n = dR.shape[-1]
    # sum_{j != i} |dR_ij|: the row sum less the diagonal term (exactly the masked sum when it is 0)
    a = (dR.abs().sum(dim=-1) - dR.diagonal(dim1=-2, dim2=-1).abs()) / (n - 1)  # (..., N)
    total = a.sum(dim=-1, keepdim=True)  # (..., 1)
    moving = total > 0
    q = torch.where(moving, n * a / torch.where(moving, total, torch.ones_like(total)), torch.ones_like(a))
    return 0.5 + 0.5 * q  # (..., N)


def weighted_l1(A: torch.Tensor, w: torch.Tensor | None = None, per_sample: bool = False) -> torch.Tensor:
    """Appendix B weighted norm: ||A||_{1,w} = sum_{i<j} w_ij |A_ij| / sum_{i<j} w_ij.

    Only the strict upper triangle of A and w is read. With ``w=None`` the weights are uniform, so
    the value is the plain mean of |A_ij| over i < j (the paper's L_cur). With a batch dimension the
    per-sample norms are averaged over the batch (each sample counts equally), or returned as they
    are with ``per_sample=True``.

    Args:
        A: (N, N) or (B, N, N).
        w: None, or non-negative weights of A's shape (or (N, N), broadcast over the batch).
        per_sample: return the (B,) per-sample norms instead of their mean.

    Returns:
        Scalar tensor, or (B,) (a scalar for unbatched A) with ``per_sample``.
    """
    _check_square(A, "A")
    upper = _upper_mask(A)
    pairs = (-2, -1)
    if w is not None:
        _check_square(w, "w")
        if w.shape[-1] != A.shape[-1] or (w.ndim == 3 and w.shape != A.shape):
            raise ValueError(f"w must be (N, N) or match A {tuple(A.shape)}, got {tuple(w.shape)}")
        wu = w * upper
        norms = (wu * A.abs()).sum(dim=pairs) / wu.sum(dim=pairs)
    else:
        n = A.shape[-1]
        norms = (A.abs() * upper).sum(dim=pairs) / (n * (n - 1) // 2)
    return norms if per_sample else norms.mean()


def student_relations(
    H_cur: torch.Tensor, H_fut: torch.Tensor, eps: float = 1e-6
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sec. 4.4: the teacher's operator applied to the normalised student tokens.

    "Normalised" is read as per-token L2 normalisation along the feature dimension
    (``F.normalize(H, dim=-1)``): it puts the student's tokens on the unit sphere so the relation
    scale does not depend on the token norm. Then R^S = R(H^|H^) and dR^S = R(H^_F|H^) - R^S.

    Args:
        H_cur: (N, d) or (B, N, d) current point tokens H_t.
        H_fut: same shape, predicted future point tokens from the WorldQueryFormer.

    Returns:
        (R_S, dR_S), each (N, N) or (B, N, N).
    """
    return teacher_relations(_unit_rows(H_cur), _unit_rows(H_fut), eps=eps)


def _unit_rows(H: torch.Tensor) -> torch.Tensor:
    """``F.normalize(H, dim=-1)`` (rows divided by max(norm, 1e-12)), half precision computed in float32 (as
    F.normalize does under autocast), with its gradient written out (``_UnitRows``)."""
    if H.dtype in (torch.float16, torch.bfloat16):
        H = H.float()
    return _UnitRows.apply(H)


class _UnitRows(torch.autograd.Function):
    """Why: autograd's gradient of x / max(|x|, eps) takes about twice the passes over (..., N, d) of the
    written-out one, dL/dx = (g - y <g, y>) / max(|x|, eps) for y = x / max(|x|, eps), where the
    <g, y> term is dropped for rows with |x| < eps (where the clamp holds the divisor constant)."""

    EPS = 1e-12  # F.normalize's

    @staticmethod
    def forward(ctx, H: torch.Tensor) -> torch.Tensor:
        with torch.autocast(device_type=H.device.type, enabled=False):
            norm = torch.linalg.vector_norm(H, dim=-1, keepdim=True)
            divisor = norm.clamp_min(_UnitRows.EPS)
            Y = H / divisor
        ctx.save_for_backward(Y, divisor, norm >= _UnitRows.EPS)
        return Y

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        Y, divisor, unclamped = ctx.saved_tensors
        with torch.autocast(device_type=Y.device.type, enabled=False):
            along = (grad * Y).sum(dim=-1, keepdim=True) * unclamped
            return torch.addcmul(grad, Y, along, value=-1.0) / divisor


def relational_losses(
    H_cur: torch.Tensor,
    H_fut: torch.Tensor,
    R_T: torch.Tensor,
    dR_T: torch.Tensor,
    eps: float = 1e-6,
    per_sample: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Paper Eq. 6: L_cur = ||R^S - R^T||_1 (uniform) and L_evo = ||dR^S - dR^T||_{1,w}.

    The weights w = dynamics_weights(dR^T) come from the teacher only and are computed on a
    detached copy (they are part of the target). The caller combines the terms as
    ``lambda_rel / 2 * (L_cur + L_evo)``.

    The teacher relations are symmetric with a zero diagonal (as ``teacher_relations`` makes
    them), and so are the student's: each norm over the pairs i < j is then taken over all ordered
    pairs i != j, half of it (``_symmetric_pair_norm``): the value of ``weighted_l1`` up to rounding,
    without the triangle mask or the (N, N) weight matrix.

    Args:
        H_cur: (N, d) or (B, N, d) current student tokens.
        H_fut: same shape, predicted future student tokens.
        R_T:  (N, N) or (B, N, N) teacher current relations.
        dR_T: same shape, teacher relation evolution.
        per_sample: return the (B,) per-sample terms instead of their batch means (see ``weighted_l1``).

    Returns:
        (L_cur, L_evo), scalar tensors (or (B,) with ``per_sample``).
    """
    R_S, dR_S = student_relations(H_cur, H_fut, eps=eps)
    if R_T.shape != R_S.shape or dR_T.shape != R_S.shape:
        raise ValueError(
            f"teacher targets must match the student relations {tuple(R_S.shape)}; "
            f"got R_T {tuple(R_T.shape)} and dR_T {tuple(dR_T.shape)}"
        )
    R_T = R_T.to(R_S.dtype)
    dR_T = dR_T.to(R_S.dtype)
    L_cur = _symmetric_pair_norm(R_S - R_T)
    L_evo = _symmetric_pair_norm(dR_S - dR_T, _point_weights(dR_T.detach()))
    return (L_cur, L_evo) if per_sample else (L_cur.mean(), L_evo.mean())


def _symmetric_pair_norm(A: torch.Tensor, b: torch.Tensor | None = None) -> torch.Tensor:
    """``weighted_l1(A, w, per_sample=True)`` of a symmetric A (..., N, N) with a zero diagonal and weights
    w_ij = sqrt(b_i b_j) given by b (..., N) (``_point_weights``; uniform when None): the (...,) norms.

    Why: with A symmetric and zero on the diagonal, sum_{i<j} w_ij |A_ij| is half of the sum over all
    pairs, s^T |A| s with s = sqrt(b), and sum_{i<j} w_ij is half of (sum_i s_i)^2 - sum_i b_i: a
    matrix-vector product instead of the (N, N) weights, the triangle mask and their products. In
    float32 under autocast too, like the distances.
    """
    n = A.shape[-1]
    if b is None:
        return A.abs().sum(dim=(-2, -1)) / (n * (n - 1))
    with torch.autocast(device_type=A.device.type, enabled=False):
        s = b.sqrt()
        weighted = (A.abs() @ s.unsqueeze(-1)).squeeze(-1)  # (..., N): sum_j |A_ij| s_j
        return (weighted * s).sum(dim=-1) / (s.sum(dim=-1) ** 2 - b.sum(dim=-1))
