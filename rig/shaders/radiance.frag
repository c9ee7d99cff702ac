#version 410 core
// GLSL 4.10 (pyrender asks EGL for a 4.1 context): sampler arrays indexed in loops need >= 4.00.
// Fragment stage of rig.raster's radiance pass: physical radiance of Lambertian surfaces under
// delta lights, in the units of render/scene.py (radiance W/(m^2 sr), spot/point intensity W/sr,
// directional irradiance W/m^2):
//   L = emission (front side, or both if two-sided) + albedo * E / pi,
//   E = sum_spot  I * spot_falloff(cos_axis) * cos(theta) / r^2 * visibility
//     + sum_dir   E_perp * cos(theta) * visibility
//     + sum_point I * cos(theta) / r^2                       (never shadowed)
// Surfaces are two-sided: the geometric normal is turned toward the viewer, and only lights on
// the viewer's side of the surface light it. Emitters emit from their front side only unless
// two-sided (render.scene.Emissive).
//
// Defines (filled in by rig.raster's program cache): LG_N_SPOT, LG_N_DIR, LG_N_POINT light
// counts, LG_SHADOWS (0 or 1), LG_NORMAL_OFFSET and LG_DEPTH_BIAS in shadow-map texels.
// NORMAL_LOC, TEXCOORD_0_LOC, HAS_BASE_COLOR_TEX come from pyrender.

const float PI = 3.141592653589793;

in vec3 frag_position;
flat in vec3 frag_normal;
in float frag_zdepth;
#ifdef TEXCOORD_0_LOC
in vec2 uv_0;
#endif

uniform vec3 cam_pos;         // camera centre, world
uniform vec3 albedo;          // Lambertian albedo (a tint when textured); 0 for emitters
uniform vec3 emission;        // emitted radiance; 0 for reflectors
uniform int emit_two_sided;   // 1: emits from both sides
uniform float coverage_code;  // 1 on subject objects, 1/16 elsewhere: decoded after the MSAA resolve
#ifdef HAS_BASE_COLOR_TEX
uniform sampler2D albedo_texture;  // linear albedo (RGB32F), bilinear, repeat, no mipmaps
#endif

struct SpotLight {
    vec3 position;
    vec3 direction;        // unit spot axis
    vec3 intensity;        // W/sr
    float cos_inner;
    float cos_outer;
    mat4 light_matrix;     // world -> shadow-map clip space
    float texel_per_depth; // shadow-map texel footprint per unit of distance along the axis
};
struct DirectionalLight {
    vec3 direction;        // unit direction light travels along
    vec3 irradiance;       // W/m^2 on a surface facing the light
    mat4 light_matrix;
    float texel;           // shadow-map texel footprint, world units
};
struct PointLight {
    vec3 position;
    vec3 intensity;        // W/sr
};

#if LG_N_SPOT > 0
uniform SpotLight spot_lights[LG_N_SPOT];
#if LG_SHADOWS
uniform sampler2DShadow spot_shadow_maps[LG_N_SPOT];
#endif
#endif
#if LG_N_DIR > 0
uniform DirectionalLight directional_lights[LG_N_DIR];
#if LG_SHADOWS
uniform sampler2DShadow directional_shadow_maps[LG_N_DIR];
#endif
#endif
#if LG_N_POINT > 0
uniform PointLight point_lights[LG_N_POINT];
#endif

layout(location = 0) out vec4 out_radiance;  // rgb radiance, alpha unused
layout(location = 1) out vec2 out_geometry;  // (z-depth, coverage code)

// render.scene.spot_falloff: pbrt-v4's smoothstep between the cone cosines.
float spot_falloff(float cos_theta, float cos_inner, float cos_outer)
{
    float width = max(cos_inner - cos_outer, 1e-9);
    float x = clamp((cos_theta - cos_outer) / width, 0.0, 1.0);
    return x * x * (3.0 - 2.0 * x);
}

// Fraction of the 2x2 shadow-map texels around p that see p (hardware bilinear PCF).
// The lookup point is moved off the surface by LG_NORMAL_OFFSET texels along the normal and
// toward the light by LG_DEPTH_BIAS * (1 + tan(theta)) texels: the depth of a plane varies by
// tan(theta) per texel across the filter footprint, so this clears acne on lit surfaces while
// keeping the shift of shadow edges (peter-panning) near one texel.
float shadow_visibility(sampler2DShadow map, mat4 light_matrix, vec3 p, vec3 n, vec3 l,
                        float cos_theta, float texel)
{
    float sin_theta = sqrt(max(1.0 - cos_theta * cos_theta, 0.0));
    float tan_theta = min(sin_theta / max(cos_theta, 1e-3), 10.0);
    vec3 q = p + texel * (LG_NORMAL_OFFSET * n + (LG_DEPTH_BIAS * (1.0 + tan_theta)) * l);
    vec4 c = light_matrix * vec4(q, 1.0);
    if (c.w <= 0.0) {
        return 1.0;
    }
    vec3 s = c.xyz / c.w * 0.5 + 0.5;
    if (any(lessThan(s.xy, vec2(0.0))) || any(greaterThan(s.xy, vec2(1.0)))) {
        return 1.0;  // outside the map: outside the spot's cone, or beyond the scene bounds
    }
    return texture(map, vec3(s.xy, min(s.z, 1.0)));
}

#ifdef HAS_BASE_COLOR_TEX
// Albedo averaged over the pixel's footprint in texture space (the parallelogram spanned by the
// uv derivatives), LG_TEXTURE_TAPS^2 bilinear taps on a regular grid: a box filter, as a sensor
// pixel integrates. MSAA alone shades once per pixel and would alias texture edges.
vec3 pixel_albedo(vec2 uv)
{
    vec2 du = dFdx(uv);
    vec2 dv = dFdy(uv);
    vec3 sum = vec3(0.0);
    for (int i = 0; i < LG_TEXTURE_TAPS; i++) {
        for (int j = 0; j < LG_TEXTURE_TAPS; j++) {
            vec2 o = (vec2(float(i), float(j)) + 0.5) / float(LG_TEXTURE_TAPS) - 0.5;
            sum += texture(albedo_texture, uv + o.x * du + o.y * dv).rgb;
        }
    }
    return sum / float(LG_TEXTURE_TAPS * LG_TEXTURE_TAPS);
}
#endif

void main()
{
    vec3 p = frag_position;
    vec3 n = frag_normal;
    float nn = dot(n, n);
    n = nn > 0.0 ? n * inversesqrt(nn) : vec3(0.0, 0.0, 1.0);  // zero-area faces are dropped on upload
    bool front = dot(n, cam_pos - p) >= 0.0;
    if (!front) {
        n = -n;
    }

    vec3 rho = albedo;
#ifdef HAS_BASE_COLOR_TEX
    rho *= pixel_albedo(uv_0);
#endif

    vec3 E = vec3(0.0);
#if LG_N_SPOT > 0
    for (int i = 0; i < LG_N_SPOT; i++) {
        vec3 d = spot_lights[i].position - p;
        float r2 = max(dot(d, d), 1e-20);
        vec3 l = d * inversesqrt(r2);
        float cos_theta = dot(n, l);
        float f = spot_falloff(dot(spot_lights[i].direction, -l),
                               spot_lights[i].cos_inner, spot_lights[i].cos_outer);
        if (cos_theta > 0.0 && f > 0.0) {
            float vis = 1.0;
#if LG_SHADOWS
            float axial = max(dot(-d, spot_lights[i].direction), 0.0);
            vis = shadow_visibility(spot_shadow_maps[i], spot_lights[i].light_matrix, p, n, l,
                                    cos_theta, spot_lights[i].texel_per_depth * axial);
#endif
            E += spot_lights[i].intensity * (f * cos_theta * vis / r2);
        }
    }
#endif
#if LG_N_DIR > 0
    for (int i = 0; i < LG_N_DIR; i++) {
        vec3 l = -directional_lights[i].direction;
        float cos_theta = dot(n, l);
        if (cos_theta > 0.0) {
            float vis = 1.0;
#if LG_SHADOWS
            vis = shadow_visibility(directional_shadow_maps[i], directional_lights[i].light_matrix,
                                    p, n, l, cos_theta, directional_lights[i].texel);
#endif
            E += directional_lights[i].irradiance * (cos_theta * vis);
        }
    }
#endif
#if LG_N_POINT > 0
    for (int i = 0; i < LG_N_POINT; i++) {
        vec3 d = point_lights[i].position - p;
        float r2 = max(dot(d, d), 1e-20);
        float cos_theta = dot(n, d * inversesqrt(r2));
        if (cos_theta > 0.0) {
            E += point_lights[i].intensity * (cos_theta / r2);
        }
    }
#endif

    vec3 L = rho * E * (1.0 / PI);
    if (front || emit_two_sided != 0) {
        L += emission;
    }
    out_radiance = vec4(L, 1.0);
    out_geometry = vec2(frag_zdepth, coverage_code);
}
