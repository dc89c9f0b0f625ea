"""Kümmerle et al.'s metric (Eqs. 22–23) and the relations reader."""

import numpy as np
import pytest

from swarmslam.evaluation.metrics import kummerle
from swarmslam.formats.relations import Relations, RelationsFormatError, read_relations
from swarmslam.runtime.pose import between, compose


def test_kummerle_metric_known_errors():
    stamps = np.arange(5.0)
    truth = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.1], [3, 1, 0.2], [3, 2, 0.3]], float)
    rel = Relations(stamps[:-1], stamps[1:], between(truth[1:], truth[:-1]))
    exact = kummerle(stamps, truth, rel)
    assert exact["eT"] < 1e-12 and exact["eR_deg"] < 1e-10 and exact["relations_used"] == 4
    moved = truth.copy()
    moved[4] = compose(truth[4], [0.1, 0.0, np.deg2rad(2.0)])  # only the last relation is off
    m = kummerle(stamps, moved, rel)
    assert np.isclose(m["eT"], 0.1 / 4) and np.isclose(m["eR_deg"], 2.0 / 4)
    with pytest.raises(ValueError, match="no relation"):
        kummerle(stamps + 100, truth, rel)


def test_kummerle_reports_the_short_relations_tail():
    """Relations under 10 s apart are scored apart with their tail: one relation 8° off among
    ninety-nine right ones moves the mean by 0.08° but is the maximum and the count above 5°;
    a long relation's error stays out of them."""
    stamps = np.arange(201.0)
    truth = np.c_[0.1 * stamps, np.zeros(201), np.zeros(201)]
    t1 = np.r_[np.arange(100.0), 0.0]
    t2 = np.r_[np.arange(100.0) + 2, 200.0]  # 100 short relations and one 200 s long
    rel = Relations(t1, t2, between(truth[t2.astype(int)], truth[t1.astype(int)]))
    moved = truth.copy()
    moved[51:] = compose(truth[51:], [0.0, 0.0, np.deg2rad(8.0)])  # turned 8° from scan 51 on
    m = kummerle(stamps, moved, rel)
    assert m["relations_short"] == 100
    assert np.isclose(m["eR_short_max_deg"], 8.0) and m["eR_short_over_5deg"] == 2
    assert m["eR_short_median_deg"] < 1e-9 and np.isclose(m["eR_short_deg"], 16.0 / 100)


def test_relations_reader_rejects_malformed_lines(tmp_path):
    p = tmp_path / "r.relations"
    p.write_text("1.0 2.0 0.1 0.2 0 0 0 0.3\n3.0 4.0 0.1 oops 0 0 0 0.3\n")
    with pytest.raises(RelationsFormatError) as info:
        read_relations(p)
    assert info.value.line == 2 and info.value.field == "y" and "r.relations:2:" in str(info.value)
    p.write_text("1.0 2.0 0.1\n")
    with pytest.raises(RelationsFormatError, match="expected 8 values"):
        read_relations(p)
