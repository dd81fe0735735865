from __future__ import annotations

import numpy as np
import pytest
from ssga_fuser_stacking.plugin import Stacking, StackingConfig

from ssga_core import InputError, PluginError
from ssga_core.testing import check_fuser


def test_is_installed(ssga_installed_registry):
    assert ssga_installed_registry.entry("fuser", "stacking").plugin.distribution == "ssga-fuser-stacking"


@pytest.mark.parametrize("inputs", [["log-probability", "reciprocal-rank"], ["log-probability"], ["reciprocal-rank"]])
def test_meets_the_fuser_contract(inputs):
    check_fuser(Stacking(StackingConfig(inputs=inputs)))


def members(rng: np.random.Generator, truth: np.ndarray, classes: int, hit_rate: float) -> np.ndarray:
    """Probabilities of a member that puts the true class first on about ``hit_rate`` of the queries."""
    scores = rng.random((len(truth), classes))
    hits = rng.random(len(truth)) < hit_rate
    scores[hits, truth[hits]] += 1.0
    return scores / scores.sum(axis=1, keepdims=True)


def test_learns_to_trust_the_informative_member_and_drop_the_noise():
    rng = np.random.default_rng(0)
    classes = 20
    truth_val, truth_test = rng.integers(0, classes, 300), rng.integers(0, classes, 300)
    # One good member, three that guess: reciprocal-rank fusion lets the three outvote it.
    def split(truth):
        return np.stack([members(rng, truth, classes, 0.8)] + [members(rng, truth, classes, 0.0) for _ in range(3)])

    val, test = split(truth_val), split(truth_test)
    fuser = Stacking()
    fuser.fit(val, truth_val)
    weights = np.asarray(fuser.learned()["weights"])
    assert weights.shape == (4, 2)
    assert weights[0].sum() > 5 * weights[1:].sum(axis=1).max()

    from ssga_fuser_rrf.plugin import ReciprocalRankFusion

    def top1(fused):
        return float(np.mean(fused.argmax(axis=1) == truth_test))

    assert top1(fuser.fuse(test)) >= top1(test[0]) - 0.02
    assert top1(fuser.fuse(test)) > top1(ReciprocalRankFusion().fuse(test)) + 0.1


def test_the_penalty_shrinks_the_weights():
    rng = np.random.default_rng(1)
    truth = rng.integers(0, 10, 100)
    scores = np.stack([members(rng, truth, 10, 0.6), members(rng, truth, 10, 0.4)])
    loose, tight = Stacking(StackingConfig(l2=0.0)), Stacking(StackingConfig(l2=1.0))
    loose.fit(scores, truth)
    tight.fit(scores, truth)
    assert np.abs(tight.weights).sum() < np.abs(loose.weights).sum()
    assert (tight.weights >= 0).all() and (loose.weights >= 0).all()


def test_refuses_to_fuse_before_it_is_fitted_or_with_other_members():
    rng = np.random.default_rng(2)
    truth = rng.integers(0, 5, 10)
    scores = np.stack([members(rng, truth, 5, 0.5) for _ in range(3)])
    fuser = Stacking()
    with pytest.raises(PluginError, match=r"fuses only after fit\(\) on validation scores"):
        fuser.fuse(scores)
    fuser.fit(scores, truth)
    with pytest.raises(InputError, match="fitted on 3 members, got scores of 2"):
        fuser.fuse(scores[:2])


def test_bad_inputs_are_named():
    fuser = Stacking()
    scores = np.full((2, 4, 5), 0.2)
    with pytest.raises(InputError, match=r"expected 4 true classes in \[0, 5\)"):
        fuser.fit(scores, np.array([0, 1, 7, 2]))
    with pytest.raises(InputError, match=r"needs class probabilities in \[0, 1\], got scores in \[-1, 0.2\]"):
        bad = scores.copy()
        bad[0, 0, 0] = -1.0
        fuser.fit(bad, np.array([0, 1, 2, 3]))


def easy_and_hard(rng: np.random.Generator, truth: np.ndarray, classes: int) -> np.ndarray:
    """Two members whose worth turns with the query: on an easy view (even queries) both are sure, A
    right and B confidently wrong; on a hard view (odd queries) both are nearly flat, B leaning to the
    truth and A as much to a wrong class. No fixed weights of their log-probabilities get both kinds right
    (A must outweigh B on the easy views and B outweigh A on the hard ones)."""
    def member(peak_at: np.ndarray, height: np.ndarray) -> np.ndarray:
        logits = rng.normal(0.0, 0.05, (len(truth), classes))
        logits[np.arange(len(truth)), peak_at] += height
        p = np.exp(logits)
        return p / p.sum(axis=1, keepdims=True)

    easy = np.arange(len(truth)) % 2 == 0
    wrong = (truth + rng.integers(1, classes, len(truth))) % classes
    height = np.where(easy, 4.0, 0.5)
    a = member(np.where(easy, truth, wrong), height)
    b = member(np.where(easy, wrong, truth), height)
    return np.stack([a, b])


@pytest.mark.parametrize("gate", ["sharpness", "consensus"])
def test_a_gate_trusts_each_member_where_it_is_right(gate):
    rng = np.random.default_rng(3)
    classes = 10
    truth_val, truth_test = rng.integers(0, classes, 400), rng.integers(0, classes, 400)
    val, test = easy_and_hard(rng, truth_val, classes), easy_and_hard(rng, truth_test, classes)

    def top1(fuser):
        fuser.fit(val, truth_val)
        return float(np.mean(fuser.fuse(test).argmax(axis=1) == truth_test))

    fixed = Stacking(StackingConfig(inputs=["log-probability"]))
    gated = Stacking(StackingConfig(inputs=["log-probability"], gate=gate))
    assert top1(fixed) < 0.75  # one kind of view right, the other by the noise's luck (0.655 here)
    assert top1(gated) > 0.95  # 1.0 here
    learned = gated.learned()
    assert learned["gate"] == gate and np.asarray(learned["weights"]).shape == (2, 1, 2)
    assert np.asarray(learned["sharpness_range"]).shape == (2, 2)
    assert "gate" not in fixed.learned()


def test_meets_the_fuser_contract_with_a_gate():
    check_fuser(Stacking(StackingConfig(gate="consensus")))


def test_a_gate_needs_probabilities():
    scores = np.full((2, 4, 5), 2.0)
    with pytest.raises(InputError, match=r"gate 'sharpness' needs class probabilities in \[0, 1\]"):
        Stacking(StackingConfig(inputs=["reciprocal-rank"], gate="sharpness")).fit(scores, np.array([0, 1, 2, 3]))
