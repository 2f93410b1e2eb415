"""Vascular risk through the client: volumes with the functional remnant and cut vessels, the
resectogram and the risk map, on the demo phantom (a portal and a hepatic tube)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import resecta_client as rc

from .conftest import DEMO_ROLES

END = (0.0, 30.0, 0.0)  # a plane between the tumours and the portal vein


@pytest.fixture
def demo(client: rc.Client, demo_phantom: Path) -> rc.Session:
    s = client.create_session("risk-tests")
    s.upload_label_map_file(demo_phantom, DEMO_ROLES)
    s.init_from_end_point("r1", END)
    return s


def test_volumes_carry_the_functional_remnant_and_the_cut_portal_vein(demo: rc.Session) -> None:
    v = demo.volumes()
    assert v.complete and v.risk is not None and v.risk_unavailable == ""
    k = v.risk
    assert k.has_portal and k.has_hepatic
    assert k.devascularised_ml > 1.0 and k.congested_ml == 0.0
    assert k.functional_remnant_ml == pytest.approx(v.remnant_ml - k.at_risk_ml, abs=1e-6)
    assert k.functional_remnant_pct == pytest.approx(100 * k.functional_remnant_ml / v.total_ml)
    assert v.flr_warning == (k.functional_remnant_pct < v.flr_threshold_pct)
    assert [c.system for c in k.cut_vessels] == ["portal"]
    c = k.cut_vessels[0]
    assert c.resection == "r1" and 3.0 < c.radius_mm < 7.0 and all(0 <= x <= 1 for x in c.uv)


def test_resectogram_and_risk_map_agree_with_the_volumes(demo: rc.Session) -> None:
    g = demo.resectogram("r1", 120, 80)
    assert g.classes.shape == g.territories.shape == (80, 120)
    assert g.plan_version == demo.plan_version
    inside = g.classes > 0
    assert 0.1 < inside.mean() < 0.9
    assert np.all(g.territories[~inside] == 0) and np.any(g.territories[inside] > 0)
    assert g.worst_uv is not None and g.min_margin_mm is not None
    assert [c.system for c in g.cut_vessels] == ["portal"]
    # The crossing lies on the surface inside the liver, as the pixel under it says.
    u, v = g.cut_vessels[0].uv
    assert g.classes[int(v * 80), int(u * 120)] > 0

    m = demo.risk_map()
    v = demo.volumes()
    assert m.risk == v.risk and m.plan_version == v.plan_version
    assert m.classes.shape == m.territories.shape
    liver = m.volume_ml(*(c for c in rc.RiskClass if c != rc.RiskClass.NONE))
    assert liver == pytest.approx(v.total_ml, rel=1e-6)
    dev = m.volume_ml(rc.RiskClass.DEVASCULARISED, rc.RiskClass.BOTH)
    assert dev == pytest.approx(v.risk.devascularised_ml, rel=0.1)
    assert m.volume_ml(rc.RiskClass.RESECTED) == pytest.approx(v.resected_ml, rel=0.02)
    # The box's corner voxel sits where the matrix says: inside the label map's extent.
    assert np.all(np.isfinite(m.ijk_to_ras)) and m.ijk_to_ras[3, 3] == 1.0


def test_bad_requests_are_refused(demo: rc.Session, client: rc.Client, phantom: Path) -> None:
    with pytest.raises(rc.NotFound):
        demo.resectogram("nope")
    with pytest.raises(rc.InvalidArgument):
        demo.resectogram("r1", 513, 10)
    assert client.server_info().limits.max_resectogram_side == 512
    # Without vessel roles there is neither risk nor a risk map.
    s = client.create_session("no-vessels")
    s.upload_label_map_file(phantom, {"parenchyma": [1, 3], "tumor": [2]})
    s.init_from_end_point("r1", (-30.0, 0.0, 0.0))
    assert s.volumes().risk is None
    with pytest.raises(rc.FailedPrecondition):
        s.risk_map()
