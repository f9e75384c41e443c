"""Write the fixed set of simulated FORC images used by test_simulated_images.py.

    python tests/learn/make_forc_fixture.py results/dataset.h5 tests/learn/data/laptop_forc_32px.npz

Takes every family of a laptop dataset (64×64×1 films, 64-field images, the workflow's
`config/config.yaml`), averages the images 2×2 down to 32×32 (uint8) and keeps M_s, K_u and the
sample ids: a small, real, simulated training set (not synthetic bars) that the default test run can
train on in seconds. The file records the dataset's config hash.
"""

import sys

import h5py
import numpy as np


def main(dataset_path: str, out_path: str) -> None:
    with h5py.File(dataset_path, "r") as h5:
        images = h5["images"][:].astype(float)
        columns = list(h5["parameters"].attrs["columns"])
        parameters = h5["parameters"][:]
        sample_id = h5["sample_id"][:]
        config_hash = str(h5.attrs["config_hash"])
    n, side, _ = images.shape
    small = images.reshape(n, side // 2, 2, side // 2, 2).mean(axis=(2, 4))
    np.savez_compressed(out_path, images=np.rint(small).astype(np.uint8), sample_id=sample_id,
                        Ms=parameters[:, columns.index("Ms")], K_u=parameters[:, columns.index("K_u")],
                        config_hash=config_hash)
    print(f"wrote {n} images of {side // 2}x{side // 2} to {out_path}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
