"""Images the tests make."""
import numpy as np


def plate(seed, h=60, w=80):
    """Left half dark grains, right half bright grains."""
    rng = np.random.default_rng(seed)
    img = np.empty((h, w, 3), np.uint8)
    img[:, : w // 2] = np.clip(rng.normal(60, 10, (h, w // 2, 3)), 0, 255)
    img[:, w // 2:] = np.clip(rng.normal(180, 15, (h, w - w // 2, 3)), 0, 255)
    mask = np.zeros((h, w), np.uint8)
    mask[:, w // 2:] = 1
    return img, mask
