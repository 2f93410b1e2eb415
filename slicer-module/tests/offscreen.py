"""Slicer's own displayable managers rendering a scene offscreen: the 3D view and the slice view.

A real 3D Slicer draws model nodes with `vtkMRMLModelDisplayableManager` (3D views) and
`vtkMRMLModelSliceDisplayableManager` (slice intersections); PyPI's `slicer-core` ships both,
and their factories. `ThreeDView` and `SliceView` set them up the way Slicer's `qMRMLThreeDView`
and `qMRMLSliceView` do (a view / slice node, a displayable manager group made by the view
type's factory for a renderer), on an offscreen render window (EGL or OSMesa, no display), and
read back pixels. Used by the rendering tests (`tests/test_render.py`) and the user guide's
pictures (`docs/make_views.py`).
"""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np
import vtk
from vtk.util import numpy_support

import slicer

#: What each view type's factory instantiates (of the managers a Slicer view registers, those
#: that draw models and segmentations; a slice view's volumes come from `vtkMRMLSliceLogic`).
THREE_D_MANAGERS = ("vtkMRMLCameraDisplayableManager", "vtkMRMLViewDisplayableManager",
                    "vtkMRMLModelDisplayableManager", "vtkMRMLSegmentationsDisplayableManager3D")
SLICE_MANAGERS = ("vtkMRMLModelSliceDisplayableManager",)
#: Markups (control grids) in a view that asks for them, with Slicer's markups logic.
MARKUPS_MANAGER = "vtkMRMLMarkupsDisplayableManager"


class NoOffscreenGL(RuntimeError):
    """No offscreen OpenGL context can be made on this machine."""


#: Renders one red pixel offscreen and reads it back; run in a child process, since a machine
#: without a working EGL/OSMesa can crash the interpreter rather than report it.
_PROBE = """
import vtk
window = vtk.vtkRenderWindow()
window.SetOffScreenRendering(True)
window.SetSize(4, 4)
renderer = vtk.vtkRenderer()
renderer.SetBackground(1, 0, 0)
window.AddRenderer(renderer)
window.Render()
grab = vtk.vtkWindowToImageFilter()
grab.SetInput(window)
grab.Update()
print("ok" if grab.GetOutput().GetPointData().GetScalars().GetTuple(0)[:3] == (255, 0, 0)
      else "wrong pixel", window.GetClassName())
"""


@functools.cache
def offscreen_gl_problem() -> str:
    """Why no offscreen OpenGL context can be made here ("" when one can)."""
    try:
        run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                             timeout=120)
        out = run.stdout.split()
        if run.returncode == 0 and out[:1] == ["ok"]:
            return ""
        rc = run.returncode
        why = " ".join(out) or (f"killed by signal {-rc}" if rc < 0 else f"exit status {rc}")
    except subprocess.TimeoutExpired:
        why = "timed out"
    return (f"rendering a test pixel offscreen failed ({why}); install EGL with Mesa "
            "(Debian: libegl1 libegl-mesa0 libgl1-mesa-dri) or OSMesa (libosmesa6)")


def _application_logic(scene):
    logic = slicer.vtkMRMLApplicationLogic()
    logic.SetMRMLScene(scene)
    return logic


def _factory(factory_class, managers, app_logic):
    factory = factory_class.GetInstance()
    factory.SetMRMLApplicationLogic(app_logic)
    for name in managers:
        if not factory.IsDisplayableManagerRegistered(name):
            factory.RegisterDisplayableManager(name)
    return factory


class _View:
    """An offscreen render window with one renderer and an interactor (never started)."""

    def __init__(self, scene, size: tuple[int, int], factory_class, managers, view_node,
                 markups=False):
        problem = offscreen_gl_problem()
        if problem:
            raise NoOffscreenGL(problem)
        self.scene = scene
        self.size = size
        self.app_logic = _application_logic(scene)
        self.window = vtk.vtkRenderWindow()
        self.window.SetOffScreenRendering(True)
        self.window.SetSize(*size)
        self.window.SetMultiSamples(0)  # pixels exactly as drawn (no blending at edges)
        self.renderer = vtk.vtkRenderer()
        self.window.AddRenderer(self.renderer)
        self.interactor = vtk.vtkRenderWindowInteractor()
        self.interactor.SetRenderWindow(self.window)
        self.view_node = view_node
        self.group = _factory(factory_class, managers, self.app_logic) \
            .InstantiateDisplayableManagers(self.renderer)
        if markups:
            self.markups_logic = slicer.vtkSlicerMarkupsLogic()  # held: the app logic does not
            self.markups_logic.SetMRMLApplicationLogic(self.app_logic)
            self.markups_logic.SetMRMLScene(scene)
            self.app_logic.SetModuleLogic("Markups", self.markups_logic)
            manager = slicer.vtkMRMLDisplayableManagerGroup.InstantiateDisplayableManager(
                MARKUPS_MANAGER)
            manager.SetMRMLApplicationLogic(self.app_logic)
            self.group.AddDisplayableManager(manager)
        self.group.SetMRMLDisplayableNode(view_node)

    def render(self) -> np.ndarray:
        """Renders and returns the picture: (height, width, 3) uint8, row 0 at the top."""
        self.window.Render()
        grab = vtk.vtkWindowToImageFilter()
        grab.SetInput(self.window)
        grab.SetInputBufferTypeToRGB()
        grab.ReadFrontBufferOff()
        grab.Update()
        w, h = self.size
        rgb = numpy_support.vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars())
        return rgb.reshape(h, w, 3)[::-1].copy()

    def save_png(self, path: str | Path, image: np.ndarray | None = None) -> Path:
        """Writes the picture (rendered now unless given) as a PNG."""
        image = self.render() if image is None else image
        h, w, _ = image.shape
        data = vtk.vtkImageData()
        data.SetDimensions(w, h, 1)
        rows = np.ascontiguousarray(image[::-1]).reshape(-1, 3)  # VTK's row 0 is the bottom
        arr = numpy_support.numpy_to_vtk(rows, deep=True)
        data.GetPointData().SetScalars(arr)
        writer = vtk.vtkPNGWriter()
        writer.SetFileName(str(path))
        writer.SetInputData(data)
        writer.Write()
        return Path(path)

    def close(self) -> None:
        if self.group is not None:
            self.group.SetMRMLDisplayableNode(None)
            self.group = None
        self.window.Finalize()


def register_segmentation_converters() -> None:
    """Labelmap → closed surface for segmentations in 3D, as Slicer's Segmentations module
    registers it on start-up."""
    factory = slicer.vtkSegmentationConverterFactory.GetInstance()
    if not factory.GetConverterRules():
        factory.RegisterConverterRule(slicer.vtkBinaryLabelmapToClosedSurfaceConversionRule())
        factory.RegisterConverterRule(slicer.vtkClosedSurfaceToBinaryLabelmapConversionRule())


class ThreeDView(_View):
    """A 3D view (`vtkMRMLViewNode`) with Slicer's camera, view, model and segmentation
    displayable managers."""

    def __init__(self, scene, size=(320, 240), box=False, background=None, markups=False):
        register_segmentation_converters()
        node = scene.AddNewNodeByClass("vtkMRMLViewNode")
        node.SetLayoutName("1")
        node.SetBoxVisible(box)
        node.SetAxisLabelsVisible(box)
        if background is not None:
            node.SetBackgroundColor(*background)
            node.SetBackgroundColor2(*background)
        super().__init__(scene, size, slicer.vtkMRMLThreeDViewDisplayableManagerFactory,
                         THREE_D_MANAGERS, node, markups)
        # as qMRMLThreeDView does: translucent surfaces by depth peeling when the node asks
        self.window.SetAlphaBitPlanes(True)
        self.renderer.SetUseDepthPeeling(node.GetUseDepthPeeling())

    @property
    def camera(self):
        return self.renderer.GetActiveCamera()

    def look(self, focal, position, view_up=(0, 0, 1), parallel_scale: float | None = None):
        """Points the camera from `position` at `focal` (RAS mm); parallel projection with
        `parallel_scale` (half the view's height in mm) when given."""
        cam = self.camera
        cam.SetFocalPoint(*focal)
        cam.SetPosition(*position)
        cam.SetViewUp(*view_up)
        cam.SetParallelProjection(parallel_scale is not None)
        if parallel_scale is not None:
            cam.SetParallelScale(parallel_scale)
        self.renderer.ResetCameraClippingRange()

    def fit(self, azimuth=0.0, elevation=0.0, direction=(0, -1, 0), view_up=(0, 0, 1), zoom=1.0):
        """Shows every visible model: looking along `direction` (anterior → posterior by
        default: the patient's front), turned by `azimuth`/`elevation` degrees."""
        self.renderer.ResetCamera()
        cam = self.camera
        focal = np.array(cam.GetFocalPoint())
        dist = cam.GetDistance()
        self.look(focal, focal - dist * np.asarray(direction, float), view_up)
        self.renderer.ResetCamera()
        cam.Azimuth(azimuth)
        cam.Elevation(elevation)
        cam.OrthogonalizeViewUp()
        cam.Zoom(zoom)
        self.renderer.ResetCameraClippingRange()

    def pixel(self, ras) -> tuple[int, int]:
        """(row, column) of the picture where RAS point `ras` projects."""
        coord = vtk.vtkCoordinate()
        coord.SetCoordinateSystemToWorld()
        coord.SetValue(*ras)
        x, y = coord.GetComputedDoubleDisplayValue(self.renderer)
        return int(round(self.size[1] - 1 - y)), int(round(x))


class SliceView(_View):
    """A slice view (`vtkMRMLSliceNode`) with Slicer's model slice displayable manager: model
    intersections drawn on a black background, as in a Slicer slice view. With `volumes`, the
    layers of its slice composite node too: `vtkMRMLSliceLogic` reslices and blends them and
    the image is drawn under everything, as `qMRMLSliceWidget` does."""

    def __init__(self, scene, orientation="Axial", layout="Red", size=(320, 240), volumes=False):
        if scene.GetDefaultNodeByClass("vtkMRMLSliceNode") is None:  # Axial, Sagittal, Coronal
            slicer.vtkMRMLSliceNode.AddDefaultSliceOrientationPresets(scene)
        node = scene.CreateNodeByClass("vtkMRMLSliceNode")
        node.UnRegister(None)  # CreateNodeByClass hands over a reference
        node.SetLayoutName(layout)
        node.SetSingletonTag(layout)
        node = scene.AddNode(node)
        node.SetOrientation(orientation)
        node.SetDimensions(size[0], size[1], 1)
        self.slice_node = node
        super().__init__(scene, size, slicer.vtkMRMLSliceViewDisplayableManagerFactory,
                         SLICE_MANAGERS, node)
        self.slice_logic = self.image_mapper = None
        if volumes:
            self.slice_logic = slicer.vtkMRMLSliceLogic()
            self.slice_logic.SetMRMLApplicationLogic(self.app_logic)
            self.slice_logic.SetMRMLScene(scene)
            self.slice_logic.SetSliceNode(node)  # finds or makes the composite node
            self.image_mapper = vtk.vtkImageMapper()
            self.image_mapper.SetColorWindow(255)
            self.image_mapper.SetColorLevel(127.5)
            image = vtk.vtkActor2D()
            image.SetMapper(self.image_mapper)
            self.renderer.AddViewProp(image)

    def render(self) -> np.ndarray:
        if self.slice_logic is not None:  # the blend's output changes with the layers
            self.slice_logic.UpdatePipeline()
            self.image_mapper.SetInputConnection(self.slice_logic.GetImageDataConnection())
        return super().render()

    def show(self, center, field_of_view_mm: float):
        """Centres the slice on RAS `center` (its plane goes through it), `field_of_view_mm`
        wide."""
        w, h = self.size
        self.slice_node.SetFieldOfView(field_of_view_mm, field_of_view_mm * h / w, 1.0)
        self.slice_node.JumpSliceByCentering(*center)
        self.slice_node.UpdateMatrices()

    def pixel(self, ras) -> tuple[int, int]:
        """(row, column) of the picture where RAS point `ras` (on the slice plane) falls."""
        ras_to_xy = vtk.vtkMatrix4x4()
        vtk.vtkMatrix4x4.Invert(self.slice_node.GetXYToRAS(), ras_to_xy)
        x, y, _, _ = ras_to_xy.MultiplyPoint((*ras, 1.0))
        return int(round(self.size[1] - 1 - y)), int(round(x))
