"""Wilson score interval of a success share."""

import pytest

from tron1cli.evaluation.binomial import wilson_interval


def test_wilson_interval_by_hand():
    # 47 of 50, z = 1.96: centre (0.94 + 0.038416) / 1.076832 = 0.90861,
    # half 1.96 * sqrt(0.001128 + 0.00038416) / 1.076832 = 0.07078
    assert wilson_interval(47, 50) == pytest.approx((0.83783, 0.97939), abs=1e-5)
    # the edges stay inside [0, 1] and are not empty: 0 of 10 reaches 3.8416 / 13.8416 = 0.27754
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.27754), abs=1e-5)
    assert wilson_interval(10, 10) == pytest.approx((0.72246, 1.0), abs=1e-5)


@pytest.mark.parametrize("k,n", [(1, 0), (-1, 5), (6, 5)])
def test_wilson_interval_rejects_impossible_counts(k, n):
    with pytest.raises(ValueError, match="0 <= k <= n"):
        wilson_interval(k, n)
