"""The rig's physically based rasterizer: pyrender offscreen (EGL) with a radiometric shader.

:class:`RasterRenderer` renders a :class:`render.scene.Scene` into linear radiance in scene units
(render/scene.py): Lambertian surfaces under spot, directional and point lights, with hard
shadows from spot and directional lights through pyrender's shadow-map pass. It simulates the
``direct`` and ``shadows`` effects only; choosing it for a scene is the caller's business
(:func:`render.effects.raster_limitations`).

Conventions and how they are met:

* Cameras are :class:`render.camera.Camera` (camera-to-world, OpenCV axes). The view is drawn with
  a pyrender ``IntrinsicsCamera`` from (fx, fy, cx, cy), whose projection puts pixel centres at
  +0.5 exactly as DESIGN.md does, and the pose converted by
  :func:`render.poses.opencv_to_opengl`. Lens distortion is ignored: the ideal pinhole image of
  the intrinsics is rendered (a sensor module remaps it).
* Shading (rig/shaders/radiance.frag): L = Le (front side) + albedo * E / pi with E summed over
  lights in render.scene's units and its exact spot falloff. The normal is the triangle's
  geometric normal (as a ray tracer's Ng), turned toward the viewer: surfaces are two-sided,
  and lit only by lights on the viewer's side. Emitters emit from their front side unless
  two-sided. Emitters do not illuminate other surfaces here (no area lights in the rasterizer).
* Textures: albedo = material.albedo * srgb_to_linear(texel), decoded with
  :func:`render.texture.decode_texture` and uploaded as RGB32F, sampled bilinearly with repeat
  wrapping and no mipmaps, v up: texel for texel what :func:`render.texture.sample_bilinear` does.
* Output: 4x MSAA into float32 render buffers (no clamping, no quantization). Colour attachment 0
  holds radiance; attachment 1 holds (z-depth, coverage code) per fragment. The resolve box-
  averages each pixel's samples, as a path tracer with pixel jitter averages over the pixel.
  The coverage code is 1 on ``is_subject`` objects and 1/16 elsewhere, so the averaged code
  tells how many of the pixel's samples hit a subject and how many hit anything; the mask is
  "a subject covers at least half the samples", and depth is the averaged depth of the covered
  samples divided by their coverage (each evaluated at the pixel centre), 0 where fewer than
  half the samples hit geometry. One pass, two float read-backs, no segmentation pass.
* Shadow maps depend only on the lights and the geometry, so they are rendered once, when the
  scene is uploaded, and reused for every view.

``PYOPENGL_PLATFORM`` is set to ``egl`` on import unless already set; it must be set before
PyOpenGL is first imported anywhere in the process.
"""
from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

if not hasattr(np, "infty"):  # pyrender 0.1.45 still uses np.infty, removed in numpy 2
    np.infty = np.inf

import pyrender  # noqa: E402
from OpenGL import GL as gl  # noqa: E402
from OpenGL.raw.GL.VERSION.GL_1_0 import glReadPixels as _gl_read_pixels_raw  # noqa: E402
from pyrender.constants import SHADOW_TEX_SZ, ProgramFlags, RenderFlags  # noqa: E402
from pyrender.renderer import Renderer as _PyrenderRenderer  # noqa: E402
from pyrender.shader_program import ShaderProgramCache  # noqa: E402

from render.camera import Camera  # noqa: E402
from render.effects import scene_effects  # noqa: E402
from render.poses import invert_rigid, opencv_to_opengl  # noqa: E402
from render.scene import DirectionalLight, Emissive, Lambertian, PointLight, Scene, SpotLight  # noqa: E402
from render.texture import decode_texture  # noqa: E402

__all__ = ["RasterFrame", "RasterRenderer", "MAX_SHADOWED_SPOT_ANGLE"]

_SHADER_DIR = Path(__file__).resolve().parent / "shaders"

#: widest spot cone (outer half-angle, radians) that a single shadow-map frustum can cover
MAX_SHADOWED_SPOT_ANGLE = np.radians(84.0)
_SPOT_FRUSTUM_MARGIN = np.radians(2.0)  # shadow frustum = cone + this on each side

# Shadow-map biases in texels (see shadow_visibility in radiance.frag); chosen by
# tests/rig/test_raster.py: no acne on lit planes up to grazing light, shadow edges within a
# pixel of the exact ones.
_NORMAL_OFFSET_TEXELS = 1.0
_DEPTH_BIAS_TEXELS = 1.5

# Coverage codes written per fragment; K must exceed the sample count so that the resolved
# average n_subject / s + n_other / (s K) decodes uniquely.
_CODE_K = 16.0
_SUBJECT_CODE = 1.0
_OTHER_CODE = 1.0 / _CODE_K

# y flip of clip space: GL rows start at the bottom; flipping the projection makes glReadPixels
# return the top image row first, so no flip (copy) on read-back. Culling is never used, and
# facing is computed from the geometric normal, so the reversed winding is harmless.
_FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])


@dataclass
class RasterFrame:
    """One rendered view.

    rgb: (H, W, 3) float32 linear radiance in scene units (render/scene.py).
    depth: (H, W) float32 z-depth along the camera's optical axis (not ray length), scene
    units, at the pixel centre; 0 where nothing was hit (less than half the pixel's samples hit
    geometry). Where two surfaces share a pixel it is their coverage-weighted mean.
    mask: (H, W) bool, pixels at least half covered by objects with ``is_subject=True``.
    """

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray


# --------------------------------------------------------------------------------------------
# pyrender extensions: textures, program cache, renderer
# --------------------------------------------------------------------------------------------

class _LinearAlbedoTexture(pyrender.Texture):
    """Linear albedo as an RGB32F texture: bilinear, repeat, no mipmaps (render.texture's lookup).

    pyrender's own upload would quantize float data to uint8 and build mipmaps.
    """

    def __init__(self, albedo_linear: np.ndarray):
        h, w = albedo_linear.shape[:2]
        super().__init__(source=None, source_channels="RGB", width=w, height=h, data_format=gl.GL_FLOAT)
        # GL's first row is v = 0, the bottom of the image (render.texture's convention)
        self._rows_bottom_up = np.ascontiguousarray(albedo_linear[::-1], dtype=np.float32)

    def _add_to_context(self):
        if self._texid is not None:
            raise ValueError("texture already loaded into the OpenGL context")
        self._texid = gl.glGenTextures(1)
        gl.glBindTexture(gl.GL_TEXTURE_2D, self._texid)
        gl.glPixelStorei(gl.GL_UNPACK_ALIGNMENT, 1)
        gl.glTexImage2D(gl.GL_TEXTURE_2D, 0, gl.GL_RGB32F, self.width, self.height, 0,
                        gl.GL_RGB, gl.GL_FLOAT, self._rows_bottom_up)
        gl.glPixelStorei(gl.GL_UNPACK_ALIGNMENT, 4)
        for name, value in ((gl.GL_TEXTURE_MIN_FILTER, gl.GL_LINEAR), (gl.GL_TEXTURE_MAG_FILTER, gl.GL_LINEAR),
                            (gl.GL_TEXTURE_WRAP_S, gl.GL_REPEAT), (gl.GL_TEXTURE_WRAP_T, gl.GL_REPEAT),
                            (gl.GL_TEXTURE_BASE_LEVEL, 0), (gl.GL_TEXTURE_MAX_LEVEL, 0)):
            gl.glTexParameteri(gl.GL_TEXTURE_2D, name, value)
        gl.glBindTexture(gl.GL_TEXTURE_2D, 0)


class _ShadowMapTexture(pyrender.Texture):
    """A light's shadow map: DEPTH32F with hardware depth comparison and bilinear PCF.

    Replaces pyrender's unsized, unfiltered depth texture; pyrender's shadow pass renders into it.
    """

    def __init__(self, size: int = SHADOW_TEX_SZ):
        super().__init__(source=None, source_channels="D", width=size, height=size, data_format=gl.GL_FLOAT)

    def _add_to_context(self):
        if self._texid is not None:
            raise ValueError("texture already loaded into the OpenGL context")
        self._texid = gl.glGenTextures(1)
        gl.glBindTexture(gl.GL_TEXTURE_2D, self._texid)
        gl.glTexImage2D(gl.GL_TEXTURE_2D, 0, gl.GL_DEPTH_COMPONENT32F, self.width, self.height, 0,
                        gl.GL_DEPTH_COMPONENT, gl.GL_FLOAT, None)
        for name, value in ((gl.GL_TEXTURE_MIN_FILTER, gl.GL_LINEAR), (gl.GL_TEXTURE_MAG_FILTER, gl.GL_LINEAR),
                            (gl.GL_TEXTURE_WRAP_S, gl.GL_CLAMP_TO_EDGE), (gl.GL_TEXTURE_WRAP_T, gl.GL_CLAMP_TO_EDGE),
                            (gl.GL_TEXTURE_COMPARE_MODE, gl.GL_COMPARE_REF_TO_TEXTURE),
                            (gl.GL_TEXTURE_COMPARE_FUNC, gl.GL_LEQUAL),
                            (gl.GL_TEXTURE_BASE_LEVEL, 0), (gl.GL_TEXTURE_MAX_LEVEL, 0)):
            gl.glTexParameteri(gl.GL_TEXTURE_2D, name, value)
        gl.glBindTexture(gl.GL_TEXTURE_2D, 0)


class _RadianceProgramCache(ShaderProgramCache):
    """pyrender's program cache, with its lit mesh program replaced by rig/shaders/radiance.*.

    pyrender still chooses the vertex-layout defines (NORMAL_LOC, TEXCOORD_0_LOC, ...); the
    scene's light counts and shadow settings are added as LG_* defines. Every other program
    (the shadow-map depth pass) stays pyrender's.
    """

    def __init__(self, scene_defines: dict):
        super().__init__()
        self._scene_defines = dict(scene_defines)

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        if vertex_shader == "mesh.vert":
            return super().get_program(str(_SHADER_DIR / "radiance.vert"), str(_SHADER_DIR / "radiance.frag"),
                                       None, {**(defines or {}), **self._scene_defines})
        return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)


class _RadianceGLRenderer(_PyrenderRenderer):
    """pyrender's Renderer with our light cameras, two-sided shadow casting and float targets."""

    def __init__(self, width: int, height: int, scene_defines: dict, samples: int):
        super().__init__(width, height)
        self._program_cache = _RadianceProgramCache(scene_defines)
        self.light_cams: dict = {}  # pyrender light node -> (V, P) world->light view, projection
        self._samples_requested = samples
        self.samples = 0
        self._fbos: list[int] = []
        self._rbos: list[int] = []

    # -- pyrender hooks ------------------------------------------------------------------------
    def _get_light_cam_matrices(self, scene, light_node, flags):
        return self.light_cams[light_node]

    def _bind_and_draw_primitive(self, primitive, pose, program, flags):
        # Used by pyrender's shadow-map pass. Unlike pyrender, never cull: an open mesh (a
        # quad, a plane) occludes light whichever way its faces point.
        program.set_uniform("M", pose)
        primitive._bind()
        gl.glDisable(gl.GL_CULL_FACE)
        gl.glPolygonMode(gl.GL_FRONT_AND_BACK, gl.GL_FILL)
        gl.glDrawArrays(gl.GL_TRIANGLES, 0, len(primitive.positions))
        primitive._unbind()

    # -- float multisample framebuffers ----------------------------------------------------------
    def create_framebuffers(self) -> None:
        """MSAA target (RGBA32F radiance, RG32F geometry, depth) and two single-sample resolves."""
        w, h = self.viewport_width, self.viewport_height
        rbos = list(np.atleast_1d(gl.glGenRenderbuffers(5)))
        fbos = list(np.atleast_1d(gl.glGenFramebuffers(3)))
        self._rbos, self._fbos = rbos, fbos
        specs = [(gl.GL_RGBA32F, True), (gl.GL_RG32F, True), (gl.GL_DEPTH_COMPONENT24, True),
                 (gl.GL_RGBA32F, False), (gl.GL_RG32F, False)]
        for rb, (fmt, ms) in zip(rbos, specs):
            gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, rb)
            if ms:
                gl.glRenderbufferStorageMultisample(gl.GL_RENDERBUFFER, self._samples_requested, fmt, w, h)
            else:
                gl.glRenderbufferStorage(gl.GL_RENDERBUFFER, fmt, w, h)
        gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, rbos[0])
        self.samples = max(1, int(gl.glGetRenderbufferParameteriv(gl.GL_RENDERBUFFER, gl.GL_RENDERBUFFER_SAMPLES)))
        if self.samples >= _CODE_K:
            raise RuntimeError(f"{self.samples} samples per pixel cannot be decoded from the coverage code")
        attach = [(fbos[0], gl.GL_COLOR_ATTACHMENT0, rbos[0]), (fbos[0], gl.GL_COLOR_ATTACHMENT1, rbos[1]),
                  (fbos[0], gl.GL_DEPTH_ATTACHMENT, rbos[2]), (fbos[1], gl.GL_COLOR_ATTACHMENT0, rbos[3]),
                  (fbos[2], gl.GL_COLOR_ATTACHMENT0, rbos[4])]
        for fb, point, rb in attach:
            gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fb)
            gl.glFramebufferRenderbuffer(gl.GL_FRAMEBUFFER, point, gl.GL_RENDERBUFFER, rb)
        for fb in fbos:
            gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fb)
            status = gl.glCheckFramebufferStatus(gl.GL_FRAMEBUFFER)
            if status != gl.GL_FRAMEBUFFER_COMPLETE:
                raise RuntimeError(f"float framebuffer incomplete (status {status:#x})")
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, fbos[0])
        gl.glDrawBuffers(2, [gl.GL_COLOR_ATTACHMENT0, gl.GL_COLOR_ATTACHMENT1])
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, 0)

    @property
    def msaa_fbo(self) -> int:
        return self._fbos[0]

    def resolve_and_read(self) -> tuple[np.ndarray, np.ndarray]:
        """Box-average the samples and read ((H, W, 3) radiance, (H, W, 2) geometry) float32."""
        w, h = self.viewport_width, self.viewport_height
        ms, res_rgb, res_geo = self._fbos
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, ms)
        for attachment, target in ((gl.GL_COLOR_ATTACHMENT0, res_rgb), (gl.GL_COLOR_ATTACHMENT1, res_geo)):
            gl.glReadBuffer(attachment)
            gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, target)
            gl.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, gl.GL_COLOR_BUFFER_BIT, gl.GL_NEAREST)
        rgb = np.empty((h, w, 3), np.float32)
        geo = np.empty((h, w, 2), np.float32)
        # the raw entry point reads straight into numpy memory (no PyOpenGL array handling;
        # PyOpenGL's wrapper does not even know GL_RG)
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, res_rgb)
        gl.glReadBuffer(gl.GL_COLOR_ATTACHMENT0)
        _gl_read_pixels_raw(0, 0, w, h, gl.GL_RGB, gl.GL_FLOAT, ctypes.c_void_p(rgb.ctypes.data))
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, res_geo)
        gl.glReadBuffer(gl.GL_COLOR_ATTACHMENT0)
        _gl_read_pixels_raw(0, 0, w, h, gl.GL_RG, gl.GL_FLOAT, ctypes.c_void_p(geo.ctypes.data))
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, 0)
        return rgb, geo

    def delete(self):
        if self._fbos:
            gl.glDeleteFramebuffers(len(self._fbos), self._fbos)
            gl.glDeleteRenderbuffers(len(self._rbos), self._rbos)
            self._fbos, self._rbos = [], []
        super().delete()


# --------------------------------------------------------------------------------------------
# Scene conversion helpers
# --------------------------------------------------------------------------------------------

def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _gl_pose_looking_along(position, direction) -> np.ndarray:
    """(4, 4) camera-to-world in OpenGL axes at ``position`` looking along unit ``direction``."""
    z = -_unit(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = _unit(np.cross(helper, z))
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, position
    return pose


def _box_corners(bounds: np.ndarray) -> np.ndarray:
    """(8, 3) corners of (2, 3) axis-aligned bounds."""
    idx = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    return bounds[idx, [0, 1, 2]]


def _primitive_for(obj) -> pyrender.Primitive | None:
    """Unindexed triangles in world coordinates with per-face geometric normals (and uv)."""
    mesh = obj.mesh
    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    tri = verts[faces]                                    # (F, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    keep = length > 1e-12 * max(float(np.abs(verts).max(initial=0.0)), 1.0) ** 2  # zero-area faces: no normal, no pixels
    if not keep.any():
        return None
    tri, normals, faces = tri[keep], normals[keep] / length[keep, None], faces[keep]
    texcoords = None
    material = pyrender.MetallicRoughnessMaterial(doubleSided=True)
    if isinstance(obj.material, Lambertian) and obj.material.texture is not None:
        uv = obj.uv
        if uv is None or uv.shape != (len(verts), 2) or not np.all(np.isfinite(uv)):
            raise ValueError(f"object '{obj.name}': a textured material needs finite (V, 2) mesh.visual.uv")
        texcoords = uv[faces].reshape(-1, 2).astype(np.float32)
        material.baseColorTexture = _LinearAlbedoTexture(decode_texture(obj.material.texture))
    return pyrender.Primitive(positions=tri.reshape(-1, 3).astype(np.float32),
                              normals=np.repeat(normals, 3, axis=0).astype(np.float32),
                              texcoord_0=texcoords, material=material)


class _Uniforms:
    """Uniform setter for one linked program, with cached locations (unused names are no-ops)."""

    def __init__(self, program):
        self.program = program
        self._loc: dict[str, int] = {}

    def loc(self, name: str) -> int:
        if name not in self._loc:
            self._loc[name] = gl.glGetUniformLocation(self.program._program_id, name)
        return self._loc[name]

    def vec3(self, name, v):
        if (i := self.loc(name)) != -1:
            gl.glUniform3f(i, *(float(x) for x in v))

    def scalar(self, name, v):
        if (i := self.loc(name)) != -1:
            gl.glUniform1f(i, float(v))

    def integer(self, name, v):
        if (i := self.loc(name)) != -1:
            gl.glUniform1i(i, int(v))

    def mat4(self, name, m):
        if (i := self.loc(name)) != -1:
            gl.glUniformMatrix4fv(i, 1, gl.GL_TRUE, np.ascontiguousarray(m, dtype=np.float32))


# --------------------------------------------------------------------------------------------
# The renderer
# --------------------------------------------------------------------------------------------

def _release_context(platform) -> None:
    """Make the context current in no thread. pyrender's EGL ``make_uncurrent`` does nothing, which
    left the context bound to the last thread that drew with it: another thread (a Dask worker's
    next task thread, or ``close()`` from elsewhere) then failed with EGL_BAD_ACCESS."""
    display = getattr(platform, "_egl_display", None)
    if display is not None:
        from OpenGL import EGL

        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
    else:
        platform.make_uncurrent()


class RasterRenderer:
    """Renders a render.scene.Scene with pyrender; one GL context, scene uploaded once.

    scene: Lambertian and Emissive objects only, no media. Shadows are drawn when the scene's
    effects (:func:`render.effects.scene_effects`) include ``shadows`` (override with
    ``shadows``); point lights are then refused, as the rasterizer cannot shadow them.
    width, height: image size; every rendered camera must have it. samples: MSAA samples
    per pixel (the driver may round up; llvmpipe gives 4). MSAA shades once per pixel, so it
    smooths geometry edges only; texture_taps: the albedo texture is box-filtered over the
    pixel's footprint with texture_taps x texture_taps bilinear taps (1 = a point sample at the
    pixel centre), as a sensor pixel (and the path tracer's box filter) integrates it.

    Usage::

        with RasterRenderer(scene, 256, 256) as r:
            frame = r.render(camera)    # RasterFrame(rgb, depth, mask)
    """

    def __init__(self, scene: Scene, width: int, height: int, *, samples: int = 4, shadows: bool | None = None,
                 texture_taps: int = 4):
        if not 1 <= int(texture_taps) <= 16:
            raise ValueError(f"texture_taps must lie in [1, 16], got {texture_taps}")
        if width <= 0 or height <= 0:
            raise ValueError(f"image size must be positive, got {width}x{height}")
        for o in scene.objects:
            if not isinstance(o.material, (Lambertian, Emissive)):
                raise ValueError(f"object '{o.name}': {type(o.material).__name__} material cannot be rasterized")
        if scene.media:
            raise ValueError("participating media cannot be rasterized")
        self.shadows = ("shadows" in scene_effects(scene)) if shadows is None else bool(shadows)
        spots = [l for l in scene.lights if isinstance(l, SpotLight)]
        dirs = [l for l in scene.lights if isinstance(l, DirectionalLight)]
        points = [l for l in scene.lights if isinstance(l, PointLight)]
        if self.shadows and points:
            raise ValueError("point-light shadows are not simulated by the rasterizer (use spot lights)")
        if self.shadows and any(s.outer_angle > MAX_SHADOWED_SPOT_ANGLE for s in spots):
            raise ValueError(f"shadowed spot lights need outer_angle <= {np.degrees(MAX_SHADOWED_SPOT_ANGLE):.0f} deg")

        self.scene = scene
        self.width, self.height = int(width), int(height)
        self._bounds = scene.bounds()
        self._diag = float(np.linalg.norm(self._bounds[1] - self._bounds[0])) or 1.0
        self._background = np.asarray(scene.background, dtype=np.float32)
        defines = {"LG_N_SPOT": len(spots), "LG_N_DIR": len(dirs), "LG_N_POINT": len(points),
                   "LG_SHADOWS": int(self.shadows), "LG_NORMAL_OFFSET": f"{_NORMAL_OFFSET_TEXELS:.6f}",
                   "LG_DEPTH_BIAS": f"{_DEPTH_BIAS_TEXELS:.6f}", "LG_TEXTURE_TAPS": int(texture_taps)}

        self._offscreen = pyrender.OffscreenRenderer(self.width, self.height)
        self._platform = self._offscreen._platform
        self._gl = _RadianceGLRenderer(self.width, self.height, defines, samples)
        self._offscreen._renderer = self._gl  # ours replaces the stock Renderer (nothing uploaded yet)
        try:
            self._platform.make_current()
            self._upload(spots, dirs, points)
        except BaseException:
            self.close()
            raise
        finally:
            _release_context(self._platform)

    # -- setup -----------------------------------------------------------------------------------
    def _upload(self, spots, dirs, points) -> None:
        glr = self._gl
        self._pscene = pyrender.Scene(bg_color=np.zeros(4), ambient_light=np.zeros(3))
        # pyrender's shadow pass reads the main camera's pose; the radiance pass ignores it
        self._pscene.add(pyrender.PerspectiveCamera(yfov=1.0), pose=np.eye(4))
        self._draws = []  # (primitive, albedo, emission, two_sided, coverage code)
        for o in self.scene.objects:
            prim = _primitive_for(o)
            if prim is None:
                continue
            self._pscene.add(pyrender.Mesh([prim]), pose=np.eye(4))
            m = o.material
            albedo = m.albedo if isinstance(m, Lambertian) else np.zeros(3)
            emission = m.radiance if isinstance(m, Emissive) else np.zeros(3)
            two_sided = bool(getattr(m, "two_sided", False))
            self._draws.append((prim, albedo, emission, two_sided, _SUBJECT_CODE if o.is_subject else _OTHER_CODE))

        shadow_nodes = []
        for kind, lights in (("spot", spots), ("dir", dirs)):
            for light in lights:
                if not self.shadows:
                    shadow_nodes.append((kind, light, None))
                    continue
                pl = pyrender.SpotLight(innerConeAngle=light.inner_angle, outerConeAngle=light.outer_angle) \
                    if kind == "spot" else pyrender.DirectionalLight()
                pl.shadow_texture = _ShadowMapTexture()
                pos = light.position if kind == "spot" else np.zeros(3)
                node = self._pscene.add(pl, pose=_gl_pose_looking_along(pos, light.direction))
                glr.light_cams[node] = self._light_camera(kind, light)
                shadow_nodes.append((kind, light, node))

        glr._update_context(self._pscene, RenderFlags.NONE)  # uploads meshes, textures, shadow maps
        glr.create_framebuffers()

        # one program per vertex layout (textured or not); lights and sampler units set once
        self._programs: dict[int, _Uniforms] = {}
        self._draw_lists: dict[int, list] = {}
        n_shadow_units = sum(1 for _, _, node in shadow_nodes if node is not None)
        self._albedo_unit = n_shadow_units
        for d in self._draws:
            program = glr._get_primitive_program(d[0], RenderFlags.NONE, ProgramFlags.USE_MATERIAL)
            key = id(program)
            if key not in self._programs:
                self._programs[key] = u = _Uniforms(program)
                program._bind()
                self._set_light_uniforms(u, shadow_nodes, points)
                u.integer("albedo_texture", self._albedo_unit)
                program._unbind()
                self._draw_lists[key] = []
            self._draw_lists[key].append(d)
        self._shadow_textures = [node.light.shadow_texture for _, _, node in shadow_nodes if node is not None]
        self._draw_shadow_maps()

    def _light_camera(self, kind: str, light) -> tuple[np.ndarray, np.ndarray]:
        """World->light view (OpenGL axes) and projection whose frustum covers the scene bounds."""
        corners = _box_corners(self._bounds)
        eps = 1e-4 * self._diag
        if kind == "spot":
            pose = _gl_pose_looking_along(light.position, light.direction)
            axial = (corners - light.position) @ light.direction
            znear = max(0.99 * axial.min(), 1e-3 * self._diag)
            zfar = max(1.01 * axial.max() + eps, 2.0 * znear)
            cam = pyrender.PerspectiveCamera(yfov=2.0 * light.outer_angle + 2.0 * _SPOT_FRUSTUM_MARGIN,
                                             znear=znear, zfar=zfar, aspectRatio=1.0)
        else:
            centre = self._bounds.mean(axis=0)
            radius = 0.5 * self._diag
            pose = _gl_pose_looking_along(centre - light.direction * (1.1 * radius + eps), light.direction)
            local = (corners - pose[:3, 3]) @ pose[:3, :3]          # corners in the light's frame
            mag = 1.01 * np.abs(local[:, :2]).max() + eps
            depth = -local[:, 2]
            cam = pyrender.OrthographicCamera(xmag=mag, ymag=mag, znear=max(depth.min() - eps, 0.5 * eps),
                                              zfar=depth.max() + eps)
        return invert_rigid(pose), cam.get_projection_matrix()

    def _set_light_uniforms(self, u: _Uniforms, shadow_nodes, points) -> None:
        unit = 0
        counters = {"spot": 0, "dir": 0}
        for kind, light, node in shadow_nodes:
            i = counters[kind]
            counters[kind] += 1
            if kind == "spot":
                b = f"spot_lights[{i}]."
                u.vec3(b + "position", light.position)
                u.vec3(b + "direction", light.direction)
                u.vec3(b + "intensity", light.intensity)
                u.scalar(b + "cos_inner", np.cos(light.inner_angle))
                u.scalar(b + "cos_outer", np.cos(light.outer_angle))
                sampler = f"spot_shadow_maps[{i}]"
            else:
                b = f"directional_lights[{i}]."
                u.vec3(b + "direction", light.direction)
                u.vec3(b + "irradiance", light.irradiance)
                sampler = f"directional_shadow_maps[{i}]"
            if node is not None:
                V, P = self._gl.light_cams[node]
                u.mat4(b + "light_matrix", P @ V)
                if kind == "spot":
                    u.scalar(b + "texel_per_depth", 2.0 / (P[1, 1] * SHADOW_TEX_SZ))  # 2 tan(fov/2) / N
                else:
                    u.scalar(b + "texel", 2.0 / (P[1, 1] * SHADOW_TEX_SZ))        # 2 ymag / N
                u.integer(sampler, unit)
                unit += 1
        for i, light in enumerate(points):
            u.vec3(f"point_lights[{i}].position", light.position)
            u.vec3(f"point_lights[{i}].intensity", light.intensity)

    def render_shadow_maps(self) -> None:
        """Redraw every shadow map (they are drawn once at upload; the scene is static)."""
        self._platform.make_current()
        try:
            self._draw_shadow_maps()
        finally:
            _release_context(self._platform)

    def _draw_shadow_maps(self) -> None:
        """pyrender's shadow-map pass for each shadowed light, with our light cameras."""
        for node in self._gl.light_cams:
            self._gl._shadow_mapping_pass(self._pscene, node, RenderFlags.NONE)
        self._gl._reset_active_textures()

    # -- rendering -------------------------------------------------------------------------------
    def _clip_planes(self, camera: Camera) -> tuple[float, float]:
        """Near and far planes bracketing the scene bounds along the optical axis."""
        z = (_box_corners(self._bounds) - camera.center) @ camera.cam_to_world[:3, 2]
        znear = max(0.99 * z.min(), 1e-3 * self._diag)
        zfar = max(1.01 * z.max() + 1e-4 * self._diag, 2.0 * znear)
        return znear, zfar

    def render(self, camera: Camera) -> RasterFrame:
        """Render ``camera``'s ideal pinhole view (its distortion coefficients are ignored)."""
        k = camera.intrinsics
        if (k.width, k.height) != (self.width, self.height):
            raise ValueError(f"camera '{camera.name}' is {k.width}x{k.height}, renderer is {self.width}x{self.height}")
        znear, zfar = self._clip_planes(camera)
        proj = pyrender.IntrinsicsCamera(k.fx, k.fy, k.cx, k.cy, znear=znear, zfar=zfar)
        P = _FLIP_Y @ proj.get_projection_matrix(self.width, self.height)
        V = invert_rigid(opencv_to_opengl(camera.cam_to_world))
        self._platform.make_current()
        try:
            self._draw(V, P, camera.center)
            rgb, geo = self._gl.resolve_and_read()
        finally:
            _release_context(self._platform)
        return self._decode(rgb, geo)

    def _draw(self, V: np.ndarray, P: np.ndarray, cam_pos: np.ndarray) -> None:
        glr = self._gl
        gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, glr.msaa_fbo)
        gl.glViewport(0, 0, self.width, self.height)
        gl.glEnable(gl.GL_DEPTH_TEST)
        gl.glDepthMask(gl.GL_TRUE)
        gl.glDepthFunc(gl.GL_LESS)
        gl.glDisable(gl.GL_CULL_FACE)
        gl.glDisable(gl.GL_BLEND)
        gl.glEnable(gl.GL_MULTISAMPLE)
        gl.glPolygonMode(gl.GL_FRONT_AND_BACK, gl.GL_FILL)
        gl.glClearBufferfv(gl.GL_COLOR, 0, np.append(self._background, 0.0).astype(np.float32))
        gl.glClearBufferfv(gl.GL_COLOR, 1, np.zeros(4, np.float32))
        gl.glClearBufferfv(gl.GL_DEPTH, 0, np.ones(1, np.float32))
        for unit, tex in enumerate(self._shadow_textures):
            gl.glActiveTexture(gl.GL_TEXTURE0 + unit)
            tex._bind()
        for key, draws in self._draw_lists.items():
            u = self._programs[key]
            u.program._bind()
            u.mat4("V", V)
            u.mat4("P", P)
            u.vec3("cam_pos", cam_pos)
            for prim, albedo, emission, two_sided, code in draws:
                u.vec3("albedo", albedo)
                u.vec3("emission", emission)
                u.integer("emit_two_sided", two_sided)
                u.scalar("coverage_code", code)
                tex = prim.material.baseColorTexture
                if tex is not None:
                    gl.glActiveTexture(gl.GL_TEXTURE0 + self._albedo_unit)
                    tex._bind()
                prim._bind()
                gl.glDrawArrays(gl.GL_TRIANGLES, 0, len(prim.positions))
                prim._unbind()
            u.program._unbind()

    def _decode(self, rgb: np.ndarray, geo: np.ndarray) -> RasterFrame:
        """Resolved buffers -> RasterFrame (see the module docstring for the coverage code)."""
        s = float(self._gl.samples)
        code = geo[..., 1] * s                          # n_subject + n_other / K
        n_subject = np.floor(code + 0.25 / _CODE_K)
        n_hit = n_subject + np.rint((code - n_subject) * _CODE_K)
        hit = 2.0 * n_hit >= s
        depth = np.zeros(geo.shape[:2], np.float32)
        # the resolve averaged z over all samples (background z = 0): renormalize by coverage
        np.divide(geo[..., 0] * s, n_hit, out=depth, where=hit)
        if not np.isfinite(rgb).all():  # the shader guards its divisions; this catches regressions
            raise RuntimeError("rasterizer produced non-finite radiance")
        return RasterFrame(rgb=rgb, depth=depth, mask=2.0 * n_subject >= s)

    # -- lifetime --------------------------------------------------------------------------------
    def close(self) -> None:
        """Free the GL context and everything uploaded to it (idempotent).

        Other renderers in the process keep working: pyrender's EGL platform would call
        eglTerminate on the display all its contexts share, so only our context is destroyed.
        """
        offscreen = getattr(self, "_offscreen", None)
        if offscreen is None:
            return
        self._offscreen = None
        platform = offscreen._platform
        platform.make_current()
        self._gl.delete()
        if getattr(platform, "_egl_context", None) is not None:
            from OpenGL import EGL

            EGL.eglMakeCurrent(platform._egl_display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
            EGL.eglDestroyContext(platform._egl_display, platform._egl_context)
            platform._egl_context = platform._egl_display = None
        else:
            platform.delete_context()
        offscreen._renderer = offscreen._platform = None  # its __del__ then has nothing to free

    def __enter__(self) -> "RasterRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
