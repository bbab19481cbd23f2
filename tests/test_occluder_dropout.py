"""The occluder-dropout training recipe: which cloud points lie on the panel (hand-placed points around a
known pose), the point reordering (hand-computed), and that a policy reads the panel-free scene points."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_bavo.envs.occlusion import (
    OCCLUDER_HALF_EXTENTS,
    OCCLUDER_POINT_MARGIN,
    panel_rotation_facing,
    points_on_occluder,
)
from lerobot_bavo.policies.augment import occluder_dropout, points_last_order, reorder_points
from lerobot_bavo.sim.transforms import quat_from_matrix


def test_points_on_the_panel_are_those_inside_its_box_plus_the_margin():
    rot = panel_rotation_facing(np.array([0.6, 0.8, -0.4]))
    centre = np.array([0.1, -0.2, 0.25])
    pose = np.r_[centre, quat_from_matrix(rot)]
    normal, width, height = rot.T
    hw = OCCLUDER_HALF_EXTENTS[1] + OCCLUDER_POINT_MARGIN
    pts = np.stack([
        centre,                                         # centre: on it
        centre + width * (hw - 1e-3) + height * 0.05,   # near the rim, inside the margin: on it
        centre + width * (hw + 1e-3),                   # just past the rim: not
        # camera-facing face side, within thickness + margin: on it
        centre - normal * 0.012,
        centre + normal * 0.02,                         # 2 cm behind: not
        centre + height * 0.2,                          # far above: not
    ])
    assert points_on_occluder(pts, pose).tolist() == [True, True, False, True, False, False]
    # batched (frames, N, 3) with per-frame poses; a zero quaternion means no occluder in that frame
    both = points_on_occluder(np.stack([pts, pts]), np.stack([pose, np.r_[centre, 0, 0, 0, 0]]))
    assert both[0].tolist() == [True, True, False, True, False, False] and not both[1].any()
    with pytest.raises(ValueError, match="pose"):
        points_on_occluder(pts, pose[:6])


def test_chosen_samples_put_labelled_points_last_in_stored_order():
    labels = torch.tensor([[[0, 1, 0, 1, 0], [1, 0, 0, 0, 0]],
                           [[1, 1, 0, 0, 0], [1, 1, 0, 0, 0]]], dtype=torch.bool)
    order = points_last_order(labels, torch.tensor([True, False]))
    assert order.tolist() == [[[0, 2, 4, 1, 3], [1, 2, 3, 4, 0]], [[0, 1, 2, 3, 4], [0, 1, 2, 3, 4]]]
    flat = torch.arange(10.0).reshape(1, 1, 10).repeat(2, 2, 1)  # 5 points x 2 channels, both steps
    out = reorder_points(flat, order)
    assert out[0, 0].tolist() == [0, 1, 4, 5, 8, 9, 2, 3, 6, 7]
    assert out[0, 1].tolist() == [2, 3, 4, 5, 6, 7, 8, 9, 0, 1]
    assert torch.equal(out[1], flat[1])
    # a feature without the time axis follows the current (last) step
    assert reorder_points(torch.arange(5.0).reshape(1, 5).repeat(2, 1), order)[0].tolist() == [1, 2, 3, 4, 0]


def test_dropout_moves_cloud_and_teacher_targets_together_and_keeps_the_rest():
    g = torch.Generator().manual_seed(0)
    b, to, n = 64, 2, 8
    cloud = torch.rand(b, to, n * 6, generator=g)
    z0 = torch.rand(b, to, n * 3, generator=g)
    labels = torch.rand(b, to, n, generator=g) < 0.3
    batch = {"pc": cloud, "z0": z0, "state": torch.rand(b, to, 4, generator=g)}
    out = occluder_dropout(batch, labels, ["pc", "z0"], p=0.5, generator=torch.Generator().manual_seed(1))
    assert out["state"] is batch["state"]
    moved = ~torch.all(out["pc"] == cloud, dim=(1, 2))
    assert 0 < int(moved.sum()) < b  # about half the samples
    for i in range(b):
        pts, zs = cloud[i].reshape(to, n, 6), z0[i].reshape(to, n, 3)
        got_pts, got_z = out["pc"][i].reshape(to, n, 6), out["z0"][i].reshape(to, n, 3)
        for t in range(to):
            expect = (torch.cat([torch.nonzero(~labels[i, t])[:, 0], torch.nonzero(labels[i, t])[:, 0]])
                      if moved[i] else torch.arange(n))
            assert torch.equal(got_pts[t], pts[t][expect]) and torch.equal(got_z[t], zs[t][expect])
    assert occluder_dropout(batch, labels, ["pc"], p=0.0)["pc"] is not None
    assert torch.equal(occluder_dropout(batch, labels, ["pc"], p=0.0)["pc"], cloud)


def test_policy_reads_the_panel_free_points_in_training_only():
    from lerobot.configs import FeatureType, PolicyFeature

    from lerobot_bavo.features import TEACHER_OCCLUDER
    from lerobot_bavo.policies import ManiFlowConfig, ManiFlowPolicy

    n, m = 8, 4
    inputs = {"observation.point_cloud": PolicyFeature(FeatureType.STATE, (n * 6,)),
              "observation.state": PolicyFeature(FeatureType.STATE, (21,))}
    cfg = ManiFlowConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (21,))},
        preset="cpu_fast",
        device="cpu",
        points_per_step=m,
        occluder_dropout=1.0,
    )
    policy = ManiFlowPolicy(cfg)
    cloud = torch.arange(2 * 2 * n * 6, dtype=torch.float32).reshape(2, 2, n * 6)
    labels = torch.zeros(2, 2, n)
    labels[:, :, :3] = 1  # the first three points are the panel's
    batch = {"observation.point_cloud": cloud, TEACHER_OCCLUDER: labels}
    # what it reads
    seen = policy.training_batch(batch)["observation.point_cloud"].reshape(2, 2, n, 6)[:, :, :m]
    assert torch.equal(seen, cloud.reshape(2, 2, n, 6)[:, :, 3:3 + m])  # points 3..6: the scene's, FPS order
    policy.eval()
    assert policy.training_batch(batch) is batch  # inference never reorders
    policy.train()
    with pytest.raises(KeyError, match="occluder"):
        policy.training_batch({"observation.point_cloud": cloud})
    # reading every point, moving the panel's points to the end would leave them read: refused, not ignored
    for reads_all in (n, 0):
        cfg.points_per_step = reads_all
        with pytest.raises(ValueError, match="reads all 8"):
            policy.training_batch(batch)


def test_batched_quaternion_matrices_equal_mujocos():
    import mujoco

    from lerobot_bavo.sim.transforms import matrices_from_quats

    q = np.random.default_rng(0).standard_normal((5, 3, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    expected = np.zeros((5, 3, 9))
    for i in np.ndindex(5, 3):
        mujoco.mju_quat2Mat(expected[i], q[i])
    np.testing.assert_allclose(matrices_from_quats(q), expected.reshape(5, 3, 3, 3), atol=1e-12)
