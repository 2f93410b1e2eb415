"""A small synthetic liver on an oblique, anisotropic grid, with its analytic truth.

The same shapes as `resecta phantom --preset small` (an ellipsoid liver 40×30×25 mm turned 20°
about S, a spherical tumour of radius 8 mm at (10, 5, 0), a portal vessel of radius 3 mm), on a
2×2×3 mm grid turned a few degrees about every axis. The self-test inside Slicer uses it (it has
no `resecta` binary to make a phantom with); the pytest suite uses the binary's phantom and this
one. `truth` describes both the same way (see `truth_from_phantom_json`).
"""

from __future__ import annotations

import numpy as np


def rotation_xyz(deg) -> np.ndarray:
    """Rz · Ry · Rx of the angles (degrees) about R, A, S."""
    ax, ay, az = np.radians(deg)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


LIVER = {"center": (0.0, 0.0, 0.0), "radii": (40.0, 30.0, 25.0), "rotation": rotation_xyz((0, 0, 20))}
TUMOUR = {"center": (10.0, 5.0, 0.0), "radius": 8.0}
PORTAL = {"points": ((-20.0, -5.0, -5.0), (0.0, -10.0, 0.0)), "radius": 3.0}


def make(dims=(48, 40, 26), spacing=(2.0, 2.0, 3.0), angles=(3.0, -2.0, 6.0)):
    """(labels (k, j, i) int16, IJK→RAS 4×4, {label: segment name}, truth)."""
    direction = rotation_xyz(angles)
    a = direction * np.asarray(spacing)
    origin = -a @ ((np.asarray(dims) - 1) / 2.0) + np.array([0.3, -0.2, 0.1])
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = a
    ijk_to_ras[:3, 3] = origin
    k, j, i = np.meshgrid(np.arange(dims[2]), np.arange(dims[1]), np.arange(dims[0]), indexing="ij")
    ijk = np.stack([i, j, k], axis=-1).reshape(-1, 3).astype(float)
    ras = ijk @ a.T + origin
    labels = np.zeros(len(ras), dtype=np.int16)
    local = (ras - LIVER["center"]) @ LIVER["rotation"]  # R^T (p - c)
    labels[((local / LIVER["radii"]) ** 2).sum(axis=1) <= 1.0] = 1
    p0, p1 = (np.asarray(p) for p in PORTAL["points"])
    d = p1 - p0
    t = np.clip(((ras - p0) @ d) / (d @ d), 0.0, 1.0)
    labels[np.linalg.norm(ras - (p0 + t[:, None] * d), axis=1) <= PORTAL["radius"]] = 3
    labels[np.linalg.norm(ras - TUMOUR["center"], axis=1) <= TUMOUR["radius"]] = 2
    labels = labels.reshape(dims[2], dims[1], dims[0])
    names = {1: "liver", 2: "tumour", 3: "portal vein"}
    return labels, ijk_to_ras, names, truth()


def truth() -> dict:
    r = LIVER["radii"]
    return {
        "liver": {"center": np.array(LIVER["center"]), "radii": np.array(r),
                  "rotation": np.array(LIVER["rotation"])},
        "tumour": {"center": np.array(TUMOUR["center"]), "radius": TUMOUR["radius"]},
        "liver_ml": 4.0 / 3.0 * np.pi * r[0] * r[1] * r[2] / 1000.0,
    }


def truth_from_phantom_json(d: dict) -> dict:
    """The same structure from the `truth.json` that `resecta phantom` writes."""
    shapes = d["shapes"]
    liver = next(s for s in shapes if s["kind"] == "ellipsoid")
    tumour = next(s for s in shapes if s["kind"] == "sphere")
    return {
        "liver": {"center": np.array(liver["center"]), "radii": np.array(liver["radii"]),
                  "rotation": np.array(liver["rotation"])},
        "tumour": {"center": np.array(tumour["center"]), "radius": float(tumour["radius"])},
        "liver_ml": d["liver"]["volume_mm3"] / 1000.0,
    }


def ellipsoid_half_extent(radii, rotation) -> np.ndarray:
    """Half the axis-aligned bounding box of a rotated ellipsoid, per RAS axis."""
    m = np.asarray(rotation) * np.asarray(radii)  # columns: the semi-axes in RAS
    return np.sqrt((m ** 2).sum(axis=1))
