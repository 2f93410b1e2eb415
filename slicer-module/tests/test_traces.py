"""DS and CP resections from markups curves (ResectaLib.traces and the Logic) against a real
`resecta serve`, on real MRML nodes from `slicer-core`: curves held until 3, then a DS
resection; a curve edited redraws its trace, a curve deleted removes it; a CP ring; the
deformation handle dragged and the surface following it; undo of a deformation; the kind and
metrics rows; and what a Slicer user sees, rendered through Slicer's displayable managers."""

import numpy as np
import pytest

from conftest import load_phantom_segmentation

# The small phantom: ellipsoid liver (radii 40, 30, 25 mm), tumour (r 8 mm) at (10, 5, 0). The
# cuts lie near the plane x = X, about 12 mm from the tumour.
X = -10.0


def axial_points(z, x=X):
    """Control points of a curve drawn on the axial slice z across the liver (slightly
    tilted: a curve of constant x would lie on a sagittal slice too)."""
    return [(x + 0.02 * y, y, z) for y in (-50.0, -25.0, 0.0, 25.0, 50.0)]


def ring_points(x=X, n=12):
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return [(x, 30.0 * np.cos(a), 22.0 * np.sin(a)) for a in t]


def draw(logic, name, kind, points):
    """What the user does: a new curve, points placed, then the curve used."""
    import vtk

    node = logic.new_trace_curve(name, kind)
    for p in points:
        node.AddControlPointWorld(vtk.vtkVector3d(*p))
    return node, logic.use_curve(node)


@pytest.fixture
def logic(scene, dispatcher, planning_server, phantom):
    from ResectaLib.logic import PlanningLogic

    _lm, seg = load_phantom_segmentation(scene, phantom)
    ids = [seg.GetSegmentation().GetNthSegmentID(i) for i in range(3)]
    s = PlanningLogic(scene, dispatcher)
    try:
        s.connect(planning_server.grpc_addr)
        dispatcher.wait_until(lambda: s.connected, 30)
        built = []
        s.upload_and_build(seg, dict(zip(ids, ["parenchyma", "tumor", "portal"])), method="mcsd",
                           on_done=built.append)
        dispatcher.wait_until(lambda: built and s.models_ready, 120)
        yield s
    finally:
        s.close()


def surface_of(logic, name):
    return logic.surfaces().get(name)


def test_ds_from_curves_held_until_three(logic, scene, dispatcher):
    from ResectaLib import controlgrid, traces

    wait = dispatcher.wait_until
    a, got = draw(logic, "ds", "ds", axial_points(-30.0))
    assert got == "held" and logic.resection("ds") is None
    b, got = draw(logic, "ds", "ds", axial_points(0.0))
    assert got == "held" and len(logic.traces.held("ds")) == 2
    c, got = draw(logic, "ds", "ds", axial_points(30.0))
    assert got == "created"
    wait(lambda: logic.resection("ds") is not None and logic.model_node("ds"), 30)
    r = logic.resection("ds")
    assert str(r.kind) == "ds" and len(r.traces) == 3
    # The trace is the curve as drawn (its interpolated points), on the curve's slice.
    assert np.allclose(r.traces[1], traces.curve_points(b), atol=1e-6)
    assert np.ptp(r.traces[1][:, 2]) == 0.0 and len(r.traces[1]) > 5
    # No control grid for a DS resection.
    assert controlgrid.find_grid_node(scene, "ds") is None and "ds" not in logic.grids
    wait(lambda: logic.metrics_table and logic.metrics_table[0].name == "ds", 30)
    row = logic.metrics_table[0]
    assert row.kind == "ds" and row.margin_deviation_mm == pytest.approx(2.0, abs=1.5)
    assert row.cells()[1] == "DS" and row.cells()[2].endswith(" mm")
    assert row.median_abs_curvature_per_mm == pytest.approx(0.0, abs=1e-6)
    margin_before = logic.verdicts["ds"][1].min_margin_mm

    # Editing a curve (a point moved 4 mm towards the tumour, in its slice) redraws the trace.
    b.SetNthControlPointPositionWorld(2, X + 4.0, 0.0, 0.0)
    b.InvokeEvent(b.PointEndInteractionEvent)
    wait(lambda: np.allclose(logic.resection("ds").traces[1], traces.curve_points(b), atol=1e-6), 30)
    wait(lambda: logic.verdicts["ds"][1].min_margin_mm < margin_before - 1.0, 30)

    # A fourth curve is appended; deleting a curve removes its trace.
    d, got = draw(logic, "ds", "ds", axial_points(15.0))
    assert got == "added"
    wait(lambda: len(logic.resection("ds").traces) == 4, 30)
    scene.RemoveNode(a)
    wait(lambda: len(logic.resection("ds").traces) == 3, 30)
    assert not any(np.allclose(t[:, 2], -30.0) for t in logic.resection("ds").traces)

    # Undo brings the removed trace back (server side); redo removes it again, undo once more.
    logic.edits.undo()
    wait(lambda: len(logic.resection("ds").traces) == 4, 30)
    logic.edits.redo()
    wait(lambda: len(logic.resection("ds").traces) == 3, 30)
    logic.edits.undo()
    # A curve edited right after (before the watch may have said so) redraws its own trace,
    # found among the traces the undo answered, not those before it.
    b.SetNthControlPointPositionWorld(2, X + 2.0, 0.0, 0.0)
    b.InvokeEvent(b.PointEndInteractionEvent)
    wait(lambda: any(t.shape == traces.curve_points(b).shape
                     and np.allclose(t, traces.curve_points(b), atol=1e-6)
                     for t in logic.resection("ds").traces), 30)
    zs = sorted(float(t[0, 2]) for t in logic.resection("ds").traces)
    assert zs == [-30.0, 0.0, 15.0, 30.0]  # a's trace (z = −30) untouched
    assert not logic.errors


def test_ds_curve_off_slice_is_refused_before_sending(logic, dispatcher):
    import vtk

    node = logic.new_trace_curve("ds", "ds")
    for p in [(X, -20.0, 0.0), (X + 5.0, 0.0, 3.0), (X, 20.0, 6.0)]:
        node.AddControlPointWorld(vtk.vtkVector3d(*p))
    with pytest.raises(ValueError, match="not on one axial, coronal or sagittal slice"):
        logic.use_curve(node)
    # Curves of mixed orientations reach the server, whose refusal is reported; they stay held.
    draw(logic, "mix", "ds", axial_points(-20.0))
    draw(logic, "mix", "ds", axial_points(0.0))
    coronal = [(x, 0.0, z) for x, z in ((-30.0, 10.0), (0.0, 12.0), (30.0, 14.0))]
    _c, got = draw(logic, "mix", "ds", coronal)
    assert got == "created"
    dispatcher.wait_until(lambda: logic.errors, 30)
    from resecta_client import InvalidArgument

    assert isinstance(logic.errors[-1], InvalidArgument)
    assert "orientation" in str(logic.errors[-1])
    assert len(logic.traces.held("mix")) == 3 and logic.resection("mix") is None


def test_cp_ring_deformation_follows_the_handle(logic, scene, dispatcher):
    from ResectaLib import controlgrid, traces

    wait = dispatcher.wait_until
    ring, got = draw(logic, "cp", "cp", ring_points())
    assert got == "created" and ring.IsA("vtkMRMLMarkupsClosedCurveNode")
    wait(lambda: logic.resection("cp") is not None and logic.model_node("cp"), 30)
    assert str(logic.resection("cp").kind) == "cp" and controlgrid.find_grid_node(scene, "cp") is None
    flat = logic.verdicts["cp"][1].min_margin_mm

    # The handle starts on the surface; dragged 5 mm away from the tumour (−R) and released.
    handle = logic.deformation_handle("cp", (X, 5.0, 0.0))
    assert traces.handle_point(handle) == pytest.approx((X, 5.0, 0.0))
    handle.SetNthControlPointPositionWorld(0, X - 5.0, 5.0, 0.0)
    offset = logic.deform("cp", 20.0, handle)
    # The plane normal is ±R here; the offset's sign is the server's orientation of it.
    assert abs(offset) == pytest.approx(5.0, abs=0.05)
    wait(lambda: logic.resection("cp").deformations, 30)
    wait(lambda: logic.verdicts["cp"][1].min_margin_mm > flat + 2.0, 30)
    # The surface now reaches the handle: its vertex nearest the handle is at the handle.
    s = surface_of(logic, "cp")
    wait(lambda: np.min(np.linalg.norm(surface_of(logic, "cp").positions - (X - 5.0, 5.0, 0.0),
                                       axis=1)) < 1.5, 30)
    assert s.resection.deformations[0].radius_mm == 20.0

    logic.undo_deformation("cp")
    wait(lambda: not logic.resection("cp").deformations, 30)
    wait(lambda: logic.verdicts["cp"][1].min_margin_mm == pytest.approx(flat, abs=1e-6), 30)
    wait(lambda: any(r.name == "cp" and r.kind == "cp" for r in logic.metrics_table), 30)
    with pytest.raises(ValueError, match="not a CP resection"):
        logic.deform("nope", 10.0, handle)
    assert not logic.errors


def test_what_the_user_sees(logic, scene, dispatcher, tmp_path):
    """A DS resection drawn from three curves and a CP ring, rendered offscreen through
    Slicer's model and markups displayable managers: the resection surfaces in their margin
    colours (safe grey: 12 mm from the tumour, margin 10, band 5 → warning yellow near it),
    the traces' curves drawn on them, and the axial slice's intersection line."""
    import offscreen

    problem = offscreen.offscreen_gl_problem()
    if problem:
        pytest.skip(f"no offscreen OpenGL: {problem}")
    from ResectaLib import models

    for z in (-30.0, 0.0, 30.0):
        draw(logic, "ds", "ds", axial_points(z))
    dispatcher.wait_until(lambda: logic.model_node("ds") is not None, 30)
    for n in models.model_nodes(scene):
        if n.GetAttribute(models.KIND_ATTRIBUTE) != "resection":
            n.GetDisplayNode().SetVisibility(False)  # the resection alone, as seen from −R
    view = offscreen.ThreeDView(scene, (240, 200), background=(0.0, 0.0, 0.0), markups=True)
    try:
        view.look((X, 0, 0), (X - 500.0, 0, 0), parallel_scale=45)
        image = view.render()
        view.save_png(tmp_path / "ds_3d.png", image)
        colours = {name: np.array(rgba[:3]) * 255 for name, rgba in models.MARGIN_CLASSES}
        # Inside the liver, away from the tumour: the safe colour; next to it: warning.
        far = image[view.pixel((X, -20.0, -15.0))].astype(float)
        near = image[view.pixel((X, 5.0, -8.0))].astype(float)
        assert np.abs(far - colours["safe"]).max() <= 40, far
        assert np.abs(near - colours["warning"]).max() <= 40, near
        # The middle trace's curve is drawn over the surface (the markups colour, not a class).
        on_curve = image[view.pixel((X, -30.0, 0.0))].astype(float)
        assert min(np.abs(on_curve - c).max() for c in colours.values()) > 40, on_curve
    finally:
        view.close()

    axial = offscreen.SliceView(scene, "Axial", size=(240, 160))
    try:
        axial.show((0.0, 0.0, 0.0), 120.0)
        image = axial.render()
        axial.save_png(tmp_path / "ds_axial.png", image)
        row, col = axial.pixel((X, -15.0, 0.0))
        assert image[row - 1:row + 2, col - 1:col + 2].max() > 100  # the intersection line
        assert not image[axial.pixel((X + 20.0, -15.0, 0.0))].any()  # nothing off the cut
    finally:
        axial.close()
