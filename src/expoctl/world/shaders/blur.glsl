#version 450
// Fast motion blur: GLSL port of expoctl.world.renderer._blur_kernel. Pixel x at time τ ∈ [start, end] sees the
// rendered point that sat at x − flow(τ), flow linear between the flows to the start (a) and end (b) poses, from the
// sharp render's depth (sky at 100 km). The poses come relative to the sharp render's camera (M·p + m, composed in
// float64 on the CPU), so km-scale translations never enter float32.
// The bilinear taps use the texture unit's filter (linear, clamped to the edge = numba's index clamping) instead of
// four texelFetch: llvmpipe filters float textures at full float precision (blur agrees with numba to ~1e-6
// relative, tests/world/test_gl_renderer.py) and the pass ran 26 → 16 ms at 640×480.

uniform sampler2D sharp;  // rgb luminance, a = z-depth (inf for sky)
uniform mat3 m_a;         // camera(ref) → camera(a) rotation
uniform vec3 t_a;
uniform mat3 m_b;
uniform vec3 t_b;
uniform vec4 intr;        // fx, fy, cx, cy

layout(location = 0) out vec4 out_lum_flow;  // rgb smeared luminance, a = largest flow component (px)

vec2 project(mat3 m, vec3 t, vec3 p) {
    vec3 q = m * p + t;
    float qz = max(q.z, 1e-3);
    return vec2(intr.x * q.x / qz + intr.z, intr.y * q.y / qz + intr.w);
}

void main() {
    ivec2 sz = textureSize(sharp, 0);
    int w = sz.x, h = sz.y;
    int x = int(gl_FragCoord.x), y = int(gl_FragCoord.y);
    float z = texelFetch(sharp, ivec2(x, y), 0).a;
    if (!(z < 1e5)) z = 1e5;
    vec3 p = vec3((float(x) + 0.5 - intr.z) / intr.x * z, (float(y) + 0.5 - intr.w) / intr.y * z, z);
    vec2 fa = project(m_a, t_a, p) - gl_FragCoord.xy;
    vec2 fb = project(m_b, t_b, p) - gl_FragCoord.xy;
    float m = max(max(abs(fa.x), abs(fa.y)), max(abs(fb.x), abs(fb.y)));
    float len_ = length(fb - fa);
    int n = len_ >= 0.5 ? min(64, int(ceil(2.0 * len_)) + 1) : 1;
    vec3 acc = vec3(0.0);
    vec2 inv_size = 1.0 / vec2(sz);
    for (int k = 0; k < n; ++k) {
        float a = (float(k) + 0.5) / float(n);
        float sx = clamp(float(x) - ((1.0 - a) * fa.x + a * fb.x), 0.0, float(w) - 1.0);
        float sy = clamp(float(y) - ((1.0 - a) * fa.y + a * fb.y), 0.0, float(h) - 1.0);
        acc += texture(sharp, (vec2(sx, sy) + 0.5) * inv_size).rgb;  // hardware bilinear (edge-clamped)
    }
    out_lum_flow = vec4(acc / float(n), m);
}
