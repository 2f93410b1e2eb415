"""The work of the Resecta Slicer module, without Qt and without Slicer's GUI helpers.

Everything here runs on MRML and VTK only (3D Slicer's own, or PyPI's `slicer-core` wheel), so
the same code serves the module inside Slicer and the pytest suite outside it:

- `segmentation`: a segmentation node → label array + IJK→RAS matrix + role map (upload input)
- `models`: client meshes (numpy) → model nodes, updated in place; palette and margin colours
- `controlgrid`: the Bézier control grid ↔ a markups node (row-major, i along u)
- `traces`: markups curves ↔ the traces of DS and CP resections; the CP deformation handle
- `coalesce`: the edit coalescer used while dragging control points
- `dispatch`: how worker-thread results reach the main thread (synchronous, polled queue)
- `margin`: the global margin indicator's state
- `volumetry`: the volumetry table and each resection's kind and metrics as plain rows
- `planfile`: plan JSON files (save / load / check)
- `preview`: the slicing contour shown before a resection is created (Algorithm 1's plane)
- `session`: `PlanningSession`, the Logic proper (server calls on a worker, scene updates on the
  main thread)
- `deps`: the Python packages installed on first use (never at import)
- `phantom`, `selftest`: the scenario shared by the pytest suite and the module's self-test
"""

# Submodules are imported by name (`from ResectaLib import session`) so that importing the
# package stays cheap and never imports the client or gRPC (installed on first use in Slicer).
