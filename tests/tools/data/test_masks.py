"""Masks of images with fewer colours than the classes asked for: a class per colour, never a
colour split between classes, and `btf-host mask` says how many classes it found."""
from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from tools.data.masks import METHODS, segment


def _two_colours() -> np.ndarray:
    image = np.zeros((64, 64, 3), np.uint8)
    image[:, 32:] = (200, 100, 50)
    return image


@pytest.mark.parametrize("method", METHODS)
def test_a_flat_image_is_one_class_and_raises_no_warning(method):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        labels = segment(np.full((64, 64, 3), 77, np.uint8), method, 3)
    assert np.all(labels == 0)


@pytest.mark.parametrize("method", METHODS)
def test_two_colours_asked_for_three_classes_are_two_classes_darkest_first(method):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        labels = segment(_two_colours(), method, 3, seed=1)
    assert np.all(labels[:, :32] == 0) and np.all(labels[:, 32:] == 1)


def test_mask_says_when_it_found_fewer_classes_than_asked(host, tmp_path):
    cv2.imwrite(str(tmp_path / "two.png"), _two_colours())
    code, _, err = host("mask", tmp_path / "two.png", "--method", "kmeans", "--k", "3", "--out", tmp_path / "m.png")
    assert code == 0
    assert err.strip() == "btf-host: note: 2 classes of the 3 asked for: the image's colours part into no more"
    code, _, err = host("mask", tmp_path / "two.png", "--method", "kmeans", "--k", "2", "--out", tmp_path / "n.png")
    assert code == 0 and err == ""
