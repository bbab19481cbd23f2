"""Relational distillation math (paper Eq. 4, Eq. 6, Appendix B)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F  # noqa: N812

from lerobot_bavo.teacher.relations import (
    dynamics_weights,
    pairwise_distances,
    relation_matrix,
    relational_losses,
    student_relations,
    teacher_relations,
    weighted_l1,
)

S2 = math.sqrt(2.0)
S5 = math.sqrt(5.0)
# Unit square (0,0), (1,0), (0,1), (1,1): four edges of length 1, two diagonals of length sqrt 2.
SQUARE = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dtype=torch.float64)
SQUARE_DIST = torch.tensor(
    [
        [0.0, 1.0, 1.0, S2],
        [1.0, 0.0, S2, 1.0],
        [1.0, S2, 0.0, 1.0],
        [S2, 1.0, 1.0, 0.0],
    ],
    dtype=torch.float64,
)
SQUARE_MEAN = (4 * 1.0 + 2 * S2) / 6  # mean over the 6 pairs p < q
# Future: point 3 moves from (1,1) to (2,2); 0-3 becomes 2 sqrt 2, 1-3 and 2-3 become sqrt 5.
SQUARE_FUT = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 2.0]], dtype=torch.float64)
SQUARE_FUT_DIST = torch.tensor(
    [
        [0.0, 1.0, 1.0, 2 * S2],
        [1.0, 0.0, S2, S5],
        [1.0, S2, 0.0, S5],
        [2 * S2, S5, S5, 0.0],
    ],
    dtype=torch.float64,
)


def test_pairwise_distances_square():
    torch.testing.assert_close(pairwise_distances(SQUARE), SQUARE_DIST)
    assert (pairwise_distances(SQUARE).diagonal() == 0).all()


def test_relation_matrix_hand_computed():
    torch.testing.assert_close(relation_matrix(SQUARE, SQUARE, eps=0.0), SQUARE_DIST / SQUARE_MEAN)
    eps = 1e-6
    torch.testing.assert_close(relation_matrix(SQUARE, SQUARE, eps=eps), SQUARE_DIST / (SQUARE_MEAN + eps))
    # Relations are scale- and translation-invariant when X = Y (up to eps).
    torch.testing.assert_close(
        relation_matrix(3 * SQUARE + 7, 3 * SQUARE + 7, eps=0.0), SQUARE_DIST / SQUARE_MEAN
    )
    # Y gives the distances, X the scale.
    torch.testing.assert_close(relation_matrix(SQUARE, 2 * SQUARE, eps=0.0), SQUARE_DIST / (2 * SQUARE_MEAN))


def test_teacher_relations_hand_computed():
    R, dR = teacher_relations(SQUARE, SQUARE_FUT, eps=0.0)
    torch.testing.assert_close(R, SQUARE_DIST / SQUARE_MEAN)
    # dR is normalised by the CURRENT mean distance.
    torch.testing.assert_close(dR, (SQUARE_FUT_DIST - SQUARE_DIST) / SQUARE_MEAN)
    # Only pairs touching point 3 change.
    assert dR[0, 1] == 0 and dR[0, 2] == 0 and dR[1, 2] == 0
    torch.testing.assert_close(dR[0, 3], torch.tensor(S2 / SQUARE_MEAN, dtype=torch.float64))


def test_dynamics_weights_hand_computed():
    _, dR = teacher_relations(SQUARE, SQUARE_FUT, eps=0.0)
    # a_i = 1/3 sum_{j != i} |dR_ij|; the common 1/(3 m) factor cancels in q:
    # a ~ [sqrt2, sqrt5-1, sqrt5-1, sqrt2 + 2(sqrt5-1)], sum ~ 2 sqrt2 + 4(sqrt5-1).
    total = 2 * S2 + 4 * (S5 - 1)
    q = (
        torch.tensor([4 * S2, 4 * (S5 - 1), 4 * (S5 - 1), 4 * (S2 + 2 * (S5 - 1))], dtype=torch.float64)
        / total
    )
    torch.testing.assert_close(q[3], torch.tensor(2.0, dtype=torch.float64))  # moving point: twice the mean
    b = 0.5 + 0.5 * q
    expected = torch.sqrt(b[:, None] * b[None, :])
    w = dynamics_weights(dR)
    torch.testing.assert_close(w, expected)
    # q has unit mean: recover q from the diagonal w_ii = b_i.
    q_rec = 2 * w.diagonal() - 1
    torch.testing.assert_close(q_rec.mean(), torch.tensor(1.0, dtype=torch.float64))


def test_dynamics_weights_properties_random():
    g = torch.Generator().manual_seed(0)
    Z0 = torch.randn(3, 16, 8, generator=g)
    ZF = Z0 + 0.3 * torch.randn(3, 16, 8, generator=g)
    _, dR = teacher_relations(Z0, ZF)
    w = dynamics_weights(dR)
    assert w.shape == (3, 16, 16)
    torch.testing.assert_close(w, w.transpose(-1, -2))
    assert (w > 0).all() and (w >= 0.5 - 1e-6).all()
    q = 2 * w.diagonal(dim1=-2, dim2=-1) - 1  # w_ii = b_i
    torch.testing.assert_close(q.mean(dim=-1), torch.ones(3))


def test_dynamics_weights_static_sample_is_uniform():
    dR = torch.zeros(2, 5, 5)
    dR[1, 0, 1] = dR[1, 1, 0] = 0.5  # second sample moves, first does not
    w = dynamics_weights(dR)
    assert torch.equal(w[0], torch.ones(5, 5))
    assert not torch.equal(w[1], torch.ones(5, 5))
    assert torch.isfinite(w).all()


def test_weighted_l1_uniform_and_hand_computed():
    A = torch.tensor([[9.0, 1.0, -2.0], [-50.0, 9.0, 3.0], [70.0, 80.0, 9.0]])  # lower/diag ignored
    assert weighted_l1(A).item() == pytest.approx((1 + 2 + 3) / 3)
    w = torch.tensor([[100.0, 1.0, 2.0], [1.0, 100.0, 3.0], [2.0, 3.0, 100.0]])
    # (1*1 + 2*2 + 3*3) / (1 + 2 + 3) = 14 / 6
    assert weighted_l1(A, w).item() == pytest.approx(14 / 6)
    # Uniform weights give the plain mean over i < j.
    assert weighted_l1(A, torch.full((3, 3), 4.0)).item() == pytest.approx(weighted_l1(A).item())


def test_batch_matches_loop():
    g = torch.Generator().manual_seed(1)
    B, N, D = 4, 10, 6
    Z0, ZF = torch.randn(B, N, D, generator=g), torch.randn(B, N, D, generator=g)
    H, HF = torch.randn(B, N, 5, generator=g), torch.randn(B, N, 5, generator=g)
    R, dR = teacher_relations(Z0, ZF)
    w = dynamics_weights(dR)
    Rs, dRs = student_relations(H, HF)
    L_cur, L_evo = relational_losses(H, HF, R, dR)
    loop_cur, loop_evo = [], []
    for b in range(B):
        Rb, dRb = teacher_relations(Z0[b], ZF[b])
        torch.testing.assert_close(R[b], Rb)
        torch.testing.assert_close(dR[b], dRb)
        torch.testing.assert_close(relation_matrix(ZF[b], Z0[b]), Rb + dRb)
        torch.testing.assert_close(w[b], dynamics_weights(dRb))
        Rsb, dRsb = student_relations(H[b], HF[b])
        torch.testing.assert_close(Rs[b], Rsb)
        torch.testing.assert_close(dRs[b], dRsb)
        lc, le = relational_losses(H[b], HF[b], Rb, dRb)
        loop_cur.append(lc)
        loop_evo.append(le)
    torch.testing.assert_close(L_cur, torch.stack(loop_cur).mean())
    torch.testing.assert_close(L_evo, torch.stack(loop_evo).mean())
    torch.testing.assert_close(
        weighted_l1(dR, w), torch.stack([weighted_l1(dR[b], w[b]) for b in range(B)]).mean()
    )


def test_student_relations_use_l2_normalised_tokens():
    g = torch.Generator().manual_seed(2)
    H, HF = torch.randn(8, 4, generator=g), torch.randn(8, 4, generator=g)
    scale = torch.rand(8, 1, generator=g) + 0.5  # per-token rescaling does not change anything
    Rs, dRs = student_relations(H * scale, HF * 3.0)
    Rn, dRn = teacher_relations(F.normalize(H, dim=-1), F.normalize(HF, dim=-1))
    torch.testing.assert_close(Rs, Rn)
    torch.testing.assert_close(dRs, dRn)


def test_relational_losses_zero_iff_relations_match():
    g = torch.Generator().manual_seed(3)
    H = torch.randn(2, 12, 16, generator=g, requires_grad=True)
    HF = torch.randn(2, 12, 16, generator=g, requires_grad=True)
    with torch.no_grad():
        R_T, dR_T = teacher_relations(F.normalize(H, dim=-1), F.normalize(HF, dim=-1))
    L_cur, L_evo = relational_losses(H, HF, R_T, dR_T)
    assert L_cur.item() == 0.0 and L_evo.item() == 0.0

    Z0, ZF = torch.randn(2, 12, 32, generator=g), torch.randn(2, 12, 32, generator=g)
    R_T, dR_T = teacher_relations(Z0, ZF)
    L_cur, L_evo = relational_losses(H, HF, R_T, dR_T)
    assert L_cur.item() > 0 and L_evo.item() > 0
    (L_cur + L_evo).backward()
    assert H.grad is not None and torch.isfinite(H.grad).all() and H.grad.abs().sum() > 0
    assert HF.grad is not None and torch.isfinite(HF.grad).all() and HF.grad.abs().sum() > 0
    # L_cur does not depend on the future tokens.
    HF.grad = None
    L_cur, _ = relational_losses(H, HF, R_T, dR_T)
    L_cur.backward()
    assert HF.grad is None or HF.grad.abs().sum() == 0


def test_gradients_finite_with_duplicate_points():
    g = torch.Generator().manual_seed(4)
    X = torch.randn(6, 5, generator=g)
    X[1] = X[0]
    X[4] = X[0]
    X.requires_grad_()
    R = relation_matrix(X, X)
    assert R[0, 1] == 0 and R[0, 4] == 0 and (R.diagonal() == 0).all()
    R.sum().backward()
    assert torch.isfinite(X.grad).all()

    # All points identical: mean distance 0, R = 0 / eps = 0, still finite.
    Y = torch.ones(5, 3, requires_grad=True)
    R = relation_matrix(Y, Y)
    assert torch.equal(R, torch.zeros(5, 5))
    R.sum().backward()
    assert torch.isfinite(Y.grad).all()

    # Duplicate student tokens through the full loss.
    H = torch.randn(2, 8, 16, generator=g)
    H[:, 3] = H[:, 2]
    HF = H.clone()
    HF[:, 5] = 2.0 * HF[:, 1]  # same direction: duplicate after L2 normalisation
    H.requires_grad_()
    HF.requires_grad_()
    R_T, dR_T = teacher_relations(torch.randn(2, 8, 4, generator=g), torch.randn(2, 8, 4, generator=g))
    L_cur, L_evo = relational_losses(H, HF, R_T, dR_T)
    (L_cur + L_evo).backward()
    assert torch.isfinite(H.grad).all() and torch.isfinite(HF.grad).all()


def test_half_precision_input_is_computed_in_float32():
    X = SQUARE.to(torch.bfloat16)
    R = relation_matrix(X, X, eps=0.0)
    assert R.dtype == torch.float32
    torch.testing.assert_close(R, (SQUARE_DIST / SQUARE_MEAN).float())


def test_shape_errors():
    with pytest.raises(ValueError):
        relation_matrix(torch.zeros(4, 2), torch.zeros(5, 2))
    with pytest.raises(ValueError):
        relation_matrix(torch.zeros(1, 2), torch.zeros(1, 2))
    with pytest.raises(ValueError):
        weighted_l1(torch.zeros(3, 4))
    with pytest.raises(ValueError):
        relational_losses(torch.zeros(4, 3), torch.zeros(4, 3), torch.zeros(5, 5), torch.zeros(5, 5))
