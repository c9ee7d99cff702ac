"""Shared test set-up: headless OpenGL for pyrender, and a tiny scene spec for pipeline tests."""
import atexit
import os
import shutil
import tempfile

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# the scene cache (rig/scene_cache.py) of this test run, its own and empty at the start, inherited
# by the CLI processes tests start: no test reads a user's entries or leaves any behind
_SCENE_CACHE = tempfile.mkdtemp(prefix="lumigraph-test-cache-")
os.environ["LUMIGRAPH_CACHE_DIR"] = _SCENE_CACHE
os.environ.pop("LUMIGRAPH_SCENE_CACHE", None)
atexit.register(shutil.rmtree, _SCENE_CACHE, True)
