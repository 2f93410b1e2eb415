"""Pictures of `resecta territories` output: an axial and a coronal slice of a territory map,
coloured by territory, with the centreline points within 4 mm of each slice.

Usage: python plot_territories.py OUT_DIR SYSTEM PICTURE.png
(OUT_DIR: the folder `resecta territories --out-dir` wrote; SYSTEM: portal, hepatic or vessel.)
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import nibabel as nib  # noqa: E402
import numpy as np  # noqa: E402
import vtk  # noqa: E402
from vtk.util import numpy_support  # noqa: E402


def main(out_dir: Path, system: str, picture: Path) -> None:
    img = nib.load(str(out_dir / f"{system}-territories.nii.gz"))
    lab = np.asarray(img.dataobj).astype(int)
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(out_dir / f"{system}-centrelines.vtp"))
    reader.Update()
    ras = numpy_support.vtk_to_numpy(reader.GetOutput().GetPoints().GetData())
    ijk = nib.affines.apply_affine(np.linalg.inv(img.affine), ras)
    zooms = img.header.get_zooms()[:3]
    n = lab.max()
    colours = plt.get_cmap("tab20", max(n, 1))
    shown = np.ma.masked_where(lab == 0, lab)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.2))
    for ax, axis, name in [(axes[0], 2, "axial"), (axes[1], 1, "coronal")]:
        k = int(np.argmax((lab > 0).sum(axis=tuple(a for a in range(3) if a != axis))))
        sl = np.take(shown, k, axis=axis)
        keep = np.abs(ijk[:, axis] - k) * zooms[axis] <= 4.0
        rest = [a for a in range(3) if a != axis]
        aspect = zooms[rest[1]] / zooms[rest[0]]
        ax.imshow(sl.T, origin="lower", cmap=colours, vmin=0.5, vmax=n + 0.5,
                  interpolation="nearest", aspect=aspect)
        ax.scatter(ijk[keep, rest[0]], ijk[keep, rest[1]], s=2, c="black")
        ax.set_title(f"{name} slice {k}: {n} territories, centrelines within 4 mm")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{out_dir.name}: {system} territories (resecta territories)")
    fig.tight_layout()
    fig.savefig(picture, dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]))
