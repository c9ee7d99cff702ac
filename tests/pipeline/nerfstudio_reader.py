"""Run nerfstudio 1.1.5's own dataparsers on a folder and print what they produced as JSON.

Used by tests/pipeline/test_export.py in a subprocess (python tests/pipeline/nerfstudio_reader.py
REQUEST.json). nerfstudio is installed without its dependencies (``make setup``: ``pip install
--no-deps nerfstudio==1.1.5 jaxtyping``): its parsers need only torch, numpy, PIL, imageio, cv2,
rich and jaxtyping, but their modules import two heavy packages at module level that parsing
never calls, so those two are stubbed here, in this process only: ``viser.transforms`` (SO3 for
oriented boxes in the viewer) and ``torch.utils.tensorboard`` (the training log writer).

REQUEST: {"parser": "nerfstudio" | "blender", "data": path, "splits": [...],
"coords": {split: [[camera_index, row_y, col_x], ...]}, "depth_files": [paths]} ->
stdout JSON: per split the image and mask file names, the dataparser transform (3x4) and scale,
cameras (c2w 3x4, fx, fy, cx, cy, w, h) and the rays nerfstudio generates at ``coords``
(origins, unit directions); for "depth_files", nerfstudio's depth loader's values in metres at
its default depth_unit_scale_factor.
"""
from __future__ import annotations

import json
import sys
import types
from pathlib import Path


def _stub(name: str, **attrs) -> None:
    mod = types.ModuleType(name)
    mod.__dict__.update(attrs)
    sys.modules[name] = mod


def main(request_file: str) -> None:
    req = json.loads(Path(request_file).read_text())
    _stub("viser")
    _stub("viser.transforms")
    sys.modules["viser"].transforms = sys.modules["viser.transforms"]
    _stub("torch.utils.tensorboard", SummaryWriter=object)
    import nerfstudio
    import torch

    out: dict = {"nerfstudio": getattr(nerfstudio, "__version__", None)}
    from importlib.metadata import version
    out["nerfstudio"] = version("nerfstudio")
    if req["parser"] == "nerfstudio":
        from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig as Config
    else:
        from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig as Config
    parser = Config(data=Path(req["data"])).setup()
    for split in req["splits"]:
        o = parser.get_dataparser_outputs(split=split)
        cams = o.cameras
        entry = {"images": [str(p) for p in o.image_filenames],
                 "masks": [str(p) for p in (o.mask_filenames or [])],
                 "depth_files": [str(p) for p in (o.metadata.get("depth_filenames") or [])],
                 "transform": o.dataparser_transform.tolist(), "scale": float(o.dataparser_scale),
                 "c2w": cams.camera_to_worlds.tolist(), "fx": cams.fx.flatten().tolist(),
                 "fy": cams.fy.flatten().tolist(), "cx": cams.cx.flatten().tolist(),
                 "cy": cams.cy.flatten().tolist(), "w": cams.width.flatten().tolist(),
                 "h": cams.height.flatten().tolist()}
        coords = req.get("coords", {}).get(split)
        if coords:
            idx = torch.tensor([[c[0]] for c in coords], dtype=torch.long)
            yx = torch.tensor([[c[1], c[2]] for c in coords], dtype=torch.float32)
            rays = cams.generate_rays(camera_indices=idx, coords=yx)
            entry["origins"] = rays.origins.tolist()
            entry["directions"] = rays.directions.tolist()
        out[split] = entry
    if req.get("depth_files"):
        from nerfstudio.data.utils.data_utils import get_depth_image_from_path

        out["depth"] = []
        for f in req["depth_files"]:
            from PIL import Image
            w, h = Image.open(f).size
            d = get_depth_image_from_path(Path(f), h, w, scale_factor=1e-3)  # nerfstudio's default unit (mm)
            out["depth"].append(d[..., 0].tolist())
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
