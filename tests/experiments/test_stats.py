"""§7.3's statistics on hand-made numbers: means and standard errors, the between-subjects F
of the mixed design (one-way ANOVA of the agents' window averages), AnovaRM's time effect."""

import math

import numpy as np
import pytest
from scipy import stats as st

from qlap_runtime.experiments import stats


def test_mean_and_standard_error():
    m, se, n = stats.mean_se([1.0, 2.0, 4.0])
    assert (m, n) == (pytest.approx(7 / 3), 3)
    assert se == pytest.approx(math.sqrt(7) / 3)          # s² = 7/3, s/√3
    assert math.isnan(stats.mean_se([5.0])[1])
    assert math.isnan(stats.mean_se([])[0])


def test_curve_over_agents():
    pts = stats.curve({"a": {10: 1.0, 20: 3.0}, "b": {10: 2.0, 20: 5.0}, "c": {10: 4.0}})
    assert [(p.step, p.n) for p in pts] == [(10, 3), (20, 2)]
    assert pts[0].mean == pytest.approx(7 / 3)
    assert pts[1].mean == pytest.approx(4.0) and pts[1].stderr == pytest.approx(1.0)


def test_window_means_leave_out_incomplete_agents():
    series = {"a": {10: 9.0, 20: 1.0, 30: 3.0}, "b": {20: 2.0, 30: 4.0}, "c": {20: 7.0}}
    assert stats.window_means(series, after=10) == {"a": 2.0, "b": 3.0}


def test_between_anova_by_hand():
    # grand mean 26/7; SSB = 3(2 − 26/7)² + 4(5 − 26/7)² = 756/49; SSW = 2 + 20 = 22
    # F = (756/49) / (22/5) = 3.50649…, on (1, 5) degrees of freedom
    res = stats.between_anova({"a": [1, 2, 3], "b": [2, 4, 6, 8]})
    assert res is not None
    assert res.F == pytest.approx(756 / 49 / (22 / 5))
    assert (res.df1, res.df2, res.n) == (1.0, 5.0, (3, 4))
    assert res.sig == pytest.approx(st.f.sf(756 / 49 / (22 / 5), 1, 5))
    assert res.caption() == "F = 3.506, sig. = 0.120"


def test_between_anova_is_the_mixed_design_between_subjects_test():
    """Split-plot ANOVA by hand (groups × steps, agents nested in groups): its F for the
    group is MS_groups / MS_agents-within-groups, the one-way F of the agents' means."""
    rng = np.random.default_rng(7)
    k, n = 4, 5                                   # steps, agents per group
    data = {g: rng.normal(mu, 1.0, size=(n, k)) + np.linspace(0, 1, k)
            for g, mu in (("x", 0.0), ("y", 0.8))}
    allv = np.concatenate(list(data.values()))
    grand = allv.mean()
    ss_groups = sum(k * n * (d.mean() - grand) ** 2 for d in data.values())
    ss_agents = sum(k * ((d.mean(axis=1) - d.mean()) ** 2).sum() for d in data.values())
    f_hand = ss_groups / 1 / (ss_agents / (2 * n - 2))
    series = {g: {f"{g}{i}": {s: float(d[i, s]) for s in range(k)} for i in range(n)}
              for g, d in data.items()}
    res = stats.between_anova({g: list(stats.window_means(s, after=-1).values())
                               for g, s in series.items()})
    assert res is not None and res.F == pytest.approx(f_hand)
    assert (res.df1, res.df2) == (1.0, 2 * n - 2)


def test_reference_captions_are_independent_groups_of_twenty():
    # Fig. 7.2(f): F = 2.358, sig. = 0.133 and Fig. 7.5(b): F = 6.739, sig. = 0.013 are
    # F(1, 38): twenty agents per condition, between subjects
    assert st.f.sf(2.358, 1, 38) == pytest.approx(0.133, abs=5e-4)
    assert st.f.sf(6.739, 1, 38) == pytest.approx(0.013, abs=5e-4)


def test_time_anova_by_hand():
    # three agents at three steps: SS_time = 13.556, SS_error = 3.111 → F(2, 4) = 8.714
    series = {"x": {1: 1.0, 2: 2.0, 3: 4.0}, "y": {1: 2.0, 2: 2.0, 3: 5.0},
              "z": {1: 0.0, 2: 3.0, 3: 3.0}}
    res = stats.time_anova(series, after=0)
    assert res is not None
    assert res.F == pytest.approx((122 / 9 / 2) / (28 / 9 / 4))
    assert (res.df1, res.df2) == (2.0, 4.0)


def test_no_test_without_agents_or_variance():
    assert stats.between_anova({"a": [1.0], "b": []}) is None
    assert stats.between_anova({"a": [2.0, 2.0], "b": [2.0, 2.0]}) is None
    assert stats.time_anova({"x": {1: 1.0}}, after=0) is None
    assert stats.format_f(None, None) == "—"
