"""Watch updates → the scene, applied by the server's own account of what changed.

The watch thread hands every `resecta_client.SceneUpdate` to `enqueue`, which merges it into the
pending work (so a burst of deltas costs one scene update) and says whether a main-thread flush
must be scheduled. `flush(live)` then, on the main thread: a name in `rebuilt` gets its polydata
rebuilt, a name only in `changed` has its arrays overwritten in place, a name in `removed` loses
its model node and control grid; after a snapshot, model nodes of surfaces the server no longer
has are removed. Nothing compares meshes: the update says what to do.
"""

from __future__ import annotations

import dataclasses
import threading

from . import models
from .gridsync import GridSync


def is_bezier(resection) -> bool:
    """Whether a resection has a control grid (DS and CP resections have traces instead)."""
    return getattr(resection, "kind", "bezier") == "bezier"


@dataclasses.dataclass
class _Pending:
    changed: set = dataclasses.field(default_factory=set)
    rebuilt: set = dataclasses.field(default_factory=set)
    removed: set = dataclasses.field(default_factory=set)
    snapshot: bool = False
    volumes: bool = False


@dataclasses.dataclass
class Applied:
    """What one flush did."""

    models_added_or_removed: bool = False
    resections_added_or_removed: bool = False
    snapshot: bool = False
    #: resection name → (margin_mm, verdict) of the resections that changed
    verdicts: dict = dataclasses.field(default_factory=dict)
    removed: set = dataclasses.field(default_factory=set)
    #: the live scene's volumes when they changed, else None
    volumes: object = None
    #: model names whose mesh changed (cached centroids of them are stale)
    remeshed: set = dataclasses.field(default_factory=set)


class WatchApplier:
    def __init__(self, updater: models.ModelUpdater, grids: GridSync):
        self.updater = updater
        self.grids = grids
        self._pending = _Pending()
        self._lock = threading.Lock()
        self._scheduled = False
        #: flushes applied (tests, status line)
        self.flushes = 0

    def enqueue(self, update) -> bool:
        """Watch thread: merges `update`; True when the caller must schedule `flush`."""
        with self._lock:
            p = self._pending
            p.snapshot |= update.kind == "snapshot"
            p.changed |= set(update.changed)
            p.rebuilt |= set(update.rebuilt)
            p.removed |= set(update.removed)
            p.changed -= set(update.removed)
            p.rebuilt -= set(update.removed)
            p.removed -= set(update.changed)
            p.volumes |= bool(update.volumes_changed)
            if self._scheduled:
                return False
            self._scheduled = True
            return True

    def flush(self, live) -> Applied:
        """Main thread: applies the merged updates from `live` (a `resecta_client.LiveScene`)."""
        with self._lock:
            p, self._pending = self._pending, _Pending()
            self._scheduled = False
        out = Applied(snapshot=p.snapshot)
        scene, session_id = self.updater.scene, self.updater.session_id
        with live.lock:
            surfaces = dict(live.surfaces)
            if p.snapshot:
                for node in models.model_nodes(scene, session_id):
                    name = node.GetAttribute(models.NAME_ATTRIBUTE)
                    if name not in surfaces:
                        p.removed.add(name)
            for name in sorted(p.changed):
                s = surfaces.get(name)
                if s is None:
                    continue
                is_new = self.updater.find(name) is None
                self.updater.upsert(s, rebuild=name in p.rebuilt)
                if s.is_resection:
                    out.resections_added_or_removed |= is_new
                    if s.resection is not None:
                        out.verdicts[name] = (s.resection.margin_mm, s.verdict)
                        if is_bezier(s.resection):
                            self.grids.sync(name, s.resection)
                else:
                    out.models_added_or_removed |= is_new
                    out.remeshed.add(name)
            if p.volumes or p.snapshot:
                out.volumes = live.volumes
        for name in sorted(p.removed):
            node = self.updater.find(name)
            kind = node.GetAttribute(models.KIND_ATTRIBUTE) if node is not None else None
            if self.updater.remove(name):
                if kind == "resection":
                    out.resections_added_or_removed = True
                else:
                    out.models_added_or_removed = True
            self.grids.remove(name)
            out.removed.add(name)
        self.flushes += 1
        return out

    def resync_grids(self, live) -> None:
        """Brings every grid in line with the server (after drags are answered)."""
        with live.lock:
            resections = [(n, s.resection) for n, s in live.surfaces.items()
                          if s.is_resection and s.resection is not None and is_bezier(s.resection)]
        for name, resection in resections:
            self.grids.sync(name, resection)
