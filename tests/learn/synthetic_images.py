"""A synthetic task whose answer is in the image: the image is bright up to a row set by the target."""

import numpy as np


def bar_images(n=400, seed=0, side=64):
    """(images uint8 (n, side, side), normalized M_s (n,), target u (n,)): rows 0..round(u (side-1))
    are bright, plus uniform noise of 20 grey levels."""
    rng = np.random.default_rng(seed)
    u = rng.random(n)
    images = np.zeros((n, side, side), dtype=np.uint8)
    rows = np.rint(u * (side - 1)).astype(int)
    for k, r in enumerate(rows):
        images[k, :r + 1, :] = 255
    images = np.clip(images + rng.integers(0, 20, size=images.shape), 0, 255).astype(np.uint8)
    return images, rng.random(n), u
