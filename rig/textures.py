"""Texture images for scene specs: photographs bundled with scikit-image, files, ChArUco boards
drawn by OpenCV, seeded procedural patterns. All return (H, W, 3) uint8 sRGB."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from .spec import CharucoTexture, ProceduralTexture, SpecError, TextureSpec

__all__ = ["load_texture", "charuco_board", "charuco_image"]


def charuco_board(spec: CharucoTexture) -> "cv2.aruco.CharucoBoard":
    """The OpenCV board object (lengths in scene units) a detector needs."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    return cv2.aruco.CharucoBoard(tuple(spec.squares), spec.square_length, spec.marker_length, dictionary)


def charuco_image(spec: CharucoTexture) -> np.ndarray:
    """(H, W, 3) uint8 image of the board, exactly ``pixels_per_square`` per square, no margin.

    Row 0 is the board's top edge, where OpenCV's board frame has its origin (x right, y down).
    """
    cols, rows = spec.squares
    px = spec.pixels_per_square
    img = charuco_board(spec).generateImage((cols * px, rows * px), marginSize=0, borderBits=1)
    return np.repeat(img[..., None], 3, axis=2)


def _procedural(spec: ProceduralTexture) -> np.ndarray:
    rng = np.random.default_rng(spec.seed)
    n = spec.size
    if spec.kind == "checker":
        cells = (np.arange(n) * spec.cells // n)
        mask = (cells[:, None] + cells[None, :]) % 2
        colours = rng.uniform(0.1, 0.9, size=(2, 3))
        img = colours[mask]
    else:
        # sum of octaves of bilinearly upsampled noise: rich, non-repeating detail for features
        img = np.zeros((n, n, 3))
        for octave in range(1, 7):
            k = min(n, 2 ** (octave + 1))
            layer = rng.uniform(0, 1, size=(k, k, 3)).astype(np.float32)
            img += cv2.resize(layer, (n, n), interpolation=cv2.INTER_CUBIC) / octave
        img = (img - img.min()) / max(np.ptp(img), 1e-9)
    return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)


def load_texture(name: str, spec: TextureSpec, base_dir: Path) -> np.ndarray:
    """Resolve one texture entry of a spec to (H, W, 3) uint8 sRGB; SpecError on failure."""
    if spec.charuco is not None:
        return charuco_image(spec.charuco)
    if spec.procedural is not None:
        return _procedural(spec.procedural)
    src = spec.image.image
    if src.startswith("skimage:"):
        import skimage.data

        fn = getattr(skimage.data, src.split(":", 1)[1], None)
        if fn is None or not callable(fn):
            raise SpecError(f"textures.{name}.image: scikit-image has no bundled image '{src}'")
        img = np.asarray(fn())
    else:
        path = (base_dir / src) if not Path(src).is_absolute() else Path(src)
        if not path.is_file():
            raise SpecError(f"textures.{name}.image: file not found: {path}")
        img = np.asarray(Image.open(path).convert("RGB"))
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img[..., :3].astype(np.uint8))
