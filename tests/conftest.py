"""Shared test set-up: headless OpenGL for pyrender, and a tiny scene spec for pipeline tests."""
import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
