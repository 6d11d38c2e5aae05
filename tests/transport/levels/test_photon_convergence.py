"""PhotonLevel.converged: the outer loop stops when a refresh no longer improves the image difference and Pd has
stopped moving, both measured against what the first refit did."""

from types import SimpleNamespace

from torchrefl.transport.levels.photon import CONVERGED_SHARE, PhotonLevel


def converged(scores, pd_change, k):
    return PhotonLevel.converged(SimpleNamespace(scores=scores, pd_change=pd_change), k)


def test_stops_when_both_have_settled():
    # refit 1 gained 1.0 DN and moved Pd by 0.1 rms; refresh 2 gains 0.001 DN and moves Pd 0.001
    why = converged([2.0, 1.0, 0.999], [0.1, 0.001], 2)
    assert why is not None and "refresh 2 beat the best image difference by 0.0010 DN" in why


def test_goes_on_while_either_still_moves():
    assert converged([2.0, 1.0, 0.9], [0.1, 0.001], 2) is None  # the image difference still drops
    assert converged([2.0, 1.0, 0.999], [0.1, 0.05], 2) is None  # Pd still moves
    assert converged([2.0, 1.0], [0.1], 1) is None  # never after the first refit
    assert converged([2.0, 2.1, 2.2], [0.1, 0.0], 2) is None  # the first refit made it worse: no scale to judge by


def test_the_threshold_is_the_share_of_the_first_refit():
    gain = 1.0
    just_under = 1.0 - 0.99 * CONVERGED_SHARE * gain
    just_over = 1.0 - 1.01 * CONVERGED_SHARE * gain
    assert converged([2.0, 1.0, just_under], [0.1, 0.0], 2) is not None
    assert converged([2.0, 1.0, just_over], [0.1, 0.0], 2) is None
    # a refresh worse than the best so far counts as no gain
    assert converged([2.0, 1.0, 0.98, 0.985], [0.1, 0.01, 0.0001], 3) is not None
