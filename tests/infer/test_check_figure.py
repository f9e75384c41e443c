"""The report page's figures (``loop.report_page``): the check figure draws every kind of verdict (its
flag line, ``check_flag_threshold``, is tested against the p-value in ``test_predictive_check.py``)."""

import numpy as np
import pytest

from forcdecode.infer.predictive_check import make_reference, predictive_p_value
from forcdecode.infer.predictive_check import check_figure


@pytest.mark.parametrize("n", [20, 10])
def test_check_figure_draws_flagged_unflagged_and_undetermined_films(tmp_path, n):
    """A flagged film, one not flagged, one undetermined (no statistic: no simulation succeeded), with a
    reference large enough to flag at α = 0.05 (n = 20) and one too small to (n = 10: no flag line)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = [0.0] * (n // 2) + list(np.linspace(0.1, 8.5, n - n // 2))
    reference = make_reference(values, budget=200, round_size=25, prior="draw", sample_ids=range(n),
                               extend={"N_pin": 4.0})
    judged = {"over-pinned": {"statistic": 306.0, "misspecified": predictive_p_value(306.0, values) < 0.05},
              "in prior": {"statistic": 0.0, "misspecified": False},
              "no simulation": {"statistic": None, "misspecified": False}}
    assert judged["over-pinned"]["misspecified"] == (n == 20)
    before = plt.get_fignums()
    path = tmp_path / "check.png"
    check_figure(path, reference, judged, title="extension check")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plt.get_fignums() == before  # closed, not leaked
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically: no temporary left
