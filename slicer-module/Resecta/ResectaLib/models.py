"""Meshes from the server → model nodes, created once and then updated in place.

The client holds every watched surface as numpy arrays (`resecta_client.SurfaceState`) and
builds VTK polydata from them (`resecta_client.to_vtk_polydata`, the one numpy → VTK builder).
A model node is made the first time a name appears; later frames of the same name go into the
same `vtkPolyData` (same node, same polydata object; the same point arrays when the Watch update
changed rows only), so views, slice intersections and anything observing the node keep working
while the surface is dragged. Nodes carry the attribute `Resecta.Name` so they are found again
after a scene reload.
"""

from __future__ import annotations

import numpy as np
import vtk
from vtk.util import numpy_support

import slicer

NAME_ATTRIBUTE = "Resecta.Name"
KIND_ATTRIBUTE = "Resecta.Kind"
SESSION_ATTRIBUTE = "Resecta.SessionId"

#: Point-data array names on resection models (as `resecta plan --out-dir` writes them in VTP).
MARGIN_ARRAY = "margin_mm"
CLASS_ARRAY = "margin_class"

#: Display colours and opacities per surface kind, close to Slicer-Liver's and the
#: GenericAnatomyColors table (liver brown, portal vein violet-pink, hepatic vein blue, tumour
#: green, unsplit vessels red).
PALETTE: dict[str, tuple[tuple[float, float, float], float]] = {
    "parenchyma": ((0.867, 0.510, 0.396), 0.35),
    "tumor": ((0.306, 0.706, 0.306), 1.0),
    "portal": ((0.788, 0.373, 0.733), 1.0),
    "hepatic": ((0.000, 0.592, 0.808), 1.0),
    "vessel": ((0.847, 0.396, 0.310), 1.0),
    "resection": ((0.75, 0.75, 0.75), 1.0),
}

#: Margin classes (docs/wire/mesh-delta.md) and their colours: outside the liver (does not count),
#: safe (grey), warning band (yellow), violation (red), as the thesis and Slicer-Liver draw them.
MARGIN_CLASSES = (
    ("outside", (0.86, 0.86, 0.86, 0.35)),
    ("safe", (0.62, 0.62, 0.62, 1.0)),
    ("warning", (1.00, 0.85, 0.00, 1.0)),
    ("violation", (0.90, 0.05, 0.05, 1.0)),
)
MARGIN_COLOR_TABLE_NAME = "ResectaMarginClasses"


def kind_name(kind) -> str:
    """'parenchyma', 'tumor', ... from a proto `SurfaceKind` name or number, or a plain string."""
    if isinstance(kind, str):
        k = kind.lower()
        return k.removeprefix("surface_kind_")
    names = {1: "parenchyma", 2: "tumor", 3: "portal", 4: "hepatic", 5: "vessel", 6: "resection"}
    return names.get(int(kind), "vessel")


def margin_color_table(scene):
    """The colour table of margin classes (one per scene, found by name): entry i is class i.

    Its lookup table's range is (0, classes - 1), as Slicer gives its label tables, so that a
    display node mapping scalars through the table's range (`UseColorNodeScalarRange`) sends
    class i to entry i. A new `vtkMRMLColorTableNode` keeps VTK's range (0, 255) instead, which
    sends every class to entry 0. Set on every call, so a table from an older scene is
    repaired."""
    node = next((n for n in _nodes_of_class(scene, "vtkMRMLColorTableNode")
                 if n.GetName() == MARGIN_COLOR_TABLE_NAME), None)
    if node is None:
        node = scene.AddNewNodeByClass("vtkMRMLColorTableNode", MARGIN_COLOR_TABLE_NAME)
        node.SetTypeToUser()
        node.SetAttribute("Category", "Resecta")
    was_modifying = node.StartModify()
    node.SetNumberOfColors(len(MARGIN_CLASSES))
    node.GetLookupTable().SetTableRange(0, len(MARGIN_CLASSES) - 1)
    for i, (name, rgba) in enumerate(MARGIN_CLASSES):
        node.SetColor(i, name, *rgba)
    node.EndModify(was_modifying)
    return node


def _nodes_of_class(scene, cls: str):
    n = scene.GetNumberOfNodesByClass(cls)
    return [scene.GetNthNodeByClass(i, cls) for i in range(n)]


def find_model(scene, name: str, session_id: str | None = None):
    """The model node this module made for surface `name` (of `session_id` when given)."""
    for node in _nodes_of_class(scene, "vtkMRMLModelNode"):
        if node.GetAttribute(NAME_ATTRIBUTE) != name:
            continue
        if session_id is not None and node.GetAttribute(SESSION_ATTRIBUTE) not in (None, session_id):
            continue
        return node
    return None


def model_nodes(scene, session_id: str | None = None) -> list:
    """Every model node this module made (for `session_id` when given)."""
    out = []
    for node in _nodes_of_class(scene, "vtkMRMLModelNode"):
        if node.GetAttribute(NAME_ATTRIBUTE) is None:
            continue
        if session_id is not None and node.GetAttribute(SESSION_ATTRIBUTE) not in (None, session_id):
            continue
        out.append(node)
    return out


class ModelUpdater:
    """Creates and updates the model nodes of one session in a scene."""

    def __init__(self, scene, session_id: str = "", prefix: str = "Resecta"):
        self.scene = scene
        self.session_id = session_id
        self.prefix = prefix
        #: how many times a name's polydata was rebuilt (new mesh) vs updated in place
        self.rebuilds: dict[str, int] = {}
        self.updates: dict[str, int] = {}
        self._nodes: dict[str, object] = {}

    def find(self, name: str):
        """The model node of `name`: remembered, else looked up in the scene (after a reload
        the nodes are there before this updater knew them)."""
        node = self._nodes.get(name)
        if node is None or self.scene.GetNodeByID(node.GetID()) is not node:
            node = find_model(self.scene, name, self.session_id)
            if node is None:
                self._nodes.pop(name, None)
            else:
                self._nodes[name] = node
        return node

    def node_name(self, name: str) -> str:
        return f"{self.prefix} {name}"

    def upsert(self, surface, rebuild: bool = True):
        """The model node of `surface` (a `resecta_client.SurfaceState`), made or updated.

        With ``rebuild=False`` (the Watch update changed rows only, the name is not in its
        `rebuilt` set) the node's polydata keeps its VTK arrays and gets the new values in
        place; otherwise, or when the shapes no longer fit, it is rebuilt. Either way the node
        and its polydata object stay the same, so views and slice intersections follow."""
        from resecta_client.vtk_adapter import to_vtk_polydata

        name, kind = surface.name, kind_name(surface.kind)
        node = self.find(name)
        created = node is None
        if created:
            node = self.scene.AddNewNodeByClass("vtkMRMLModelNode", self.node_name(name))
            self._nodes[name] = node
            node.SetAttribute(NAME_ATTRIBUTE, name)
            node.SetAttribute(KIND_ATTRIBUTE, kind)
            if self.session_id:
                node.SetAttribute(SESSION_ATTRIBUTE, self.session_id)
            node.CreateDefaultDisplayNodes()
        poly = node.GetPolyData()
        fresh = poly is None
        if fresh:
            poly = vtk.vtkPolyData()
        before = poly.GetPoints().GetData() if poly.GetPoints() is not None else None
        to_vtk_polydata(surface, poly, rebuild=rebuild or fresh)
        in_place = not fresh and poly.GetPoints().GetData() is before
        counter = self.updates if in_place else self.rebuilds
        counter[name] = counter.get(name, 0) + 1
        if fresh:
            node.SetAndObservePolyData(poly)
        else:
            node.Modified()
        if created:
            self._style(node, kind, surface.color)
        return node

    def _style(self, node, kind: str, color=None) -> None:
        display = node.GetDisplayNode()
        rgb, opacity = PALETTE.get(kind, PALETTE["vessel"])
        if color is not None and kind not in PALETTE:
            rgb, opacity = tuple(color[:3]), (color[3] if len(color) > 3 else 1.0)
        display.SetColor(*rgb)
        display.SetOpacity(opacity)
        display.SetVisibility(True)
        display.SetVisibility2D(True)  # slice intersections
        display.SetSliceIntersectionThickness(2)
        if kind == "resection":
            display.SetBackfaceCulling(False)
            table = margin_color_table(self.scene)
            display.SetAndObserveColorNodeID(table.GetID())
            display.SetActiveScalar(CLASS_ARRAY, vtk.vtkAssignAttribute.POINT_DATA)
            # class i → entry i in 3D and on slices: the table's own range (0, classes - 1),
            # as Slicer does for label tables; per-vertex alpha comes from the table.
            display.SetScalarRangeFlag(slicer.vtkMRMLDisplayNode.UseColorNodeScalarRange)
            display.UpdateScalarRange()
            display.SetScalarVisibility(True)
            display.SetSliceIntersectionThickness(3)

    def remove(self, name: str) -> bool:
        node = self.find(name)
        if node is None:
            return False
        self._nodes.pop(name, None)
        self.scene.RemoveNode(node)
        return True

    def set_opacity(self, kinds: tuple[str, ...], opacity: float) -> None:
        for node in model_nodes(self.scene, self.session_id):
            if node.GetAttribute(KIND_ATTRIBUTE) in kinds and node.GetDisplayNode():
                node.GetDisplayNode().SetOpacity(float(opacity))


def polydata_arrays(node) -> dict[str, np.ndarray]:
    """Copies of a model node's positions, triangles and point arrays (for tests and export)."""
    poly = node.GetPolyData()
    out = {"positions": numpy_support.vtk_to_numpy(poly.GetPoints().GetData()).copy()}
    conn = poly.GetPolys().GetConnectivityArray()
    out["triangles"] = numpy_support.vtk_to_numpy(conn).reshape(-1, 3).copy()
    pd = poly.GetPointData()
    for i in range(pd.GetNumberOfArrays()):
        arr = pd.GetArray(i)
        out[arr.GetName()] = numpy_support.vtk_to_numpy(arr).copy()
    return out
