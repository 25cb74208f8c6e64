"""The training objective: finite values and finite gradients on degenerate input."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("torch")
import torch
from scotti.export.losses import (
    LossWeights,
    ScottiTargets,
    angle_mask,
    joint_angles,
    mpjae_deg,
    mpjpe_mm,
    scotti_loss,
)
from scotti.export.model import ScottiOutputs
from scotti.models import contract

pytestmark = pytest.mark.torch

B = 4


def standing_pose() -> torch.Tensor:
    """A plausible upright pose (19, 3) in metres, no two points shared."""
    g = torch.Generator().manual_seed(0)
    z = torch.tensor(
        [
            1.65,
            1.45,
            1.45,
            1.15,
            1.15,
            0.9,
            0.9,
            0.95,
            0.95,
            0.5,
            0.5,
            0.08,
            0.08,
            0.02,
            0.02,
            0.03,
            0.02,
            0.02,
            0.03,
        ]
    )
    y = torch.tensor([0.0, 0.2, -0.2, 0.25, -0.25, 0.27, -0.27, 0.1, -0.1, 0.1, -0.1, 0.1, -0.1])
    y = torch.cat([y, torch.tensor([0.12, 0.05, 0.1, -0.12, -0.05, -0.1])])
    x = torch.tensor([0.05] + [0.0] * 12 + [0.2, 0.18, -0.05, 0.2, 0.18, -0.05])
    return torch.stack([x, y, z], dim=-1) + 0.01 * torch.randn(19, 3, generator=g)


def outputs(pose: torch.Tensor, logits: torch.Tensor | None = None) -> ScottiOutputs:
    b = pose.shape[0]
    if logits is None:
        logits = torch.zeros(b, contract.NUM_ACTIONS)
    return ScottiOutputs(pose, logits, torch.full((b,), 0.5))


def grads_finite(*tensors: torch.Tensor) -> bool:
    return all(t.grad is not None and bool(torch.isfinite(t.grad).all()) for t in tensors)


def test_perfect_prediction_costs_almost_nothing() -> None:
    pose = standing_pose().expand(B, -1, -1)
    tgt = ScottiTargets(pose, torch.tensor([0, 1, 2, 3]), torch.full((B,), 0.5))
    logits = torch.full((B, contract.NUM_ACTIONS), -30.0)
    logits[torch.arange(B), tgt.action] = 30.0
    total, parts = scotti_loss(outputs(pose, logits), tgt)
    assert float(parts["mpjpe_mm"]) < 0.01
    assert float(parts["mpjae_deg"]) < 1e-3
    assert float(total) < 1e-3


def test_known_errors_in_paper_units() -> None:
    target = standing_pose().expand(B, -1, -1)
    shifted = target + torch.tensor([0.0, 0.0, 0.1])  # every joint 10 cm up: angles unchanged
    assert torch.allclose(mpjpe_mm(shifted, target), torch.full((B,), 100.0), atol=1e-3)
    assert torch.allclose(mpjae_deg(shifted, target), torch.zeros(B), atol=1e-3)


def test_joint_angle_of_straight_and_right_angle() -> None:
    pose = torch.zeros(19, 3)
    kp = contract.KP
    pose[kp["left_shoulder"]] = torch.tensor([0.0, 0.0, 1.0])
    pose[kp["left_elbow"]] = torch.tensor([0.0, 0.0, 0.7])
    pose[kp["left_wrist"]] = torch.tensor([0.0, 0.0, 0.4])  # straight arm: 0
    pose[kp["right_shoulder"]] = torch.tensor([0.0, 0.0, 1.0])
    pose[kp["right_elbow"]] = torch.tensor([0.0, 0.0, 0.7])
    pose[kp["right_wrist"]] = torch.tensor([0.3, 0.0, 0.7])  # right angle: pi/2
    angles = joint_angles(pose)
    assert float(angles[0]) == pytest.approx(0.0, abs=2e-3)
    assert float(angles[1]) == pytest.approx(math.pi / 2, abs=1e-4)


@pytest.mark.parametrize("case", ["all_zero", "coincident_pairs", "target_zero"])
def test_degenerate_poses_give_finite_values_and_gradients(case: str) -> None:
    pose = standing_pose().expand(B, -1, -1).clone()
    target = pose.clone()
    if case == "all_zero":  # every bone has zero length, every angle undefined
        pose = torch.zeros(B, 19, 3)
    elif case == "coincident_pairs":  # prediction equals the target exactly: |d| = 0
        pose[:, contract.KP["left_elbow"]] = pose[:, contract.KP["left_shoulder"]]
        target = pose.clone()
    else:
        target = torch.zeros(B, 19, 3)
    pred = pose.clone().requires_grad_(True)
    logits = torch.zeros(B, contract.NUM_ACTIONS, requires_grad=True)
    progress = torch.full((B,), 0.5, requires_grad=True)
    tgt = ScottiTargets(target, torch.tensor([0, 1, -1, 3]), torch.tensor([0.1, 0.2, 0.3, 1.0]))
    total, parts = scotti_loss(ScottiOutputs(pred, logits, progress), tgt)
    assert all(bool(torch.isfinite(v)) for v in parts.values()), parts
    total.backward()  # type: ignore[no-untyped-call]
    assert grads_finite(pred, logits, progress)


def test_pose_gradients_match_finite_differences() -> None:
    target = standing_pose().double()
    pred = (target + 0.03 * torch.randn(19, 3, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: mpjae_deg(p, target).sum(), (pred,))
    assert torch.autograd.gradcheck(lambda p: mpjpe_mm(p, target).sum(), (pred,))


def test_unlabelled_batch_has_zero_action_and_progress_never_nan() -> None:
    pred = standing_pose().expand(B, -1, -1).clone().requires_grad_(True)
    logits = torch.randn(B, contract.NUM_ACTIONS, requires_grad=True)
    progress = torch.rand(B, requires_grad=True)
    tgt = ScottiTargets(
        standing_pose().expand(B, -1, -1),
        torch.full((B,), contract.NO_ACTION),
        torch.full((B,), math.nan),
    )
    total, parts = scotti_loss(ScottiOutputs(pred, logits, progress), tgt)
    assert float(parts["action"]) == 0.0
    assert float(parts["progress"]) == 0.0
    assert bool(torch.isfinite(total))
    total.backward()  # type: ignore[no-untyped-call]
    assert grads_finite(pred, logits, progress)
    assert logits.grad is not None
    assert float(logits.grad.abs().max()) == 0.0


def test_standing_trains_the_action_head_but_never_the_progress_head() -> None:
    """Standing is a class of the action loss; its NaN progress is left out, gradient finite."""
    standing = contract.STANDING
    pose = standing_pose().expand(3, -1, -1)
    logits = torch.zeros(3, contract.NUM_ACTIONS, requires_grad=True)
    progress = torch.tensor([0.9, 0.1, 0.4], requires_grad=True)
    tgt = ScottiTargets(
        pose,
        torch.tensor([standing, contract.NO_ACTION, 0]),
        torch.tensor([math.nan, math.nan, 0.6]),
    )
    total, parts = scotti_loss(ScottiOutputs(pose, logits, progress), tgt)
    # Uniform logits: the cross-entropy of each of the two named frames is ln(9).
    assert float(parts["action"]) == pytest.approx(math.log(contract.NUM_ACTIONS), rel=1e-6)
    assert float(parts["progress"]) == pytest.approx(0.04, rel=1e-5)  # (0.4 - 0.6)^2 only
    total.backward()  # type: ignore[no-untyped-call]
    assert progress.grad is not None
    assert logits.grad is not None
    assert bool(torch.isfinite(progress.grad).all())
    assert bool(torch.isfinite(logits.grad).all())
    assert progress.grad[:2].abs().max() == 0.0  # standing and the transition: no pull
    assert logits.grad[0, standing] < 0  # the standing logit is pushed up
    assert logits.grad[1].abs().max() == 0.0  # the transition is out of the action loss


def test_a_number_on_a_standing_frame_is_not_trusted_as_progress() -> None:
    pose = standing_pose().expand(2, -1, -1)
    out = ScottiOutputs(pose, torch.zeros(2, contract.NUM_ACTIONS), torch.tensor([0.0, 0.5]))
    tgt = ScottiTargets(pose, torch.tensor([contract.STANDING, 1]), torch.tensor([1.0, 0.5]))
    _, parts = scotti_loss(out, tgt)
    assert float(parts["progress"]) == 0.0


def test_no_action_frames_are_ignored_and_nan_progress_masked() -> None:
    pose = standing_pose().expand(2, -1, -1)
    logits = torch.zeros(2, contract.NUM_ACTIONS)
    logits[1, 3] = 5.0  # a confident wrong answer on the unlabelled frame only
    pred = ScottiOutputs(pose, logits, torch.tensor([0.9, 0.25]))
    tgt = ScottiTargets(pose, torch.tensor([contract.NO_ACTION, 3]), torch.tensor([math.nan, 0.75]))
    _, parts = scotti_loss(pred, tgt)
    expected_ce = -torch.log_softmax(logits[1], dim=0)[3]
    assert float(parts["action"]) == pytest.approx(float(expected_ce), rel=1e-6)
    assert float(parts["progress"]) == pytest.approx(0.25, rel=1e-6)  # (0.25 - 0.75)^2


def test_weights_are_configurable_and_default_to_the_paper() -> None:
    assert LossWeights() == LossWeights(pose=0.01, action=1.0, progress=1.0)
    target = standing_pose().expand(B, -1, -1)
    pred = ScottiOutputs(target + 0.05, torch.randn(B, contract.NUM_ACTIONS), torch.rand(B))
    tgt = ScottiTargets(target, torch.tensor([0, 1, 2, 3]), torch.rand(B))
    w = LossWeights(pose=0.5, action=2.0, progress=3.0)
    total, parts = scotti_loss(pred, tgt, w)
    expected = 0.5 * parts["pose"] + 2.0 * parts["action"] + 3.0 * parts["progress"]
    assert float(total) == pytest.approx(float(expected), rel=1e-6)


def test_a_missing_keypoint_is_left_out_on_its_own() -> None:
    # Frame 0 exact; frame 1 off by 0.2 m on every axis with its nose unlabelled;
    # frame 2 entirely unlabelled. MPJPE: mean of 0 and 0.2 * sqrt(3) m over the
    # 18 labelled keypoints; frame 2 counts nowhere.
    target = standing_pose().expand(3, -1, -1).clone()
    pred = target.clone()
    pred[1] += 0.2
    pred[2] += 1.0
    target[1, contract.KP["nose"], 0] = math.nan
    target[2] = math.nan
    p = pred.clone().requires_grad_(True)
    out = ScottiOutputs(p, torch.zeros(3, contract.NUM_ACTIONS), torch.zeros(3))
    tgt = ScottiTargets(target, torch.tensor([0, 0, 0]), torch.tensor([0.0, 0.0, 0.0]))
    total, parts = scotti_loss(out, tgt)
    assert float(parts["mpjpe_mm"]) == pytest.approx(0.5 * 200.0 * math.sqrt(3.0), rel=1e-4)
    # A pure translation keeps every joint angle: MPJAE 0 over the angles present.
    assert float(parts["mpjae_deg"]) == pytest.approx(0.0, abs=1e-3)
    total.backward()  # type: ignore[no-untyped-call]
    assert grads_finite(p)
    assert p.grad is not None
    assert float(p.grad[2].abs().sum()) == 0.0  # nothing learnt from the unlabelled frame
    assert float(p.grad[1, contract.KP["nose"]].abs().sum()) == 0.0


def test_angles_need_both_bones() -> None:
    ok = torch.ones(1, contract.NUM_KEYPOINTS, dtype=torch.bool)
    ok[0, contract.KP["left_wrist"]] = False
    mask = angle_mask(ok)[0]
    # Only the left elbow angle (upper arm, forearm) uses the left wrist.
    assert mask.tolist() == [i != 0 for i in range(len(contract.JOINT_ANGLES))]
