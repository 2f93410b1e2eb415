"""Model nodes as Slicer draws them: rendered offscreen through the real
`vtkMRMLModelDisplayableManager` (3D view) and `vtkMRMLModelSliceDisplayableManager` (slice
view) of `slicer-core`, pixels compared with the product colours.

Set-up: flat quads facing the camera (normals towards it, parallel projection, black
background), lit by the renderer's default headlight as in a Slicer 3D view, so a surface's
pixel is its colour exactly (Lambert, cos 0 = 1; display nodes have ambient 0, diffuse 1,
specular 0). Tolerance: ±4 per channel (8-bit rounding, blending) for opaque colours, ±6 for
translucent blends. Slice intersections are drawn unlit, so the same tolerance holds.
"""

import numpy as np
import pytest

from ResectaLib import models
from resecta_client.scene import SurfaceState
from resecta_client.types import SurfaceKind

import offscreen

TOL, TOL_BLEND = 4, 6
BLACK = (0.0, 0.0, 0.0)
CLASS = {name: i for i, (name, _) in enumerate(models.MARGIN_CLASSES)}
STRIPS = ("outside", "safe", "warning", "violation")  # the mixed surface, left to right
WIDTH = 30.0  # mm per strip; quads in the R–S plane at A = y


@pytest.fixture(scope="module")
def gl():
    problem = offscreen.offscreen_gl_problem()
    if problem:
        pytest.skip(f"no offscreen OpenGL: {problem}")


def rgb255(rgba):
    return np.array(rgba[:3]) * 255


def class_rgba(name):
    return models.MARGIN_CLASSES[CLASS[name]][1]


def quads(xs, y=0.0, half_height=40.0):
    """One quad per [x0, x1) in `xs`, in the plane A = y, normals towards −A (the camera);
    quads share no vertex, so each keeps its own colour."""
    pos, tri = [], []
    for x0, x1 in xs:
        k = len(pos)
        pos += [(x0, y, -half_height), (x1, y, -half_height), (x1, y, half_height),
                (x0, y, half_height)]
        tri += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    pos = np.array(pos, np.float32)
    normals = np.tile(np.float32([0, -1, 0]), (len(pos), 1))
    return pos, normals, np.array(tri, np.uint32)


def surface(name, kind, pos, normals, tri, classes=None):
    n = len(pos)
    return SurfaceState(name=name, kind=kind, label=0, color=None, positions=pos, normals=normals,
                        triangles=tri, margins=None if classes is None else np.zeros(n, np.float32),
                        classes=None if classes is None else np.asarray(classes, np.uint8))


def resection(scene, classes_per_strip, y=0.0):
    """A resection made by `ModelUpdater.upsert`, one strip per class name, left to right."""
    n = len(classes_per_strip)
    xs = [(WIDTH * (i - n / 2), WIDTH * (i + 1 - n / 2)) for i in range(n)]
    pos, normals, tri = quads(xs, y)
    classes = np.repeat([CLASS[c] for c in classes_per_strip], 4)
    node = models.ModelUpdater(scene, "s1").upsert(
        surface("r1", SurfaceKind.RESECTION, pos, normals, tri, classes))
    centres = [((x0 + x1) / 2, y, 0.0) for x0, x1 in xs]
    return node, centres


@pytest.fixture
def front(gl, scene):
    """A 3D view looking from the front (−A) at the R–S plane through the origin."""
    view = offscreen.ThreeDView(scene, (240, 160), background=BLACK)
    view.look((0, 0, 0), (0, -500, 0), parallel_scale=60)
    yield view
    view.close()


@pytest.fixture
def axial(gl, scene):
    """The axial slice (S = 0) through the origin, 160 mm wide."""
    view = offscreen.SliceView(scene, "Axial", size=(240, 160))
    view.show((0, 0, 0), 160)
    yield view
    view.close()


def at(image, view, ras):
    return image[view.pixel(ras)].astype(float)


def assert_rgb(got, want, tol=TOL):
    assert np.all(np.abs(got - np.asarray(want)) <= tol), \
        f"pixel {got} != {np.round(want)} ± {tol}"


# --- the display set-up, without rendering -------------------------------------------------


def test_class_i_maps_to_entry_i_through_the_display_nodes_range(scene):
    """What both displayable managers do: a copy of the colour node's table with the display
    node's scalar range. The old set-up (range 0–255) sent every class to entry 0."""
    node, _ = resection(scene, STRIPS)
    display = node.GetDisplayNode()
    table = scene.GetNodeByID(display.GetColorNodeID())
    assert display.GetScalarRangeFlag() == display.UseColorNodeScalarRange
    assert display.GetScalarRange() == (0.0, len(models.MARGIN_CLASSES) - 1)
    assert table.GetLookupTable().GetRange() == display.GetScalarRange()
    assert table.GetNumberOfColors() == len(models.MARGIN_CLASSES)
    lut = table.CreateLookupTableCopy()
    lut.SetRange(display.GetScalarRange())
    for i, (_name, rgba) in enumerate(models.MARGIN_CLASSES):
        rgb = [0.0] * 3
        lut.GetColor(i, rgb)
        assert rgb == pytest.approx(rgba[:3], abs=1 / 255)  # the table holds 8-bit colours
        assert lut.GetOpacity(i) == pytest.approx(rgba[3], abs=1 / 255)


def test_an_older_table_is_repaired(scene):
    table = scene.AddNewNodeByClass("vtkMRMLColorTableNode", models.MARGIN_COLOR_TABLE_NAME)
    table.SetTypeToUser()
    table.SetNumberOfColors(4)  # range (0, 255), as earlier versions left it
    assert models.margin_color_table(scene) is table
    assert table.GetLookupTable().GetRange() == (0.0, 3.0)


# --- 3D view -----------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", ["violation", "warning", "safe"])
def test_3d_view_draws_each_class_in_its_colour(front, scene, cls):
    _node, centres = resection(scene, [cls])
    image = front.render()
    got = at(image, front, centres[0])
    assert_rgb(got, rgb255(class_rgba(cls)))
    r, g, b = got
    if cls == "violation":
        assert r > 200 and g < 40 and b < 40  # red
    elif cls == "warning":
        assert r > 200 and g > 180 and b < 40  # yellow
    else:
        assert abs(r - g) < 8 and abs(g - b) < 8 and 120 < r < 200  # mid grey


def test_3d_view_mixed_surface_and_translucent_outside(front, scene):
    """One resection with all four classes, in front of an opaque tumour: the opaque classes
    hide it, the outside-liver strip lets it show through (the table's per-vertex alpha)."""
    _node, centres = resection(scene, STRIPS)
    pos, normals, tri = quads([(-80, 80)], y=20.0, half_height=50)
    tumour = models.ModelUpdater(scene, "s1").upsert(
        surface("tumor_1", SurfaceKind.TUMOR, pos, normals, tri))
    image = front.render()
    tumour.GetDisplayNode().SetVisibility(False)
    alone = front.render()
    green = rgb255(models.PALETTE["tumor"][0])
    for name, ras in zip(STRIPS, centres):
        if name == "outside":
            alpha = class_rgba(name)[3]
            own = alpha * rgb255(class_rgba(name))
            assert_rgb(at(image, front, ras), own + (1 - alpha) * green, TOL_BLEND)
            assert_rgb(at(alone, front, ras), own, TOL_BLEND)  # over black
        else:
            assert_rgb(at(image, front, ras), rgb255(class_rgba(name)))


@pytest.mark.parametrize("kind", [SurfaceKind.TUMOR, SurfaceKind.PARENCHYMA])
def test_3d_view_models_in_their_palette_colour(front, scene, kind):
    pos, normals, tri = quads([(-40, 40)])
    models.ModelUpdater(scene, "s1").upsert(surface("m", kind, pos, normals, tri))
    image = front.render()
    rgb, opacity = models.PALETTE[kind.value]
    assert_rgb(at(image, front, (0, 0, 0)), opacity * rgb255(rgb), TOL_BLEND)  # over black


# --- slice front --------------------------------------------------------------------------------


def test_slice_view_intersection_in_the_class_colours(axial, scene):
    """The axial slice through the mixed resection: its intersection line, strip by strip."""
    _node, centres = resection(scene, STRIPS)
    image = axial.render()
    for name, ras in zip(STRIPS, centres):
        rgba = class_rgba(name)
        assert_rgb(at(image, axial, ras), rgba[3] * rgb255(rgba), TOL_BLEND)  # over black
    row = axial.pixel(centres[0])[0]
    assert not image[row + 5].any() and not image[row - 5].any()  # a line, not a band


@pytest.mark.parametrize("cls", ["violation", "warning", "safe"])
def test_slice_view_each_class(axial, scene, cls):
    _node, centres = resection(scene, [cls])
    image = axial.render()
    assert_rgb(at(image, axial, centres[0]), rgb255(class_rgba(cls)))


def test_slice_view_model_in_its_palette_colour(axial, scene):
    pos, normals, tri = quads([(-40, 40)])
    models.ModelUpdater(scene, "s1").upsert(surface("t", SurfaceKind.TUMOR, pos, normals, tri))
    image = axial.render()
    assert_rgb(at(image, axial, (0, 0, 0)), rgb255(models.PALETTE["tumor"][0]))
