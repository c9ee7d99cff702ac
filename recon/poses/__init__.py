"""Camera poses from images: COLMAP structure from motion, ChArUco boards, and their scoring
against ground truth (Umeyama similarity alignment, rotation / centre / intrinsics errors,
turntable self-check). Conventions: camera-to-world 4x4 float64, OpenCV axes, pixel centres at
+0.5 (see :mod:`render.camera`)."""
from .align import (Similarity, apply_similarity, intrinsics_error, projection_error, rotation_angles_deg,
                    scene_scale, score_cameras, sequence_rotation_bias, turntable_self_check, umeyama)
from .charuco import BoardNotFound, CharucoConfig, CharucoResult, detect_board, estimate_charuco, make_board
from .colmap import CAMERA_MODELS, ColmapConfig, ColmapResult, ReconstructionError, calibrate_lens, estimate_colmap
from .pairing import ViewOrder, capture_order_pairs

__all__ = ["Similarity", "umeyama", "apply_similarity", "rotation_angles_deg", "scene_scale", "score_cameras",
           "intrinsics_error", "projection_error", "turntable_self_check", "sequence_rotation_bias", "BoardNotFound", "CharucoConfig", "CharucoResult",
           "detect_board", "estimate_charuco", "make_board", "CAMERA_MODELS", "ColmapConfig", "ColmapResult", "calibrate_lens",
           "ReconstructionError", "estimate_colmap", "ViewOrder", "capture_order_pairs"]
