"""Margins true to the segmentation on real label maps (MSD Task08, through the server): for
planes at known gaps from the nearest tumour voxel centre, the reported minimum margin never
exceeds the distance to the nearest tumour voxel centre and never falls below the distance to
the tumour's voxel cubes by more than 0.05 mm; the reported uncertainty covers the difference."""
import sys

import nibabel as nib
import numpy as np
import pytest

from conftest import ROOT
from server_harness import planning_client as client  # noqa: F401  (fixture)

sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client import Target  # noqa: E402

MSD = ("liver", "msd-task08-hepaticvessel")
ROLES = {"parenchyma": [1], "tumor": [2]}
BELOW_CUBES_MM = 0.05


@pytest.mark.parametrize("case", ["002", "008", "010"])
def test_real_tumours_margins_never_exceed_the_nearest_voxel_centre(client, test_data, case):
    folder = test_data.joinpath(*MSD)
    path = folder / f"hepaticvessel_{case}_label.nii.gz"
    if not path.is_file():
        print(f"SKIP: MSD case {case} not found in {folder}")
        pytest.skip(f"MSD case {case} not found")
    img = nib.load(path)
    msd = np.asarray(img.dataobj)
    liver = np.asarray(nib.load(folder / f"hepaticvessel_{case}_liver_pred.nii.gz").dataobj) == 1
    labels = np.where(liver, 1, 0).astype(np.uint8)
    labels[liver & (msd == 2)] = 2
    if not (labels == 2).any():
        pytest.skip(f"MSD case {case}: no tumour inside the liver mask")
    affine = img.affine
    cell = affine[:3, :3]
    centres = np.argwhere(labels == 2) @ cell.T + affine[:3, 3]
    s = client.create_session(f"margins-{case}")
    s.upload_label_map(labels.transpose(2, 1, 0), affine, ROLES)
    rng = np.random.default_rng(int(case))
    checked = 0
    for cut in range(8):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        gap = float(rng.uniform(1.0, 8.0))
        heights = centres @ n
        nearest = centres[np.argmin(heights)]
        foot = nearest - gap * n
        # The check needs the nearest centre's foot on the cut inside the liver (where margins
        # count); the plane is drawn over the liver's whole section.
        ijk = np.rint(np.linalg.solve(cell, foot - affine[:3, 3])).astype(int)
        if (ijk < 0).any() or (ijk >= labels.shape).any() or labels[tuple(ijk)] != 1:
            continue
        name = f"c{cut}"
        result = s.init_from_plane(name, tuple(foot), tuple(n), target=Target(labels=(2,)))
        v = result[name].verdict
        h = 0.5 * np.abs(cell.T @ n).sum()  # half a voxel along n
        got = v.min_margin_mm
        print(f"case {case} cut {cut}: reported {got:.3f} (+{v.margin_uncertainty_mm:.3f}) mm, "
              f"nearest voxel centre {gap:.3f} mm, voxel cubes {gap - h:.3f} mm")
        assert got <= gap + 1e-6, f"reported {got} > nearest voxel centre {gap}"
        assert got >= gap - h - BELOW_CUBES_MM, f"reported {got} < voxel cubes {gap - h}"
        assert got < 0.05 or gap <= got + v.margin_uncertainty_mm + 0.02
        s.delete_resection(name)
        checked += 1
    assert checked >= 3, f"only {checked} cuts had their nearest point inside the liver"
    s.delete()
