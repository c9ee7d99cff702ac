"""Half-precision slab samples (render/lightfield/): float16 radiance and depth, stored, memory
mapped and rendered by both paths (the compiled kernels read float16 bits through a table, the
numpy path converts) as the float32 values they round-trip to."""
import numpy as np
import pytest

from render.camera import Camera, Intrinsics
from render.lightfield import MODES, LightSlab, load_slabs, render_pinhole, render_rays, save_slabs
from render.lightfield.kernels import HALF_TO_FLOAT
from render.poses import look_at
from tests.render.test_slab import analytic_slab, make_geometry, texture_wavy


def half(slab: LightSlab) -> LightSlab:
    return LightSlab(slab.geometry, slab.radiance.astype(np.float16), slab.depth.astype(np.float16), slab.focal_depth)


def test_half_to_float_table_is_numpys_conversion():
    bits = np.arange(2**16, dtype=np.uint32).astype(np.uint16)
    finite = np.isfinite(bits.view(np.float16))
    np.testing.assert_array_equal(HALF_TO_FLOAT[finite], bits.view(np.float16)[finite].astype(np.float32))
    assert HALF_TO_FLOAT[0x3C00] == 1.0 and HALF_TO_FLOAT[0x0001] == np.float32(2.0**-24)  # one; smallest subnormal


def test_half_slab_renders_as_its_float32_round_trip(tmp_path):
    """A float16 slab (depth varying, so the depth lookup's decoding matters) renders exactly like
    the float32 slab holding the same values, compiled and numpy paths, every mode; stored and
    memory-mapped as float16."""
    g = make_geometry((6, 6, 40, 40))
    slab = analytic_slab(g, 0.7, texture_wavy)
    slab.depth = np.linspace(0.6, 0.8, slab.depth.size, dtype=np.float32).reshape(slab.depth.shape)
    h = half(slab)
    wide = LightSlab(g, h.radiance.astype(np.float32), h.depth.astype(np.float32))
    save_slabs(tmp_path, [h])
    back = load_slabs(tmp_path)[0]
    assert isinstance(back.radiance, np.memmap) and back.radiance.dtype == np.float16 and back.depth.dtype == np.float16
    cam = Camera(Intrinsics(48, 36, 40.0, 40.0, 24.0, 18.0), look_at([0.05, -0.05, -0.3], [0.0, 0.0, 1.0], [0, -1, 0]), "c")
    o, d = cam.pixel_rays()
    for mode in MODES:
        want = render_pinhole([wide], cam, mode)
        np.testing.assert_allclose(render_pinhole([back], cam, mode), want, rtol=0, atol=1e-6)
        np.testing.assert_allclose(render_rays([back], o, d, mode).reshape(want.shape), want, rtol=0, atol=1e-5)


def test_slab_refuses_other_sample_dtypes():
    g = make_geometry((2, 2, 4, 4))
    with pytest.raises(ValueError, match="float32 or float16"):
        LightSlab(g, np.zeros(g.array_shape, np.float64))
    with pytest.raises(ValueError, match="float32 or float16"):
        LightSlab(g, np.zeros(g.array_shape, np.float32), np.zeros(g.array_shape[:4], np.uint16))
