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


def public_photos(side: int = 64) -> dict[str, np.ndarray]:
    """Crops of photographs shipped in public packages (scikit-image's data, matplotlib's sample
    data), as read_image returns them: RGB (H, W, 3), one band (H, W, 1), and one 16-bit (an MRI
    slice). Each crop is `side` pixels square, where the photograph has texture."""
    import gzip

    import matplotlib.cbook
    from skimage import data

    def crop(img, y, x):
        img = img[y:y + side, x:x + side]
        return np.ascontiguousarray(img if img.ndim == 3 else img[:, :, None])

    with gzip.open(matplotlib.cbook.get_sample_data("s1045.ima.gz", asfileobj=False)) as fh:
        mri = np.frombuffer(fh.read(), ">u2").astype(np.uint16).reshape(256, 256)  # big-endian levels 0..215
    return {"astronaut": crop(data.astronaut(), 150, 150), "coffee": crop(data.coffee(), 150, 250),
            "chelsea": crop(data.chelsea(), 100, 150), "immunohistochemistry": crop(data.immunohistochemistry(), 200, 200),
            "camera": crop(data.camera(), 200, 200), "coins": crop(data.coins(), 100, 100),
            "mri16": crop(mri, 100, 100)}
