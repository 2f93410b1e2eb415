"""`Client.reconstruct_points`: a point cloud closed into a surface without a session, with and
without normals, the mesh decoded into numpy arrays with the server's report; shapes checked
before sending; bad clouds and the server's limits as `InvalidArgument`; the encodings the
client allows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import resecta_client as rc
from server_harness import fibonacci_sphere

from .conftest import Server

CENTRE = np.array([-40.0, 25.0, 110.0])


def _off_sphere_mm(s: rc.PointCloudSurface, radius: float) -> float:
    d = np.linalg.norm(s.positions.astype(np.float64) - CENTRE, axis=1)
    return float(np.abs(d - radius).max())


def test_a_sphere_of_points_closes_with_or_without_normals(client: rc.Client) -> None:
    points, normals = fibonacci_sphere(2000, 20.0, CENTRE)
    estimated = client.reconstruct_points(points, depth=6)
    given = client.reconstruct_points(points, normals * 3.0, depth=6)  # any length
    for s, source in ((estimated, rc.NormalSource.ESTIMATED), (given, rc.NormalSource.GIVEN)):
        assert isinstance(s, rc.PointCloudSurface)
        assert s.positions.dtype == np.float32 and s.positions.shape[1] == 3
        assert s.triangles.dtype == np.uint32 and s.triangles.shape[1] == 3
        assert s.normals is not None and s.normals.shape == s.positions.shape
        assert int(s.triangles.max()) < len(s.positions)
        assert _off_sphere_mm(s, 20.0) < 0.3
        outward = np.einsum("ij,ij->i", s.positions - CENTRE.astype(np.float32), s.normals)
        assert (outward > 0).all()
        assert s.volume_ml == pytest.approx(4 / 3 * np.pi * 20.0**3 / 1000, rel=0.03)
        r = s.report
        assert r.normals is source
        assert (r.points, r.distinct, r.depth, r.neighbours) == (2000, 2000, 6, 10)
        assert r.cell_mm > 0 and r.sampled_area_mm2 > 0
        assert r.solve_s >= 0 and r.normals_s >= 0 and r.surface_s >= 0
    # Estimated normals report their graph; given ones do not.
    assert estimated.report.components == 1 and estimated.report.spacing_mm is not None
    assert given.report.components is None and given.report.spacing_mm is None
    # Nothing stays on the server.
    assert client.list_sessions() == []


def test_defaults_flat_arrays_and_lists_are_taken(client: rc.Client) -> None:
    points, _ = fibonacci_sphere(300, 10.0, CENTRE)
    a = client.reconstruct_points(points)
    assert (a.report.depth, a.report.neighbours) == (5, 10)
    b = client.reconstruct_points(points.reshape(-1), neighbours=8)
    c = client.reconstruct_points(points.tolist(), neighbours=8)
    assert b.report.neighbours == 8
    np.testing.assert_array_equal(b.positions, c.positions)
    np.testing.assert_array_equal(b.triangles, c.triangles)


def test_bad_clouds_raise(client: rc.Client) -> None:
    points, normals = fibonacci_sphere(200, 10.0)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        client.reconstruct_points(points[:, :2])
    bad = points.copy()
    bad[5, 1] = np.nan
    cases = [
        (dict(positions=points.reshape(-1)[:-1]), "multiple of 3"),
        (dict(positions=bad), "positions[16]: must be finite"),
        (dict(positions=points, normals=normals[:-1]), "as many values as positions"),
        (dict(positions=points[:3]), "distinct points"),
        (dict(positions=points, depth=11), "max_cloud_depth"),
        (dict(positions=points, neighbours=65), "neighbours 65"),
    ]
    for kwargs, message in cases:
        with pytest.raises(rc.InvalidArgument) as e:
            client.reconstruct_points(**kwargs)
        assert message in e.value.message, (message, e.value.message)
        assert e.value.code == "INVALID_ARGUMENT"


def test_limits_follow_the_server_configuration(tmp_path: Path) -> None:
    cfg = tmp_path / "resecta.toml"
    cfg.write_text("[limits]\nmax_cloud_points = 500\nmax_cloud_depth = 5\n")
    s = Server("--config", str(cfg))
    try:
        with rc.Client(s.grpc_addr) as c:
            limits = c.server_info().limits
            assert (limits.max_cloud_points, limits.max_cloud_depth) == (500, 5)
            points, _ = fibonacci_sphere(501, 10.0)
            with pytest.raises(rc.InvalidArgument, match=r"max_cloud_points \(500\)"):
                c.reconstruct_points(points)
            with pytest.raises(rc.InvalidArgument, match="max_cloud_depth"):
                c.reconstruct_points(points[:500], depth=6)
            assert len(c.reconstruct_points(points[:500], depth=5).positions) > 0
    finally:
        s.stop()


def test_encodings_the_client_allows_are_only_used_when_the_server_has_them(client: rc.Client) -> None:
    """This server (no zstd, no quantisation) sends exact f32 meshes whatever the client allows."""
    points, _ = fibonacci_sphere(300, 10.0)
    meshes = [client.reconstruct_points(points, allow_zstd=a, allow_quantized=a) for a in (False, True)]
    np.testing.assert_array_equal(meshes[0].positions, meshes[1].positions)
    np.testing.assert_array_equal(meshes[0].normals, meshes[1].normals)
