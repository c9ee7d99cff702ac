"""GLSL sources of the rig's rasterizer (:mod:`rig.raster`); a package so they ship as package data."""
