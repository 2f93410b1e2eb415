"""One model per segment through the server (gRPC, the Python client): vessel labels as one model
holding all their pieces, tumours one per component, specks left out and counted; the
per-component split on request. On a synthetic map and on a real MSD case whose vessels and
tumours are clipped to the liver (many pieces)."""
import sys

import nibabel as nib
import numpy as np
import pytest

from conftest import ROOT
from server_harness import planning_client as client  # noqa: F401  (fixture)

sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client import InvalidArgument, SurfaceKind  # noqa: E402

ROLES = {"parenchyma": [1], "tumor": [2], "portal": [3]}
MSD = ("liver", "msd-task08-hepaticvessel")


def fragmented_map() -> np.ndarray:
    """A 1 mm liver block with three disconnected portal bars, two tumour balls and a one-voxel
    (1 mm³) speck of each, as (k, j, i)."""
    labels = np.zeros((30, 40, 60), np.uint8)
    labels[2:28, 2:38, 2:58] = 1
    for j in (8, 18, 28):
        labels[10:14, j:j + 4, 8:50] = 3
    k, j, i = np.mgrid[:30, :40, :60]
    for centre, r in (((20, 20, 15), 5), ((20, 20, 42), 4)):
        labels[(k - centre[0]) ** 2 + (j - centre[1]) ** 2 + (i - centre[2]) ** 2 <= r * r] = 2
    labels[5, 34, 30] = 2
    labels[24, 4, 30] = 3
    return labels


def by_kind(models, kind):
    return [m for m in models if m.kind == kind]


def test_one_model_per_segment_specks_counted_and_split_on_request(client):
    s = client.create_session("segments")
    s.upload_label_map(fragmented_map(), np.eye(4), ROLES)
    built = s.reconstruct("mcsd")
    assert [m.name for m in built] == ["parenchyma", "tumor_1", "tumor_2", "portal_1"]
    assert [m.label for m in built] == [1, 2, 2, 3]
    dropped = {d.kind: d for d in built.dropped}
    assert set(dropped) == {SurfaceKind.TUMOR, SurfaceKind.PORTAL}
    for d in dropped.values():
        assert d.count == 1 and d.volume_ml == pytest.approx(0.001)
    assert built.min_component_mm3 == 10 and built.elapsed_s > 0

    split = s.reconstruct("mcsd", split_components=True, min_component_mm3=0)
    assert [m.name for m in by_kind(split, SurfaceKind.PORTAL)] == [
        "portal_1", "portal_2", "portal_3", "portal_4"]
    assert all(m.label == 3 for m in by_kind(split, SurfaceKind.PORTAL))
    # The tumour speck stays out whatever the request: tumour models are the planning targets.
    assert len(by_kind(split, SurfaceKind.TUMOR)) == 2
    assert [(d.kind, d.count) for d in split.dropped] == [(SurfaceKind.TUMOR, 1)]

    for bad in (-1.0, float("nan")):
        with pytest.raises(InvalidArgument, match="min_component_mm3"):
            s.reconstruct("mcsd", min_component_mm3=bad)
    s.delete()


def test_real_msd_case_clipped_to_the_liver_gives_one_model_per_segment(client, test_data):
    folder = test_data.joinpath(*MSD)
    if not (folder / "hepaticvessel_002_label.nii.gz").is_file():
        print(f"SKIP: MSD case 002 not found in {folder}")
        pytest.skip(f"MSD case 002 not found in {folder}")
    img = nib.load(folder / "hepaticvessel_002_label.nii.gz")
    msd = np.asarray(img.dataobj)
    liver = np.asarray(nib.load(folder / "hepaticvessel_002_liver_pred.nii.gz").dataobj) == 1
    # Vessels and tumours segmented inside the liver only: both fall apart into pieces.
    labels = np.where(liver, 1, 0).astype(np.uint8)
    labels[liver & (msd == 1)] = 3
    labels[liver & (msd == 2)] = 2
    s = client.create_session("msd-002")
    s.upload_label_map(labels.transpose(2, 1, 0), img.affine, ROLES)
    split = s.reconstruct("mcsd", split_components=True, min_component_mm3=0)
    built = s.reconstruct("mcsd")
    vessels = by_kind(built, SurfaceKind.PORTAL)
    assert [(m.name, m.label) for m in vessels] == [("portal_1", 3)]
    assert len(by_kind(split, SurfaceKind.PORTAL)) > 10
    tumours = by_kind(built, SurfaceKind.TUMOR)
    assert tumours and all(m.label == 2 for m in tumours)
    assert len(tumours) == len(by_kind(split, SurfaceKind.TUMOR))
    assert len(built) == 2 + len(tumours)
    # The tumour's one- and two-voxel fragments are counted, not modelled.
    dropped = {d.kind: d for d in built.dropped}
    assert dropped[SurfaceKind.TUMOR].count > 0
    assert 0 < dropped[SurfaceKind.TUMOR].volume_ml < 0.1
    s.delete()
