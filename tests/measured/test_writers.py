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


def test_written_lakeshore_csv_reads_back_with_times_and_drift(tmp_path):
    from forcdecode.measured.writers import write_lakeshore_csv

    grid = np.linspace(-1, 1, 17)
    curves = [(grid[i:], 2e-8 * np.tanh(3 * grid[i:])) for i in range(17)]
    calibration = 2e-8 * np.tanh(3.0) * np.linspace(1.0, 1.02, 17)[::-1]  # the highest curve measured first
    path = write_lakeshore_csv(tmp_path / "sim.csv", grid, curves, calibration_moments_Am2=calibration,
                               averaging_s=0.1, pause_s=1.0, sweep_rate_T_per_s=0.05)
    data = read_forc(path, drift_correction=False)
    assert data.format == "lakeshore8600-csv" and len(data.curves) == 17 and data.complete
    by_hr = sorted(data.curves, key=lambda c: c.reversal_field_T)
    for (fields, moments), curve in zip(curves, by_hr):
        np.testing.assert_allclose(curve.field_T, fields, rtol=0, atol=1e-15)
        np.testing.assert_allclose(curve.moment_Am2, moments, rtol=1e-15, atol=0)
    # time stamps: a point every averaging time plus the sweep between fields (0.125 T at 0.05 T/s = 2.5 s)
    steps = np.diff(data.curves[0].time_s)
    np.testing.assert_allclose(steps, 0.1 + 0.125 / 0.05, atol=2e-3)
    # the calibration moments change by 2 % over the run: the reader's drift is that
    assert data.drift_percent == pytest.approx(2.0, abs=0.05)
