"""`unseen`: the share of synthesized pixels whose colour the region's photograph never shows."""
from __future__ import annotations

import numpy as np

from tools.analysis.grain_metrics import unseen


def gray_ramp(rng: np.random.Generator) -> np.ndarray:
    """A 64 x 64 region whose colours all lie on the gray diagonal, every level of it."""
    v = rng.integers(0, 256, (64, 64)).astype(np.uint8)
    return np.repeat(v[..., None], 3, axis=2)


def test_the_photographs_own_colours_in_another_order_are_all_seen():
    rng = np.random.default_rng(0)
    photo = gray_ramp(rng)
    shuffled = rng.permutation(photo.reshape(-1, 3)).reshape(photo.shape)
    assert unseen(photo, shuffled, np.ones((64, 64), bool)) == 0.0


def test_each_bands_levels_kept_but_paired_anew_give_colours_the_region_never_had():
    rng = np.random.default_rng(1)
    photo = gray_ramp(rng)
    # every band's levels exactly as in the photograph, each band shuffled on its own
    apart = np.stack([rng.permutation(photo[..., b].ravel()).reshape(64, 64) for b in range(3)], axis=2)
    share = unseen(photo, apart, np.ones((64, 64), bool))
    # a random triple lies within a bin of the diagonal only when all three are within 16 levels or so
    assert 0.9 < share < 1.0


def test_one_bin_off_is_slack_two_bins_off_is_not_and_only_the_region_counts():
    photo = np.full((8, 8, 3), 100, np.uint8)
    inside = np.zeros((8, 8), bool)
    inside[:, :4] = True
    near, far = photo.copy(), photo.copy()
    near[..., 0] += 8   # the next bin of 8 levels
    far[..., 0] += 16   # two bins off
    far[:, 4:] = 100    # outside the region: not counted
    assert unseen(photo, near, inside) == 0.0
    assert unseen(photo, far, inside) == 1.0
    assert unseen(photo[..., :1], far[..., :1], inside) is None  # one band: its levels say it all


def test_sixteen_bit_bands_are_binned_over_their_depth():
    photo = np.full((4, 4, 2), 30000, np.uint16)
    synth = photo.copy()
    synth[..., 1] += 2048  # one bin of 65536 / 32
    assert unseen(photo, synth, np.ones((4, 4), bool), levels=65536) == 0.0
    synth[..., 1] += 2048
    assert unseen(photo, synth, np.ones((4, 4), bool), levels=65536) == 1.0
