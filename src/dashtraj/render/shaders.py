"""GLSL of the renderer: one vertex shader for every pass, the shading of the colour
pass (sun, sky, shadows, materials, fog, camera response) and the sky.

Frames: positions and normals arrive in the CARLA world frame (metres; the vertex
shader does not move them), so textures are planar in world metres and the shadow
map is looked up with the world position. ``gl_FragCoord`` rows are image rows (the
projection puts the image top at GL's row 0).

Colour pipeline of the colour pass (per fragment): albedo (sRGB vertex colour or a
material's uniform, decoded with gamma 2.2) × (hemispheric ambient + sun × Lambert ×
shadow) + Blinn–Phong specular + Fresnel-weighted reflection of the sky (paint,
glass, wet road) → aerial perspective and fog (exponential in the distance) → white
balance × exposure → ACES filmic curve (Narkowicz's fit) → display gamma →
vignetting → sensor noise (a hash of the pixel and the frame's seed: deterministic).
``legacy = 1`` reproduces the renderer's look before this module (flat sky, fixed sun,
ambient 0.45 + diffuse 0.6, no gamma).

Material codes: ``dashtraj.render.meshes.MAT_*`` (the 4th vertex colour component).
"""

from __future__ import annotations

VS = """
#version 330
uniform mat4 mvp;
uniform mat4 light_mvp;
in vec3 in_pos;
in vec3 in_normal;
in vec4 in_color;
in int in_id;
out vec3 v_light;
out vec3 v_world;
flat out vec3 v_normal;
flat out vec3 v_color;
flat out int v_mat;
out float v_depth;
flat out int v_id;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_world = in_pos;
    v_normal = in_normal;
    // the shadow map's projection is affine: interpolating it per vertex is exact
    v_light = (light_mvp * vec4(in_pos + in_normal * 0.2, 1.0)).xyz * 0.5 + 0.5;
    v_color = in_color.rgb;
    v_mat = int(in_color.a + 0.5);
    v_depth = gl_Position.w;
    v_id = in_id;
}
"""

_COMMON = """
uniform vec3 sun_dir;
uniform vec3 sun_rgb;
uniform vec3 amb_sky;
uniform vec3 amb_ground;
uniform vec3 sky_zen;
uniform vec3 sky_hor;
uniform vec3 fog_rgb;
uniform float fog_sigma;
uniform float fog_start;
uniform float cloud;
uniform vec3 cam_pos;
uniform vec3 wb;
uniform vec4 gamma_fit;
uniform vec4 vig_lo;
uniform vec4 vig_hi;
uniform float noise_std;
uniform float seed;
uniform vec2 img_size;
uniform vec2 tex_off;
uniform float tex_scale;
uniform sampler2D noise_tex;

const vec3 LEGACY_SKY = vec3(0.62, 0.74, 0.88);

float hash12(vec2 p) {
    vec3 p3 = fract(vec3(p.xyx) * 0.1031);
    p3 += dot(p3, p3.yzx + 33.33);
    return fract((p3.x + p3.y) * p3.z);
}

vec3 sky_color(vec3 d) {
    float e = d.z;
    vec3 c = mix(sky_hor, sky_zen, sqrt(clamp(e, 0.0, 1.0)));
    if (e < 0.0) c = mix(sky_hor, amb_ground, clamp(-e * 4.0, 0.0, 1.0));
    return c;
}

vec3 camera_response(vec3 c) {
    c *= wb;
    c = clamp((c * (2.51 * c + 0.03)) / (c * (2.43 * c + 0.59) + 0.14), 0.0, 1.0);
    vec3 r = sqrt(c);  // c^(1/gamma) as a fit in c, c^1/2, c^1/4, c^2 (error < 1.3 levels)
    c = gamma_fit.x * c + gamma_fit.y * r + gamma_fit.z * sqrt(r) + gamma_fit.w * c * c;
    vec2 q = (gl_FragCoord.xy - 0.5 * img_size) / (0.5 * img_size.x);
    float r2 = dot(q, q);
    // vignetting 1 / (1 + multiplier r2^(falloff/2)) as a degree-7 polynomial in r2
    // (``scene.vignette_fit``): multiply-adds instead of a pow
    c *= ((((((vig_hi.w * r2 + vig_hi.z) * r2 + vig_hi.y) * r2 + vig_hi.x) * r2 + vig_lo.w) * r2
           + vig_lo.z) * r2 + vig_lo.y) * r2 + vig_lo.x;
#ifdef NOISE
    vec2 px = gl_FragCoord.xy + seed * vec2(17.17, 91.3);
    float nz = hash12(px) + hash12(px + 53.7) - 1.0;
    c += vec3(nz * 2.45 * noise_std / 255.0);
#endif
    return c;
}
"""

_SHADE = _COMMON + """
uniform float shadow_strength;
uniform float wetness;
uniform float deposits;
uniform vec3 asphalt_rgb;
uniform vec3 sidewalk_rgb;
uniform vec3 grass_rgb;
uniform vec3 facade_tint;
uniform vec3 foliage_tint;
uniform vec3 prop_tint;
uniform float mark_wear;
uniform float road_wear;
uniform sampler2D shadow_map;

in vec3 v_light;
in vec3 v_world;
flat in vec3 v_normal;
flat in vec3 v_color;
flat in int v_mat;

#if defined(G_VEHICLE) || defined(G_FACADE) || defined(WET)
#define REFLECT
#endif
#if defined(REFLECT) || defined(G_PROPS)
#define SPECULAR
#endif

vec3 shade() {
    vec3 n = v_normal;  // flat faces: the interpolated normal is the unit face normal
    int m = v_mat;
#ifdef LEGACY
    float lam0 = max(dot(n, vec3(0.3546, -0.4559, 0.8307)), 0.0);
    return m == 1 ? v_color : v_color * (0.45 + 0.6 * lam0);
#else
    vec3 p = v_world;
    vec3 vd = cam_pos - p;
    float dist = length(vd);
    vec3 alb = v_color;
    float spec = 0.0;
    float shin = 32.0;
    float refl = 0.0;
    float wrap = 0.0;
    float emit = 0.0;
    float sunk = 1.0;
    vec2 uv = (p.xy + tex_off) / tex_scale;
#if defined(G_ASPHALT) || defined(G_MARK)
    float puddle = 0.0;
#ifdef TEXTURES
    vec4 t1 = texture(noise_tex, uv * 0.08);
    float patch = 1.0 + road_wear * (0.5 * (t1.g - 0.5) + 0.25 * (t1.b - 0.5));
    vec3 road = asphalt_rgb * (0.91 + 0.18 * t1.r) * patch;
#ifdef WET
    float pth = 1.0 - 0.3 * deposits;  // puddles cover up to ~30 % of the road
    puddle = deposits > 0.0 ? smoothstep(pth, pth + 0.12, t1.g) : 0.0;
#endif
#else
    vec3 road = asphalt_rgb;
#endif
#ifdef G_MARK
#ifdef TEXTURES
    float worn = smoothstep(1.0 - mark_wear - 0.12, 1.0 - mark_wear + 0.12, t1.a);
    alb = mix(v_color * (0.9 + 0.1 * t1.r), road, 0.85 * worn);
#endif
#else
    alb = road;
#endif
#ifdef WET
    float wet = max(wetness, puddle);
    alb *= 1.0 - 0.5 * wet;
    refl = wet * (0.04 + 0.3 * puddle);
    spec = 0.15 + 0.9 * wet;
    shin = 24.0 + 200.0 * wet;
#endif
    if (m == 14) {  // contact shadow under a vehicle: albedo × r, sun × g
        alb *= v_color.r;
        spec = 0.0;
        refl = 0.0;
        sunk = v_color.g;
    }
#elif defined(G_SIDEWALK)
    alb = sidewalk_rgb;
#ifdef TEXTURES
    vec4 t1 = texture(noise_tex, uv * 0.08);
    alb *= 0.88 + 0.24 * t1.b;
    if (m == 3) {
        vec2 g = abs(fract(p.xy / 0.6) - 0.5);
        vec2 w = fwidth(p.xy / 0.6);
        float joint = smoothstep(0.47 - w.x, 0.5, g.x) + smoothstep(0.47 - w.y, 0.5, g.y);
        alb *= 1.0 - 0.22 * clamp(joint, 0.0, 1.0) * clamp(1.0 - 3.0 * max(w.x, w.y), 0.0, 1.0);
    }
#endif
    if (m == 10) alb *= 1.06;
#ifdef WET
    alb *= 1.0 - 0.35 * wetness;
    refl = 0.1 * wetness;
    spec = 0.4 * wetness;
#endif
#elif defined(G_GRASS)
    alb = grass_rgb;
#ifdef TEXTURES
    vec4 t1 = texture(noise_tex, uv * 0.06);
    alb *= (0.8 + 0.4 * t1.r) * vec3(1.0 + 0.3 * (t1.g - 0.5), 1.0, 1.0);
#endif
#elif defined(G_FACADE)
    vec3 base = v_color * facade_tint;
    alb = base;
#ifdef TEXTURES
    if (abs(n.z) < 0.5) {
        float h1 = fract(dot(v_color, vec3(13.1, 71.7, 37.3)) * 43.7);
        float h2 = fract(h1 * 91.3 + 0.37);
        float along = dot(p.xy, vec2(-n.y, n.x));
        vec2 cell = vec2(along / (2.4 + 1.6 * h1), (p.z - 0.4) / (3.0 + 0.6 * h2));
        vec2 f = fract(cell);
        vec2 fw = fwidth(cell);
        float a = 0.18 + 0.14 * h2;
        float win = smoothstep(a - fw.x, a + fw.x, f.x)
                  * smoothstep(a - fw.x, a + fw.x, 1.0 - f.x)
                  * smoothstep(0.25 - fw.y, 0.25 + fw.y, f.y)
                  * smoothstep(0.12 - fw.y, 0.12 + fw.y, 1.0 - f.y);
        float far = clamp(1.0 - 1.5 * max(fw.x, fw.y), 0.0, 1.0);
        win *= step(0.8, cell.y);
        float lum = hash12(floor(cell) + h1 * 10.0);
        vec3 glassc = vec3(0.05, 0.07, 0.09) * (0.6 + 0.8 * lum);
        float cover = (1.0 - 2.0 * a) * 0.63;
        vec3 avg = mix(base, glassc * 1.5, cover);
        alb = mix(avg, mix(base, glassc, win), far) * (0.95 + 0.1 * fract(lum * 7.3));
        refl = 0.25 * win * far;
        spec = 0.8 * win * far;
        shin = 80.0;
    } else {
        alb = vec3(0.25, 0.25, 0.26);
    }
#endif
#elif defined(G_PROPS)
    if (m == 11) {
        alb = v_color * foliage_tint;
#ifdef TEXTURES
        alb *= 0.6 + 0.8 * texture(noise_tex, (p.xy + p.zz * 0.7) * 0.15).r;
#endif
        wrap = 0.35;
    } else if (m == 1) {
        emit = 1.0;
    } else {
        alb = v_color * prop_tint;
        if (m == 12) {
            spec = 0.5;
            shin = 40.0;
        } else if (m == 15) {
#ifdef TEXTURES
            alb *= 0.7 + 0.6 * texture(noise_tex, (p.xy * 0.8 + p.zz * 0.9) * 0.35).g;
#endif
        }
    }
#elif defined(G_VEHICLE)
    if (m == 1) {
        emit = 1.0;
    } else if (m == 5) {
        spec = 0.9;
        shin = 90.0;
        refl = 0.05;
    } else if (m == 6) {
        spec = 1.5;
        shin = 160.0;
        refl = 0.12;
    } else if (m == 7) {
        spec = 0.05;
    } else if (m == 12) {
        spec = 0.7;
        shin = 60.0;
        refl = 0.08;
    }
#endif
    alb = clamp(alb, 0.0, 1.0);
    alb *= alb;  // sRGB-ish colours to linear (gamma 2)
    float ndl = dot(n, sun_dir);
    float lam = max((ndl + wrap) / (1.0 + wrap), 0.0);
    float sh = 1.0;
#ifdef SHADOWS
    if (ndl >= 0.0 && v_light.x > 0.0 && v_light.y > 0.0 && v_light.x < 1.0 && v_light.y < 1.0
        && v_light.z < 1.0)  // faces away from the sun are dark anyway: no lookup
        sh = step(v_light.z - 0.002, texture(shadow_map, v_light.xy).r);  // nearest texel
#endif
    sh *= step(0.0, ndl);
    float direct = sunk * lam * (1.0 - shadow_strength * (1.0 - sh));
    vec3 amb = mix(amb_ground, amb_sky, 0.5 + 0.5 * n.z);
    vec3 col = alb * (amb + sun_rgb * direct);
#ifdef SPECULAR
    vec3 V = vd / max(dist, 1e-4);
    // llvmpipe runs a branch only where some fragment of the block takes it: matte
    // fragments (walls, foliage, dry road) skip the highlight and the reflection
    if (spec > 0.0) {
        vec3 h = normalize(sun_dir + V);
        float sp = exp2(shin * log2(max(dot(n, h), 1e-4))) * (shin + 8.0) / 25.0;
        col += spec * 0.04 * sp * sun_rgb * sh;
    }
#endif
#if defined(REFLECT) && defined(TEXTURES)
    if (refl > 0.0) {
        float c = max(dot(n, V), 0.0);
        float c5 = 1.0 - c;
        c5 = c5 * c5 * c5 * c5 * c5;
        float fr = refl + (1.0 - refl) * c5 * min(1.0, refl * 8.0);
        col = mix(col, sky_color(reflect(-V, n)) * 0.75, clamp(fr, 0.0, 1.0));
    }
#endif
#if defined(G_VEHICLE) || defined(G_PROPS)
    col = mix(col, alb * 1.8, emit);
#endif
    float fg = 1.0 - exp2(-1.4427 * fog_sigma * max(dist - fog_start, 0.0));
    col = mix(col, fog_rgb, fg);
    return camera_response(col);
#endif
}
"""

FS_ALL = """
""" + _SHADE + """
in float v_depth;
flat in int v_id;
layout(location = 0) out vec4 f_color;
layout(location = 1) out int f_id;
layout(location = 2) out float f_depth;
void main() { f_color = vec4(shade(), 1.0); f_id = v_id; f_depth = v_depth; }
"""

FS_COLOR = """
""" + _SHADE + """
out vec4 f_color;
void main() { f_color = vec4(shade(), 1.0); }
"""

FS_ID = """
#version 330
in float v_depth;
flat in int v_id;
layout(location = 0) out int f_id;
layout(location = 1) out float f_depth;
void main() { f_id = v_id; f_depth = v_depth; }
"""

FS_SIL = """
#version 330
uniform uint bit;
out uint f_bits;
void main() { f_bits = bit; }
"""

FS_DEPTH = """
#version 330
void main() { }
"""

VS_CASTER = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;  // vehicle frame (x forward, y right, z up), metres
in vec3 in_origin;  // per instance: the vehicle's ground point, CARLA world, metres
in vec2 in_yaw;  // per instance: cos, sin of its yaw
void main() {
    vec2 xy = in_origin.xy + vec2(in_yaw.x * in_pos.x - in_yaw.y * in_pos.y,
                                  in_yaw.y * in_pos.x + in_yaw.x * in_pos.y);
    gl_Position = mvp * vec4(xy, in_origin.z + in_pos.z, 1.0);
}
"""
"""Vertex shader of the vehicles' shadow casters in the sun's shadow map (instanced: one
draw per caster mesh; float32 placement, which only ever touches the shadow map)."""

SKY_VS = """
#version 330
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 1.0, 1.0); }
"""

SKY_FS = """
""" + _COMMON + """
uniform mat3 pix_to_world;
layout(location = 0) out vec4 f_color;
layout(location = 1) out int f_id;
layout(location = 2) out float f_depth;
void main() {
    f_id = 0;
    f_depth = uintBitsToFloat(0x7F800000u);
#ifdef LEGACY
    f_color = vec4(LEGACY_SKY, 1.0);
    return;
#endif
    vec3 d = normalize(pix_to_world * vec3(gl_FragCoord.xy, 1.0));
    vec3 c = sky_color(d);
    float sd = max(dot(d, sun_dir), 0.0);
    float clear = 1.0 - cloud;
    // sd^6 and sd^200 by squaring (pow is exp2(log2) on llvmpipe)
    float s2 = sd * sd;
    float s8 = s2 * s2;
    s8 *= s8;
    float s64 = s8 * s8;
    s64 *= s64;
    c += sun_rgb * clear * (0.03 * s2 * s2 * s2 + 0.2 * s64 * s64 * s64 * s8);
    if (sd > 0.99985) c += sun_rgb * 6.0 * clear;
#ifdef CLOUDS
    if (d.z > 0.0) {
        vec2 cuv = d.xy / (d.z + 0.08) * 0.045 + tex_off * 0.002;
        float cn = 0.65 * texture(noise_tex, cuv).a + 0.35 * texture(noise_tex, cuv * 3.7).r;
        float cov = smoothstep(1.0 - cloud - 0.05, 1.0 - cloud + 0.25, cn);
        vec3 cc = (sky_hor * 1.05 + sun_rgb * 0.08 * clear) * (0.75 + 0.35 * cn);
        c = mix(c, cc, cov * smoothstep(0.0, 0.12, d.z));
    }
#endif
    float fg = 1.0 - exp(-fog_sigma * 400.0);
    c = mix(c, fog_rgb, fg);
    f_color = vec4(camera_response(c), 1.0);
}
"""


GROUPS = ("asphalt", "mark", "sidewalk", "grass", "facade", "props", "vehicle")
"""Material groups: each is drawn with its own compiled variant of the colour shader."""


def variant(source: str, group: str | None = None, legacy: bool = False, shadows: bool = False,
            textures: bool = True, noise: bool = True, clouds: bool = False,
            wet: bool = False) -> str:
    """``source`` (``FS_ALL``, ``FS_COLOR`` or ``SKY_FS``) with the ``#define`` lines of one
    variant: llvmpipe runs both sides of a branch that any fragment of a block takes
    (under masks; it skips a branch only where no fragment takes it), so features that
    are off are compiled out instead of branched around."""
    defs = ["#version 330"]
    if group is not None:
        defs.append(f"#define G_{group.upper()}")
    for name, on in (("LEGACY", legacy), ("SHADOWS", shadows), ("TEXTURES", textures),
                     ("NOISE", noise), ("CLOUDS", clouds), ("WET", wet)):
        if on:
            defs.append(f"#define {name}")
    return "\n".join(defs) + "\n" + source
