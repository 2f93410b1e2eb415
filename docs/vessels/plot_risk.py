"""Picture of a plan's vascular risk: axial and coronal slices of `resecta plan --out-dir`'s
risk map (functional remnant, resected, devascularised, congested) beside the resection's
resectogram PNG (`resecta resectogram`).

Usage: python plot_risk.py OUT_DIR RESECTOGRAM.png PICTURE.png
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import nibabel as nib  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

CLASSES = [  # code, name, colour (as the Slicer module's risk segments)
    (0, "not liver", "#ffffff"),
    (1, "functional remnant", "#4caf50"),
    (2, "resected", "#9e9e9e"),
    (3, "devascularised", "#e53935"),
    (4, "congested", "#8e24aa"),
    (5, "both", "#7f0000"),
]


def main(out_dir: Path, resectogram: Path, picture: Path) -> None:
    img = nib.load(str(out_dir / "risk.nii.gz"))
    cls = np.asarray(img.dataobj).astype(int)
    zooms = img.header.get_zooms()[:3]
    cmap = ListedColormap([c for _, _, c in CLASSES])
    # The slices through the middle of the devascularised or congested region (else the box).
    lost = np.argwhere(cls >= 3)
    centre = np.median(lost, axis=0).astype(int) if len(lost) else np.array(cls.shape) // 2
    fig, ax = plt.subplots(1, 3, figsize=(15, 5.2), gridspec_kw={"width_ratios": [1, 1, 1]})
    axial = cls[:, :, centre[2]].T
    coronal = cls[:, centre[1], :].T
    for a, sl, aspect, title in [
        (ax[0], axial, zooms[1] / zooms[0], f"axial slice k = {centre[2]}"),
        (ax[1], coronal, zooms[2] / zooms[0], f"coronal slice j = {centre[1]}"),
    ]:
        a.imshow(sl, origin="lower", cmap=cmap, vmin=0, vmax=5, interpolation="nearest", aspect=aspect)
        a.set_title(title)
        a.set_xticks([])
        a.set_yticks([])
    ax[2].imshow(plt.imread(str(resectogram)))
    ax[2].set_title("resectogram (u →, v ↓)")
    ax[2].set_xticks([])
    ax[2].set_yticks([])
    present = set(np.unique(cls))
    fig.legend(
        handles=[Patch(color=c, label=n) for k, n, c in CLASSES if k and k in present],
        loc="lower center",
        ncol=5,
    )
    fig.tight_layout(rect=(0, 0.07, 1, 0.96))
    fig.savefig(picture, dpi=90)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]))
