"""GLSL 3.30 core shaders: clay characters (key + fill + sky light), grid ground with a planar
shadow mask, a background gradient and flat-coloured overlays. Lighting is in linear space and
written out as sRGB."""

BACKGROUND_VS = """#version 330
out vec2 uv;
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    uv = p;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}"""
BACKGROUND_FS = """#version 330
uniform vec4 viewport;  // x, y, w, h; rows run top-first because the projection is flipped
out vec4 color;
void main() {
    float t = (gl_FragCoord.y - viewport.y) / viewport.w;  // 0 at the top of the image
    color = vec4(mix(vec3(0.20, 0.21, 0.235), vec3(0.085, 0.09, 0.10), 1.0 - t), 1.0);
}"""

MESH_VS = """#version 330
uniform mat4 vp;
in vec3 in_pos;
in vec3 in_nrm;
out vec3 v_pos;
out vec3 v_nrm;
void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
    gl_Position = vp * vec4(in_pos, 1.0);
}"""
MESH_FS = """#version 330
uniform vec3 eye;
uniform vec3 base;      // linear albedo
uniform float alpha;
uniform int use_flat;   // 1: facet normals from screen derivatives (meshes without normals)
uniform vec3 key_dir;
uniform vec3 fill_dir;
uniform float ground_y;
uniform float ao_height;
in vec3 v_pos;
in vec3 v_nrm;
out vec4 color;
void main() {
    vec3 n = use_flat == 1 ? normalize(cross(dFdx(v_pos), dFdy(v_pos))) : normalize(v_nrm);
    vec3 v = normalize(eye - v_pos);
    if (dot(n, v) < 0.0) n = -n;  // two-sided: assets disagree on winding
    float key = max(dot(n, key_dir), 0.0);
    float fill = max(dot(n, fill_dir), 0.0);
    float sky = 0.5 + 0.5 * n.y;
    float rim = pow(1.0 - max(dot(n, v), 0.0), 3.0);
    vec3 lin = base * (0.10 + 0.22 * sky)
             + base * key * vec3(1.0, 0.95, 0.88) * 0.95
             + base * fill * vec3(0.70, 0.82, 1.0) * 0.30
             + vec3(0.10) * rim;
    // Ambient-occlusion look: parts near the ground get darker.
    lin *= mix(0.55, 1.0, clamp((v_pos.y - ground_y) / ao_height, 0.0, 1.0));
    color = vec4(pow(lin, vec3(1.0 / 2.2)), alpha);
}"""

SHADOW_VS = """#version 330
uniform mat4 vp;
uniform vec3 key_dir;
uniform float ground_y;
in vec3 in_pos;
void main() {
    // Planar projection along the key light onto the ground.
    vec3 p = in_pos - key_dir * ((in_pos.y - ground_y) / key_dir.y);
    p.y = ground_y;
    gl_Position = vp * vec4(p, 1.0);
}"""
SHADOW_FS = """#version 330
out vec4 color;
void main() { color = vec4(1.0); }"""

GROUND_VS = """#version 330
uniform mat4 vp;
in vec3 in_pos;
out vec3 v_pos;
void main() { v_pos = in_pos; gl_Position = vp * vec4(in_pos, 1.0); }"""
GROUND_FS = """#version 330
uniform vec2 center;
uniform float radius;
uniform float cell;
uniform sampler2D shadow_mask;
in vec3 v_pos;
out vec4 color;
float line(vec2 p, float spacing, float width) {
    vec2 q = p / spacing;
    vec2 g = abs(fract(q - 0.5) - 0.5) / fwidth(q);
    return 1.0 - clamp(min(g.x, g.y) - width + 1.0, 0.0, 1.0);
}
void main() {
    vec2 p = v_pos.xz;
    vec3 c = vec3(0.30, 0.305, 0.31);
    c = mix(c, vec3(0.40, 0.41, 0.42), line(p, cell, 0.6));
    c = mix(c, vec3(0.52, 0.53, 0.55), line(p, cell * 5.0, 1.0));
    float s = texelFetch(shadow_mask, ivec2(gl_FragCoord.xy), 0).r;
    c *= 1.0 - 0.5 * s;
    float r = length(p - center) / radius;
    if (r >= 1.0) discard;  // fully faded: blending it would leave the pixel as it is
    color = vec4(c, 1.0 - smoothstep(0.55, 1.0, r));
}"""

FLAT_VS = """#version 330
uniform mat4 vp;
in vec3 in_pos;
in float in_t;
out float v_t;
void main() { v_t = in_t; gl_Position = vp * vec4(in_pos, 1.0); }"""
FLAT_FS = """#version 330
uniform vec4 color_past;    // drawn where in_t <= current
uniform vec4 color_future;
uniform float current;
uniform float reach;         // frames either side of the current one drawn (the trail)
in float v_t;
out vec4 color;
void main() {
    if (abs(v_t - current) > reach) discard;
    color = v_t <= current + 0.5 ? color_past : color_future;
}"""

# The characters and overlays are drawn into the 4x MSAA buffer over transparent black with
# premultiplied alpha, and only in the screen rectangle they cover; this pass resolves that
# rectangle (the mean of the 4 samples, as the blit) and lays it over the single-sampled
# background and ground (blend ONE, ONE_MINUS_SRC_ALPHA, scissored to the rectangle).
COMPOSITE_FS = """#version 330
uniform sampler2DMS layer;
uniform int samples;
out vec4 color;
void main() {
    ivec2 q = ivec2(gl_FragCoord.xy);
    vec4 sum = vec4(0.0);
    for (int s = 0; s < samples; s++) sum += texelFetch(layer, q, s);
    color = sum / float(samples);
}"""
