"""Texture images for scene specs: photographs bundled with scikit-image, files, ChArUco boards
drawn by OpenCV, seeded procedural patterns. All return (H, W, 3) uint8 sRGB."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from .scene_file import note_read
from .spec import MAX_TEXTURE_SIDE, CharucoTexture, ProceduralTexture, SpecError, TextureSpec, resolve_file

if TYPE_CHECKING:  # imported where a board is drawn or noise resized: a scene without those (the
    import cv2  # Cornell box) loads without OpenCV (start-up cost)

__all__ = ["load_texture", "charuco_board", "charuco_image"]


def charuco_board(spec: CharucoTexture) -> "cv2.aruco.CharucoBoard":
    """The OpenCV board object (lengths in scene units) a detector needs."""
    import cv2

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
        import cv2

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
        board = charuco_image(spec.charuco)
        import cv2

        note_read(Path(cv2.__file__), f"textures.{name}.charuco")  # drawn by this OpenCV: the scene cache's stamp
        return board
    if spec.procedural is not None:
        return _procedural(spec.procedural)
    src = spec.image.image
    field = f"textures.{name}.image"
    if src.startswith("skimage:"):
        import skimage.data

        # the schema allows only images bundled with scikit-image (no download, no other callable)
        img = np.asarray(getattr(skimage.data, src.split(":", 1)[1])())
        note_read(Path(skimage.data.__file__), field)  # the scene cache's stamp: a new scikit-image is a miss
    else:
        img = _read_image(resolve_file(base_dir, src, field), field)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img[..., :3].astype(np.uint8))


def _read_image(path: Path, field: str) -> np.ndarray:
    """(H, W, 3) uint8 from an image file; SpecError naming ``field`` for anything unreadable or
    larger than MAX_TEXTURE_SIDE per side (judged from the header, before decoding)."""
    try:
        with warnings.catch_warnings():
            # Pillow's warnings (e.g. about palette transparency) would add lines to the one-line error
            warnings.simplefilter("ignore")
            with Image.open(path) as im:
                w, h = im.size
                if max(w, h) > MAX_TEXTURE_SIDE:
                    raise SpecError(f"{field}: {path} is {w} x {h} pixels, at most {MAX_TEXTURE_SIDE} per side")
                return np.asarray(im.convert("RGB"))
    except SpecError:
        raise
    except Exception as exc:  # Pillow raises OSError, ValueError, SyntaxError... for broken files
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise SpecError(f"{field}: cannot read {path} as an image ({why})") from None
