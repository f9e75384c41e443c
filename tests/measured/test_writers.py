import numpy as np
import pytest

from forcdecode.measured import read_forc
from forcdecode.measured.writers import write_micromag_0015


def test_written_micromag_file_reads_back(tmp_path):
    grid = np.linspace(-1, 1, 21)
    curves = [(grid[i:], 3e-8 * np.tanh(4 * grid[i:]) * (1 + 0.01 * i)) for i in range(21)]
    path = write_micromag_0015(tmp_path / "sim.frc", grid, curves)
    data = read_forc(path, drift_correction=False)
    assert data.format == "micromag-0015" and len(data.curves) == 21
    by_hr = sorted(data.curves, key=lambda c: c.reversal_field_T)
    for (fields, moments), curve in zip(curves, by_hr):
        np.testing.assert_allclose(curve.field_T, fields, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(curve.moment_Am2, moments, rtol=1e-6, atol=1e-15)
    assert data.drift_percent == pytest.approx(0.0, abs=1e-6)
