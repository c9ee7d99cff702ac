#version 410 core
// Vertex stage of rig.raster's radiance pass.
// Vertices arrive in world coordinates (meshes are uploaded with an identity model matrix), with
// the face's geometric normal repeated on its three vertices (meshes are uploaded unindexed).
// Attribute locations are pyrender's (Primitive._add_to_context): defines filled in by pyrender.

layout(location = 0) in vec3 position;
layout(location = NORMAL_LOC) in vec3 normal;
#ifdef TEXCOORD_0_LOC
layout(location = TEXCOORD_0_LOC) in vec2 texcoord_0;
#endif

uniform mat4 V;  // world -> camera, OpenGL axes
uniform mat4 P;  // camera -> clip (pyrender IntrinsicsCamera, rows flipped so readback is top-down)

// Interpolation at the pixel centre (not `centroid`): a pixel split between two triangles of one
// surface is then shaded at its centre by both, exactly as a fully covered pixel; a pixel on a
// silhouette is shaded at its centre extrapolated on the triangle's plane.
out vec3 frag_position;   // world position
flat out vec3 frag_normal;         // geometric face normal (world), as a path tracer's Ng
out float frag_zdepth;    // z-depth along the optical axis (camera frame), scene units
#ifdef TEXCOORD_0_LOC
out vec2 uv_0;
#endif

void main()
{
    vec4 pc = V * vec4(position, 1.0);
    gl_Position = P * pc;
    frag_position = position;
    frag_normal = normal;
    frag_zdepth = -pc.z;  // OpenGL cameras look down -z
#ifdef TEXCOORD_0_LOC
    uv_0 = texcoord_0;
#endif
}
