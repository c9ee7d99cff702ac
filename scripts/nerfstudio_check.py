"""Does nerfstudio read a capture where its ground truth says? ``python scripts/nerfstudio_check.py CAPTURE``

Runs nerfstudio 1.1.5's own dataparser (installed by ``make setup``, through
tests/pipeline/nerfstudio_reader.py in a subprocess) on a capture folder and prints its splits, its
normalisation scale per split, and how far (in pixels at the point's depth) the rays nerfstudio
generates pass from ground-truth depth points: 16 random depth pixels per view, seed 0. The test
(tests/pipeline/test_export.py) asserts the same on a 128x96 capture; this measures any capture,
e.g. the default one (issue 18's figure: 2.7e-4 px at most on artifacts/turntable/capture).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from render.camera_io import read_cameras_json  # noqa: E402
from render.image_io import read_exr  # noqa: E402
from tests.pipeline.test_export import _gt_points, _nerfstudio  # noqa: E402


def main(capture: Path, per_view: int = 16) -> None:
    cams, splits = read_cameras_json(capture / "cameras.json")
    by_name = {c.name: c for c in cams}
    rng = np.random.default_rng(0)
    coords, truth = {}, {}
    for split in ("train", "test"):
        names = sorted(c.name for c, s in zip(cams, splits) if s == split)  # nerfstudio sorts by file name
        coords[split], truth[split] = [], []
        for i, n in enumerate(names):
            depth = read_exr(capture / "depth" / f"{n}.exr")
            rows, cols = np.nonzero(depth > 0)
            pick = rng.choice(len(rows), size=min(per_view, len(rows)), replace=False)
            rc = list(zip(rows[pick].tolist(), cols[pick].tolist()))
            coords[split] += [[i, r + 0.5, c + 0.5] for r, c in rc]
            truth[split].append(_gt_points(by_name[n], depth, rc))
    with tempfile.TemporaryDirectory() as tmp:
        out = _nerfstudio(Path(tmp), {"parser": "nerfstudio", "data": str(capture), "splits": ["train", "val", "test"],
                                      "coords": coords})
    print(f"nerfstudio {out['nerfstudio']}: train/val/test {len(out['train']['images'])}/{len(out['val']['images'])}/"
          f"{len(out['test']['images'])}, scale train {out['train']['scale']:.6f} test {out['test']['scale']:.6f}")
    T = np.vstack([np.array(out["train"]["transform"]), [0, 0, 0, 1]])
    for split in ("train", "test"):
        pts = np.concatenate(truth[split])
        pts_ns = (pts @ T[:3, :3].T + T[:3, 3]) * out[split]["scale"]
        o, d = np.array(out[split]["origins"]), np.array(out[split]["directions"])
        along = np.sum((pts_ns - o) * d, axis=1)
        off_ray = np.linalg.norm(pts_ns - o - along[:, None] * d, axis=1)
        px = off_ray / along * np.array(out[split]["fx"])[[c[0] for c in coords[split]]]
        print(f"{split}: {len(px)} depth points, ray distance max {px.max():.2e} px, median {np.median(px):.2e} px")


if __name__ == "__main__":
    if len(sys.argv) != 2 or not Path(sys.argv[1], "cameras.json").is_file():
        print("usage: python scripts/nerfstudio_check.py CAPTURE_DIR (a folder with cameras.json)", file=sys.stderr)
        sys.exit(2)
    main(Path(sys.argv[1]))
