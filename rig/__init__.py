"""rig: the synthetic capture rig. A scene spec (``spec``) becomes a render scene with cameras
(``build``, ``layouts``, ``textures``, ``volumes``); ``capture`` renders each view with the
rasterizer (``raster``, pyrender/EGL) or a path tracer, as the scene's effects call for, and
``sensor`` applies the camera's noise, vignetting and distortion. Imports render, never recon."""
