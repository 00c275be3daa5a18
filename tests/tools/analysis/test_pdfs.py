"""Table 2: Johnson against its peers on regions with known shapes."""
import numpy as np
import pytest

from btf.fit.fitter import fit_histogram
from tools.analysis import pdfs


def johnson(values, levels):
    return fit_histogram(np.bincount(values, minlength=levels)).model


def test_skewed_region_johnson_beats_gaussian_uniform_weibull():
    rng = np.random.default_rng(0)
    band = np.clip(np.rint(30 + rng.gamma(1.5, 20, (150, 150))), 0, 255).astype(np.uint8)[:, :, None]
    t = pdfs.table(band, np.zeros((150, 150), np.uint8), ("Y",), johnson)
    (row,) = t.rows
    assert row.count == 22500 and not row.failed
    for peer in ("gaussian", "uniform", "weibull"):
        assert row.errors["johnson"] < row.errors[peer]
    assert t.total == row.errors


def test_errors_are_l1_of_binned_probabilities():
    rng = np.random.default_rng(1)
    band = np.clip(np.rint(rng.normal(100, 10, (100, 100))), 0, 255).astype(np.uint8)[:, :, None]
    t = pdfs.table(band, np.zeros((100, 100), np.uint8), ("Y",), johnson)
    e = t.rows[0].errors
    assert all(0.0 <= v <= 2.0 for v in e.values())
    assert e["gaussian"] < 0.15 and e["uniform"] > 0.5  # a normal sample: the normal fits, flat does not


def test_constant_region_has_zero_error_everywhere():
    band = np.full((10, 10, 1), 42, np.uint8)
    t = pdfs.table(band, np.zeros((10, 10), np.uint8), ("Y",), johnson)
    assert t.total == {p: 0.0 for p in pdfs.PEERS}


def test_mask_size_mismatch_is_refused():
    with pytest.raises(ValueError, match="mask size"):
        pdfs.table(np.zeros((4, 4, 1), np.uint8), np.zeros((3, 4), np.uint8), ("Y",), johnson)
