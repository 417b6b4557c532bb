// Per-pixel shading: GLSL port of expoctl.world.shade (shade_pixel, render_kernel) and the texture helpers of
// expoctl.world.raycast (_hash01, _bilinear, sample_texture, box_cover, dash_cover). float32.

// Small per-scene data in one uniform block (fast loads, see trace.glsl), vec4-packed (std140 arrays have a 16-byte
// stride); sizes fixed per program (gl_renderer._programs).
layout(std140, binding = 1) uniform Params {
    vec4 lp4[LP_VEC4];            // lighting vector lp
    vec4 lamp_mult4[LAMP_VEC4];   // (n_tunnels, lamp_stride) lamp multipliers
    vec4 portal4[PORTAL_VEC4];    // (n_tunnels, 2, 2) luminance seen out of each tunnel's start/end opening, up/down
    ivec4 lamp_count4[TUN_VEC4];
    ivec4 tex_level4[LEVEL_VEC4]; // texture level offsets (M×L, texel units), then sizes (M×L)
    vec4 mat4_[MAT_VEC4];         // albedo (N_MAT), then texture scales (N_MAT)
};
#define LP(k) lp4[(k) >> 2][(k) & 3]
#define LAMP_MULT(k) lamp_mult4[(k) >> 2][(k) & 3]
#define PORTAL_LUM(k) portal4[(k) >> 2][(k) & 3]
#define LAMP_COUNT(k) lamp_count4[(k) >> 2][(k) & 3]
#define TEX_LEVEL(k) tex_level4[(k) >> 2][(k) & 3]
#define MAT_PROP(k) mat4_[(k) >> 2][(k) & 3]
// atlas texels, one RGBA8 word per texel (the flat uint8 RGB atlas repacked: one load per texel, not three)
layout(std430, binding = 4) readonly buffer TexelBuf { uint texels[]; };
uniform int lamp_stride;
uniform int n_lev;
uniform sampler2D hdri;  // equirectangular RGB32F, row 0 = zenith; fetched texel by texel (same bilinear as numba)

uint hash_u(int a, int b) {
    uint h = uint(a) * 374761393u + uint(b) * 668265263u;  // mod 2^32, as the int64 & 0xFFFFFFFF of _hash01
    h = (h ^ (h >> 13)) * 1274126177u;
    return h ^ (h >> 16);
}

void bilinear(int base, int n, float x, float y, inout vec3 acc, float weight) {
    x -= 0.5;
    y -= 0.5;
    float fx0 = floor(x), fy0 = floor(y);
    float ax = x - fx0, ay = y - fy0;
    int mask = n - 1;  // level sizes are powers of two (checked in Renderer)
    int x0 = int(fx0) & mask, y0 = int(fy0) & mask;
    int x1 = (x0 + 1) & mask, y1 = (y0 + 1) & mask;
    int row0 = base + y0 * n, row1 = base + y1 * n;
    vec3 v00 = unpackUnorm4x8(texels[row0 + x0]).rgb;
    vec3 v01 = unpackUnorm4x8(texels[row0 + x1]).rgb;
    vec3 v10 = unpackUnorm4x8(texels[row1 + x0]).rgb;
    vec3 v11 = unpackUnorm4x8(texels[row1 + x1]).rgb;
    acc += weight * ((v00 * (1.0 - ax) + v01 * ax) * (1.0 - ay) + (v10 * (1.0 - ax) + v11 * ax) * ay);
}

// Trilinear mip sample of material mat. The along-route coordinate comes split as (cell0, a_local): the integer
// tile cell of the segment start (from float64 on the CPU) and the metres past it, so km-scale arc lengths keep
// float32 precision; the level's texel wrap is periodic in the tile length, so only the cell index (for the hash
// shift) needs the full value.
vec3 sample_tex(int mat, float cell0, float a_local, float b_m, float footprint_m, float texel_m) {
    int n0 = TEX_LEVEL(N_MAT * n_lev + mat * n_lev);
    float tile_m = float(n0) * texel_m;
    float fc = floor(a_local / tile_m);
    int cell = int(cell0 + fc);
    float shift = float(hash_u(cell, mat + 17)) * (1.0 / 4294967296.0) * tile_m;
    float a = (a_local - fc * tile_m) + shift;
    float lev = log2(max(footprint_m / texel_m, 1e-6));
    lev = min(max(lev, 0.0), float(n_lev) - 1.0);
    int l0 = int(lev);
    float fr = lev - float(l0);
    int l1 = min(l0 + 1, n_lev - 1);
    vec3 acc = vec3(0.0);
    float s0 = float(1 << l0);
    bilinear(TEX_LEVEL(mat * n_lev + l0), TEX_LEVEL(N_MAT * n_lev + mat * n_lev + l0),
             a / (texel_m * s0), b_m / (texel_m * s0), acc, 1.0 - fr);
    if (fr > 0.0) {
        float s1 = float(1 << l1);
        bilinear(TEX_LEVEL(mat * n_lev + l1), TEX_LEVEL(N_MAT * n_lev + mat * n_lev + l1),
                 a / (texel_m * s1), b_m / (texel_m * s1), acc, fr);
    }
    // unpackUnorm gives v/255 already: × scale is the numba v · scale/255
    return acc * MAT_PROP(N_MAT + mat);
}

float box_cover(float x, float half_, float c, float half_w) {
    float lo = max(x - half_, c - half_w);
    float hi = min(x + half_, c + half_w);
    return max(0.0, hi - lo) / (2.0 * half_);
}

float dash_integral(float x, float period, float on) {
    float k = floor(x / period);
    return k * on + min(x - k * period, on);
}

float dash_cover(float x, float half_, float period, float on, float phase) {
    return (dash_integral(x + half_ - phase, period, on) - dash_integral(x - half_ - phase, period, on)) / (2.0 * half_);
}

// atan(t) for t >= 0 to float32 rounding (llvmpipe's atan is off by ~1.5e-5 relative, which the daylight sum would
// amplify): octant reduction to |u| <= tan(π/8), then the odd Taylor series (u² <= 0.172: 12 terms reach 1e-9)
float atan_pos(float t) {
    bool inv = t > 1.0;
    float u = inv ? 1.0 / t : t;
    float off = 0.0;
    if (u > 0.41421356) { u = (u - 1.0) / (u + 1.0); off = 0.25 * PI; }
    float z = u * u;
    float s = 1.0 / 23.0;
    for (int k = 10; k >= 0; --k) s = 1.0 / float(2 * k + 1) - z * s;
    float r = off + u * s;
    return inv ? 0.5 * PI - r : r;
}

// atan(t) − t for t >= 0 without cancellation for small t: −t³/3 + t⁵/5 − … (t² < 0.25: 14 terms reach 1e-9)
float atan_minus_t(float t) {
    if (t >= 0.5) return atan_pos(t) - t;
    float z = t * t;
    float q = 1.0 / 29.0;  // q = 1/3 − z/5 + z²/7 − … (Horner, 14 terms)
    for (int k = 13; k >= 1; --k) q = 1.0 / float(2 * k + 1) - z * q;
    return -t * z * q;
}

vec3 sky(vec3 d) {
    if (LP(LP_HDRI) > 0.5) {
        ivec2 sz = textureSize(hdri, 0);
        int w = sz.x, h = sz.y;
        float az = atan(d.y, d.x) + LP(LP_HDRI_AZ);
        // = asin(d.z) for a unit d, but well conditioned near the zenith: in float32, asin's slope 1/sqrt(1 − z²)
        // turns the rounding of d.z into ~3e-4 rad there (a twentieth of a texel of a 1k map)
        float el = atan(d.z, length(d.xy));
        float x = fract(0.5 - az / (2.0 * PI)) * float(w) - 0.5;
        float y = (0.5 - el / PI) * float(h) - 0.5;
        int x0 = int(floor(x));
        int y0 = clamp(int(floor(y)), 0, h - 1);
        int y1 = min(y0 + 1, h - 1);
        float ax = x - floor(x);
        float ay = clamp(y - float(y0), 0.0, 1.0);
        int xa = ((x0 % w) + w) % w, xb = (((x0 + 1) % w) + w) % w;
        vec3 v = (texelFetch(hdri, ivec2(xa, y0), 0).rgb * (1.0 - ax) + texelFetch(hdri, ivec2(xb, y0), 0).rgb * ax)
                 * (1.0 - ay)
                 + (texelFetch(hdri, ivec2(xa, y1), 0).rgb * (1.0 - ax) + texelFetch(hdri, ivec2(xb, y1), 0).rgb * ax) * ay;
        return LP(LP_HDRI_SCALE) * v;
    }
    float cs = d.x * LP(0) + d.y * LP(1) + d.z * LP(2);
    float lum;
    if (LP(LP_SKY_KIND) > 0.5) {
        // CIE general (clear) sky, L/Lz = f(χ)·φ(Z)/(f(Zs)·φ(0)) (clear_sky.general_sky_inline); below the horizon
        // the horizon value (φ = 1)
        float phi = 1.0;
        if (d.z > 0.0) phi = 1.0 + LP(LP_SKY_ABCDE) * exp(LP(LP_SKY_ABCDE + 1) / d.z);
        float cc = clamp(cs, -1.0, 1.0);
        // χ = 2·atan(|d − s| / |d + s|): well conditioned everywhere, and atan_pos is accurate to float32 rounding
        // (llvmpipe's acos, like its atan, is off by ~1e-5, which the steep indicatrix of type 13 amplified ~10×)
        vec3 sun_d = vec3(LP(0), LP(1), LP(2));
        float ap = length(d + sun_d);
        float chi = ap > 1.0e-30 ? 2.0 * atan_pos(length(d - sun_d) / ap) : PI;
        float f = 1.0 + LP(LP_SKY_ABCDE + 2) * (exp(LP(LP_SKY_ABCDE + 3) * chi) - exp(LP(LP_SKY_ABCDE + 3) * 0.5 * PI))
                  + LP(LP_SKY_ABCDE + 4) * cc * cc;
        lum = LP(LP_LZ) * f * phi * LP(LP_SKY_NORM);
    } else {
        // CIE standard overcast sky; below the horizon the horizon value
        lum = LP(LP_LZ) * (1.0 + 2.0 * max(d.z, 0.0)) / 3.0;
    }
    vec3 out_ = lum * vec3(LP(LP_SKY_RGB), LP(LP_SKY_RGB + 1), LP(LP_SKY_RGB + 2));
    if (LP(LP_E_SUN) > 0.0 && cs > LP(LP_SUN_COS)) out_ += LP(LP_SUN_DISK_L);
    return out_;
}

float lamp_height(int j, float v) {
    if (S(j, C_ARC_R) == 0.0) return S(j, C_CROWN_H) - 0.05;
    float r = S(j, C_ARC_R);
    float dv = min(abs(v), r * 0.95);
    return S(j, C_ARC_C) + sqrt(r * r - dv * dv) - 0.05;
}

float lamp_illuminance(int j, float x, vec3 p, vec3 n) {
    int tid = int(S(j, C_TUN_ID));
    float spacing = LP(LP_LAMP_SPACING);
    float area = LP(LP_LAMP_LEN) * LP(LP_LAMP_W);
    float intensity = LP(LP_LAMP_L) * area;
    int kc = int(floor((x - 0.5 * spacing) / spacing + 0.5));
    int n_rows = int(LP(LP_N_ROWS));
    float heights[4];
    for (int r = 0; r < 4; ++r) heights[r] = r < n_rows ? lamp_height(j, LP(LP_ROWS + r)) : 0.0;
    float e = 0.0;
    int count = LAMP_COUNT(tid);
    for (int k = kc - 4; k < kc + 5; ++k) {
        if (k < 0 || k >= count) continue;
        float du = (0.5 * spacing + float(k) * spacing) - x;
        float mult = LAMP_MULT(tid * lamp_stride + k);
        for (int r = 0; r < n_rows; ++r) {
            float ddv = LP(LP_ROWS + r) - p.y;
            float ddw = heights[r] - p.z;
            float r2 = du * du + ddv * ddv + ddw * ddw;
            float rr = sqrt(r2);
            float cos_l = ddw / rr;
            float cos_s = (n.x * du + n.y * ddv + n.z * ddw) / rr;
            if (cos_l > 0.0 && cos_s > 0.0) e += mult * intensity * cos_l * cos_s / max(r2, area);
        }
    }
    return e;
}

// coverage of white paint: solid edge lines, dashed lane dividers (3 m every 12 m); s = arc length mod 12 m
float road_marking(float s, float v, float half_v, float half_s) {
    int lanes = int(LP(LP_LANES));
    float lw = LP(LP_LANE_W);
    float edge = float(lanes) * lw / 2.0;
    float cov = box_cover(v, half_v, -edge + 0.1, 0.075) + box_cover(v, half_v, edge - 0.1, 0.075);
    for (int k = 1; k < lanes; ++k) {
        float across = box_cover(v, half_v, -edge + float(k) * lw, 0.07);
        if (across > 0.0) cov += across * dash_cover(s, half_s, 12.0, 3.0, 0.0);
    }
    return min(cov, 1.0);
}

// one edge of Lambert's polygon formula minus m/x, for the two portals at axial distances x.x and x.y, in the
// cancellation-free form of daylight._edge
vec2 vf_edge(vec2 x, vec2 a, vec2 b, vec2 n) {
    float dv = b.x - a.x, dw = a.y - b.y;
    float m = n.x * dw + n.y * dv;
    if (m == 0.0) return vec2(0.0);
    float l2 = dv * dv + dw * dw;
    float d = a.x * b.y - a.y * b.x;
    float d2 = d * d;
    float pp = dot(a, b);
    vec2 out_;
    for (int k = 0; k < 2; ++k) {
        float xx = x[k];
        float nc = sqrt(d2 + xx * xx * l2);
        float p = xx * xx + pp;
        out_[k] = p > 0.0 ? xx * m * atan_minus_t(nc / p) / nc - m * pp / (xx * p)
                          : xx * m * (PI - atan_pos(nc / -p)) / nc - m / xx;
    }
    return out_;
}

// configuration factors of a tunnel's two openings at axial distances x0, x1 from the surface point p = (v, w) with
// normal n = (nv, nw): xy = F of the whole openings, zw = G of their parts below the point's height (rays descending)
// (daylight.opening_factors_inline: box rectangle, or walls + ARC_EDGES arch chords; the lower part clipped on the walk)
vec4 opening_factors(int j, float x0, float x1, vec2 p, vec2 n) {
    vec2 x = max(vec2(x0, x1), vec2(1.0e-3));
    float hw = S(j, C_HW), wall_h = S(j, C_WALL_H), crown_h = S(j, C_CROWN_H);
    float arc_c = S(j, C_ARC_C), arc_r = S(j, C_ARC_R);
    float w = p.y;
    float top = arc_r == 0.0 ? crown_h : wall_h;
    bool box_ceiling = arc_r == 0.0 && w >= crown_h - 1.0e-6;
    bool low = w > 1.0e-6 && !box_ceiling;
    float wc = min(w, top);
    vec2 bl = vec2(-hw, 0.0) - p, br = vec2(hw, 0.0) - p;
    vec2 e = vf_edge(x, bl, br, n);
    vec2 f = e, g = vec2(0.0);
    if (low) g += e + vf_edge(x, br, vec2(br.x, wc - w), n);
    vec2 pv = vec2(hw, top) - p;
    f += vf_edge(x, br, pv, n);
    vec2 out_pt = vec2(br.x, wc - w);
    if (arc_r > 0.0) {
        float a0 = atan(wall_h - arc_c, hw);
        float step = (PI - 2.0 * a0) / float(ARC_EDGES);
        float cs = cos(step), sn = sin(step);
        float ca = hw / arc_r, sa = (wall_h - arc_c) / arc_r;
        for (int k = 0; k < ARC_EDGES; ++k) {
            float c2 = ca * cs - sa * sn;
            sa = sa * cs + ca * sn;
            ca = c2;
            vec2 q = vec2(arc_r * ca, arc_c + arc_r * sa) - p;
            e = vf_edge(x, pv, q, n);
            f += e;
            if (low && w > wall_h) {
                bool p_in = pv.y <= 0.0, q_in = q.y <= 0.0;
                if (p_in && q_in) {
                    g += e;
                } else if (p_in || q_in) {
                    vec2 ip = vec2(pv.x + (q.x - pv.x) * (0.0 - pv.y) / (q.y - pv.y), 0.0);
                    if (p_in) {
                        g += vf_edge(x, pv, ip, n);
                        out_pt = ip;
                    } else {
                        g += vf_edge(x, out_pt, ip, n) + vf_edge(x, ip, q, n);
                    }
                }
            }
            pv = q;
        }
    } else {
        vec2 q = vec2(-hw, crown_h) - p;
        f += vf_edge(x, pv, q, n);
        pv = q;
    }
    if (low && w <= wall_h) {
        g += vf_edge(x, vec2(br.x, 0.0), vec2(bl.x, 0.0), n) + vf_edge(x, vec2(bl.x, 0.0), bl, n);
    } else if (low) {
        g += vf_edge(x, pv, bl, n);
    }
    f += vf_edge(x, pv, bl, n);
    f = abs(f) / (2.0 * PI);
    g = box_ceiling ? f : abs(g) / (2.0 * PI);
    return vec4(f, g);
}

int lamp_index(int tid, float x, float spacing) {
    return clamp(int(floor((x - 0.5 * spacing) / spacing + 0.5)), 0, LAMP_COUNT(tid) - 1);
}

// Luminance of one ray (o camera-relative, d unit); t, code and material through the out parameters.
vec3 shade_pixel(vec3 o, vec3 d, float pix_rad, int start_seg, bool start_inside, bool cull,
                 out float t_out, out int code_out, out int mat_out) {
    Hit hit = trace(start_seg, start_inside, o, d, LP(LP_TMAX), LP(LP_ZTOP), cull);
    code_out = hit.code;
    if (hit.code == SKY) { t_out = INF; mat_out = MAT_SKY; return sky(d); }
    float texel_m = LP(LP_TEXEL_M);
    if (hit.code == FAR) {
        float e = LP(LP_E_SKY) + LP(LP_E_SUN) * max(LP(2), 0.0);
        t_out = 1.0e4; mat_out = MAT_VERGE;
        return vec3(MAT_PROP(MAT_VERGE) * e / PI);
    }
    int j = hit.j;
    float t = hit.t;
    float u = hit.p.x, v = hit.p.y, w = hit.p.z;
    vec3 nl = hit.n;
    vec3 fj, rj, uj;
    frame(j, fj, rj, uj);  // trace.glsl: axes from the forward axis (3 loads, not 9)
    vec3 nw_ = nl.x * fj + nl.y * rj + nl.z * uj;
    int code = hit.code;
    int mat = hit.mat;
    bool interior = S(j, C_KIND) == KIND_TUNNEL && (code == GROUND || code == TWALL || code == TCEIL);
    float road_half = LP(LP_ROAD_HALF);
    // along-route texture coordinate as (cell0, metres past it): s_hit = S0 + u, or v + 37·S0 on faces
    float cell0 = S(j, C_SCELL), a = S(j, C_SREM) + u, b = v;
    if (code == GROUND) {
        float av = abs(v);
        if (av < road_half) mat = MAT_ROAD;
        else if (interior || av < road_half + LP(LP_SIDEWALK)) mat = MAT_SIDEWALK;
        else mat = MAT_VERGE;
    } else if (code == SIDE || code == TWALL) {
        b = w;
    } else if (code == FACE) {
        cell0 = S(j, C_FCELL); a = S(j, C_FREM) + v; b = w;
    } else if (code == PROP) {
        if (abs(nl.x) > 0.5) { cell0 = S(j, C_FCELL); a = S(j, C_FREM) + v; b = w; }
        else if (abs(nl.y) > 0.5) b = w;
    }
    float cos_i = abs(dot(nw_, d));
    float foot_across = t * pix_rad;
    float foot = foot_across / sqrt(max(cos_i, 0.02));
    vec3 tex = sample_tex(mat, cell0, a, b, foot * LP(LP_MIP_BIAS), texel_m);
    float alb = MAT_PROP(mat);
    if (mat == MAT_ROAD) {
        float paint = road_marking(S(j, C_S12) + u, v, max(0.5 * foot, 1e-4), max(0.5 * foot_across / max(cos_i, 0.02), 1e-4));
        tex = (1.0 - paint) * tex * alb + paint * 0.6;
    } else {
        tex *= alb;
    }
    // illumination
    float e_day = 0.0, e_lamp = 0.0;
    vec3 sun = vec3(LP(0), LP(1), LP(2));
    float e_sun = LP(LP_E_SUN);
    float cos_sun = dot(nw_, sun);
    if (e_sun > 0.0 && cos_sun > 0.0 && sun.z > 0.0) {
        vec3 ps = o + t * d + 0.02 * nw_;
        Hit sh = trace(hit.air, hit.air_in, ps, sun, LP(LP_TMAX), LP(LP_ZTOP), cull);
        if (sh.code == SKY) e_day += e_sun * cos_sun;
    }
    float x = S(j, C_TX0) + u;  // distance into the tunnel (only used on tunnel segments)
    if (!interior) {
        e_day += LP(LP_E_SKY) * 0.5 * (1.0 + nw_.z);
    } else {
        float tl = S(j, C_TUN_LEN);
        int tid = int(S(j, C_TUN_ID));
        if (LP(LP_DAYLIGHT_MODEL) > 0.5) {
            // diffuse daylight through both openings (the sun's own patch is the shadow ray's, above)
            vec4 f = opening_factors(j, x, tl - x, hit.p.yz, nl.yz);
            e_day += PI * ((f.x - f.z) * PORTAL_LUM(4 * tid) + f.z * PORTAL_LUM(4 * tid + 1)
                           + (f.y - f.w) * PORTAL_LUM(4 * tid + 2) + f.w * PORTAL_LUM(4 * tid + 3));
        } else {
            float tail = LP(LP_TAIL_M);
            float e_glob = LP(LP_E_SKY) + e_sun * max(sun.z, 0.0);
            e_day += LP(LP_TAIL_FRAC) * e_glob * (exp(-3.0 * x / tail) + exp(-3.0 * (tl - x) / tail));
        }
        e_lamp += lamp_illuminance(j, x, hit.p, nl);
        int kc = lamp_index(tid, x, LP(LP_LAMP_SPACING));
        e_lamp += LP(LP_INTERREFL) * LP(LP_E_LAMP_NOM) * LAMP_MULT(tid * lamp_stride + kc);
    }
    vec3 lamp_rgb = vec3(LP(LP_LAMP_RGB), LP(LP_LAMP_RGB + 1), LP(LP_LAMP_RGB + 2));
    vec3 out_ = tex * (e_day + e_lamp * lamp_rgb) / PI;
    if (code == TCEIL) {
        // emissive lamp panels, box-filtered over the pixel footprint
        float spacing = LP(LP_LAMP_SPACING);
        float half_ = max(0.5 * foot, 1e-4);
        float along = dash_cover(x, half_, spacing, LP(LP_LAMP_LEN), 0.5 * spacing - 0.5 * LP(LP_LAMP_LEN));
        if (x < 0.0 || x > S(j, C_TUN_LEN)) along = 0.0;
        if (along > 0.0) {
            float cov = 0.0;
            for (int r = 0; r < int(LP(LP_N_ROWS)); ++r) cov += box_cover(v, half_, LP(LP_ROWS + r), 0.5 * LP(LP_LAMP_W));
            cov = min(cov * along, 1.0);
            if (cov > 0.0) {
                int tid = int(S(j, C_TUN_ID));
                float le = LP(LP_LAMP_L) * LAMP_MULT(tid * lamp_stride + lamp_index(tid, x, spacing));
                out_ = (1.0 - cov) * out_ + cov * le * lamp_rgb;
                if (cov > 0.5) mat = MAT_LAMP;
            }
        }
    }
    t_out = t;
    mat_out = mat;
    return out_;
}

uniform mat3 rot;        // camera-to-world rotation (columns: camera x right, y down, z forward)
uniform vec4 intr;       // fx, fy, cx, cy
uniform int start_seg;
uniform bool start_inside;
uniform bool cull;

layout(location = 0) out vec4 out_lum_depth;  // rgb cd/m², a = z-depth (inf for sky)
layout(location = 1) out uvec2 out_code_mat;

void main() {
    // gl_FragCoord is the pixel centre (x + 0.5, y + 0.5); framebuffer row y is image row y (read back unflipped)
    float cxr = (gl_FragCoord.x - intr.z) / intr.x;
    float cyr = (gl_FragCoord.y - intr.w) / intr.y;
    float nrm = 1.0 / sqrt(cxr * cxr + cyr * cyr + 1.0);
    vec3 d = (rot * vec3(cxr, cyr, 1.0)) * nrm;
    float t; int code; int mat;
    vec3 l = shade_pixel(vec3(0.0), d, nrm * sqrt(nrm) / intr.x, start_seg, start_inside, cull, t, code, mat);
    out_lum_depth = vec4(l, t < 1.0e29 ? t * nrm : uintBitsToFloat(0x7f800000u));
    out_code_mat = uvec2(uint(code), uint(mat));
}
