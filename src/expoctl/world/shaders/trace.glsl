// Segment walker: GLSL port of expoctl.world.raycast.trace (same algorithm, same branch order), float32.
// Column/index constants (C_*, LP_*, SKY…PROP, MAT_*) and EPS_DIR, CULL_MARGIN_M, INF come from the generated header
// (gl_renderer._header), so they cannot drift from route.py / raycast.py.
// Coordinates are camera-relative: the CPU subtracts the camera position from every segment's P0/P1 per frame.

// The table lives in a uniform block when it fits (64 KiB): llvmpipe loads uniform-block data ~4x faster than
// storage-buffer data (measured 0.9 vs 3.9 ns per load per pixel; its storage loads are bounds-checked per lane).
// Longer routes fall back to a storage buffer (same code, slower). SEG_STRIDE is a multiple of 4, so with a constant
// column c the vec4 component below is a constant too.
#ifdef SEG_IN_UBO
layout(std140, binding = 0) uniform SegBlock { vec4 segv[SEG_VEC4_TOTAL]; };
#define S(i, c) segv[(i) * (SEG_STRIDE / 4) + ((c) >> 2)][(c) & 3]
#else
layout(std430, binding = 0) readonly buffer SegBuf { float seg[]; };
#define S(i, c) seg[(i) * SEG_STRIDE + (c)]
#endif
uniform int n_seg;

vec3 sv(int i, int c) { return vec3(S(i, c), S(i, c + 1), S(i, c + 2)); }

struct Hit {
    float t;
    int code;
    int j;        // segment whose frame the hit's local coordinates are in
    int air;      // segment of the air the ray was in just before the hit (start of the shadow ray)
    bool air_in;
    vec3 p;       // local (u, v, w) in segment j
    vec3 n;       // local outward normal
    int mat;
};

Hit mkhit(float t, int code, int j, int air, bool air_in, vec3 p, vec3 n, int mat) {
    Hit h;
    h.t = t; h.code = code; h.j = j; h.air = air; h.air_in = air_in; h.p = p; h.n = n; h.mat = mat;
    return h;
}

bool inside_profile(int j, float v, float w) {
    float hw = S(j, C_HW);
    if (w <= 0.0 || v <= -hw || v >= hw) return false;
    if (S(j, C_ARC_R) == 0.0) return w < S(j, C_CROWN_H);
    if (w <= S(j, C_WALL_H)) return true;
    float dc = w - S(j, C_ARC_C);
    float r = S(j, C_ARC_R);
    return v * v + dc * dc < r * r;
}

// Entry time into the solid {sign·v > off, w < h}; side = true when it enters through the side (else the roof).
float block_entry(float o_v, float o_w, float d_v, float d_w, float off, float h, float sgn, out bool side) {
    side = true;
    float sv_ = sgn * o_v, sdv = sgn * d_v;
    float lo_v, hi_v, lo_w, hi_w;
    if (sdv > EPS_DIR) { lo_v = (off - sv_) / sdv; hi_v = INF; }
    else if (sdv < -EPS_DIR) { lo_v = -INF; hi_v = (off - sv_) / sdv; }
    else if (sv_ > off) { lo_v = -INF; hi_v = INF; }
    else return INF;
    if (d_w < -EPS_DIR) { lo_w = (h - o_w) / d_w; hi_w = INF; }
    else if (d_w > EPS_DIR) { lo_w = -INF; hi_w = (h - o_w) / d_w; }
    else if (o_w < h) { lo_w = -INF; hi_w = INF; }
    else return INF;
    float entry = max(lo_v, lo_w);
    if (entry < min(hi_v, hi_w)) { side = lo_v >= lo_w; return entry; }
    return INF;
}

// Clip [tmin, tmax] to the slab lo <= o + t·d <= hi; entered/sgn: whether the entry moved here and its normal sign.
void slab(float o, float d, float lo, float hi, inout float tmin, inout float tmax, out bool entered, out float sgn) {
    entered = false;
    sgn = 0.0;
    if (abs(d) < EPS_DIR) {
        if (o < lo || o > hi) { tmin = 1.0; tmax = 0.0; }
        return;
    }
    float ta = (lo - o) / d;
    float tb = (hi - o) / d;
    sgn = -1.0;
    if (ta > tb) { float tt = ta; ta = tb; tb = tt; sgn = 1.0; }
    if (ta > tmin) { tmin = ta; entered = true; }
    if (tb < tmax) tmax = tb;
}

float box_hit(int i, int col, vec3 o, vec3 d, float t0, float best, out vec3 nrm) {
    float tmin = t0, tmax = best;
    nrm = vec3(0.0);
    bool e; float sg;
    slab(o.x, d.x, S(i, col), S(i, col + 1), tmin, tmax, e, sg);
    if (e) nrm = vec3(sg, 0.0, 0.0);
    if (tmin > tmax) return INF;
    slab(o.y, d.y, S(i, col + 2), S(i, col + 3), tmin, tmax, e, sg);
    if (e) nrm = vec3(0.0, sg, 0.0);
    if (tmin > tmax) return INF;
    slab(o.z, d.z, S(i, col + 4), S(i, col + 5), tmin, tmax, e, sg);
    if (e) nrm = vec3(0.0, 0.0, sg);
    if (tmin > tmax || nrm == vec3(0.0)) return INF;
    return tmin;
}

// The segment's right and up axes from its forward axis, as route.build_segments makes them (right = F × ẑ
// normalised, up = right × F): 3 uniform loads instead of 9 per segment step (each load is a per-lane gather on
// llvmpipe, the walk's main cost); equal to the stored axes to float32 rounding.
void frame(int i, out vec3 f, out vec3 r, out vec3 u) {
    f = sv(i, C_F);
    r = vec3(f.y, -f.x, 0.0) / sqrt(f.x * f.x + f.y * f.y);
    u = cross(r, f);
}

Hit trace(int i0, bool inside0, vec3 o, vec3 d, float tmax, float ztop, bool cull) {
    int i = i0;
    bool inside = inside0;
    float t0 = 0.0;
    // Local ray of the current segment. Unlike the numba loop, it is computed once per segment (the crossing step
    // below already needs it for the next segment, and carries it over) and from the per-frame columns C_O0 (the
    // camera's local coordinates, float64 on the CPU) instead of o − P0: fewer uniform loads per step, same values
    // up to float32 rounding.
    vec3 Fi, Ri, Ui;
    frame(i, Fi, Ri, Ui);
    // kind and roadside blocks of the current segment, carried over from the crossing step (which reads them for
    // the next segment's faces anyway) instead of loaded again
    float kind = S(i, C_KIND);
    float l_off = S(i, C_L_OFF), l_h = S(i, C_L_H), r_off = S(i, C_R_OFF), r_h = S(i, C_R_H);
    float ou = dot(o, Fi) + S(i, C_O0), ov = dot(o, Ri) + S(i, C_O0 + 1), ow = dot(o, Ui) + S(i, C_O0 + 2);
    float du = dot(d, Fi), dv = dot(d, Ri), dw = dot(d, Ui);
    for (int it = 0; it < 4096; ++it) {
        // nothing above ztop: a rising ray above it sees only sky
        if (dw > 0.0 && ow + t0 * dw > ztop) return mkhit(INF, SKY, i, i, inside, vec3(0.0), vec3(0.0), -1);
        float t_exit = INF;
        int dirn = 0;
        vec3 ne = sv(i, C_NE);
        float dn = dot(ne, d);
        if (dn > EPS_DIR) {
            float te = (S(i, C_NE_D) - dot(ne, o)) / dn;  // NE·(P1 − o)
            if (te < t_exit) { t_exit = max(te, t0); dirn = 1; }
        }
        vec3 ns = sv(i, C_NS);
        dn = dot(ns, d);
        if (dn < -EPS_DIR) {
            float ts = (S(i, C_NS_D) - dot(ns, o)) / dn;  // NS·(P0 − o)
            if (ts < t_exit) { t_exit = max(ts, t0); dirn = -1; }
        }
        float best = min(t_exit, tmax);
        int code = -1;
        vec3 n = vec3(0.0);
        int mat = -1;
        if (kind == KIND_TUNNEL && inside) {
            float hw = S(i, C_HW);
            float wall_h = S(i, C_WALL_H);
            float t;
            if (dw < -EPS_DIR) {
                t = -ow / dw;
                if (t0 <= t && t < best) { best = t; code = GROUND; n = vec3(0, 0, 1); mat = MAT_ROAD; }
            }
            if (dv > EPS_DIR) {
                t = (hw - ov) / dv;
                if (t0 <= t && t < best && ow + t * dw <= wall_h) { best = t; code = TWALL; n = vec3(0, -1, 0); mat = MAT_TWALL; }
            } else if (dv < -EPS_DIR) {
                t = (-hw - ov) / dv;
                if (t0 <= t && t < best && ow + t * dw <= wall_h) { best = t; code = TWALL; n = vec3(0, 1, 0); mat = MAT_TWALL; }
            }
            float rho = S(i, C_ARC_R);
            if (rho == 0.0) {
                if (dw > EPS_DIR) {
                    t = (S(i, C_CROWN_H) - ow) / dw;
                    if (t0 <= t && t < best) { best = t; code = TCEIL; n = vec3(0, 0, -1); mat = MAT_TCEIL; }
                }
            } else {
                float c = S(i, C_ARC_C);
                float a = dv * dv + dw * dw;
                if (a > EPS_DIR) {
                    float b = 2.0 * (ov * dv + (ow - c) * dw);
                    float cc = ov * ov + (ow - c) * (ow - c) - rho * rho;
                    float disc = b * b - 4.0 * a * cc;
                    if (disc > 0.0) {
                        t = (-b + sqrt(disc)) / (2.0 * a);
                        float wh = ow + t * dw;
                        if (t0 <= t && t < best && wh >= wall_h) {
                            float vh = ov + t * dv;
                            best = t; code = TCEIL; mat = MAT_TCEIL;
                            n = vec3(0.0, -vh / rho, -(wh - c) / rho);
                        }
                    }
                }
            }
        } else if (kind == KIND_TUNNEL) {
            if (dw < -EPS_DIR) {
                float t = (S(i, C_HILL_H) - ow) / dw;
                if (t0 <= t && t < best) { best = t; code = HILLTOP; n = vec3(0, 0, 1); mat = MAT_HILL; }
            }
        } else {
            if (dw < -EPS_DIR) {
                float t = -ow / dw;
                if (t0 <= t && t < best) { best = t; code = GROUND; n = vec3(0, 0, 1); mat = MAT_VERGE; }
            }
            // reach test of the straight piece [t0, best] before the exact block/prop tests (see raycast.trace)
            float ua = ou + t0 * du, ub = ou + best * du;
            float va = ov + t0 * dv, vb = ov + best * dv;
            float wa = ow + t0 * dw, wb = ow + best * dw;
            float v_min = min(va, vb) - CULL_MARGIN_M, v_max = max(va, vb) + CULL_MARGIN_M;
            float w_min = min(wa, wb) - CULL_MARGIN_M, w_max = max(wa, wb) + CULL_MARGIN_M;
            for (int k = 0; k < 2; ++k) {
                float sgn = k == 0 ? -1.0 : 1.0;
                float off, h, m;
                bool reach;
                if (k == 0) { off = l_off; h = l_h; m = S(i, C_L_MAT); reach = -v_min > off; }
                else { off = r_off; h = r_h; m = S(i, C_R_MAT); reach = v_max > off; }
                if (off < NO_BLOCK_OFFSET && ((reach && w_min < h) || !cull)) {
                    bool side;
                    float t = block_entry(ov, ow, dv, dw, off, h, sgn, side);
                    if (t0 <= t && t < best) {
                        best = t; mat = int(m);
                        if (side) { code = SIDE; n = vec3(0.0, -sgn, 0.0); }
                        else { code = ROOF; n = vec3(0, 0, 1); mat = MAT_ROOF; }
                    }
                }
            }
            float u_min = min(ua, ub) - CULL_MARGIN_M, u_max = max(ua, ub) + CULL_MARGIN_M;
            int nb = int(S(i, C_N_BOXES));
            for (int b = 0; b < nb; ++b) {
                int col = C_BOX0 + C_BOX_STRIDE * b;
                if (cull && (u_max < S(i, col) || u_min > S(i, col + 1) || v_max < S(i, col + 2)
                             || v_min > S(i, col + 3) || w_max < S(i, col + 4) || w_min > S(i, col + 5)))
                    continue;  // the piece's bounding box misses the prop's box
                vec3 bn;
                float t = box_hit(i, col, vec3(ou, ov, ow), vec3(du, dv, dw), t0, best, bn);
                if (t < best) { best = t; code = PROP; n = bn; mat = int(S(i, col + 6)); }
            }
        }
        if (code >= 0) return mkhit(best, code, i, i, inside, vec3(ou, ov, ow) + best * vec3(du, dv, dw), n, mat);
        if (t_exit >= tmax) {
            if (d.z < 0.0) return mkhit(INF, FAR, i, i, inside, vec3(0.0), vec3(0, 0, 1), MAT_VERGE);
            return mkhit(INF, SKY, i, i, inside, vec3(0.0), vec3(0.0), -1);
        }
        // cross into the neighbouring segment
        t0 = t_exit;
        int j = (i + dirn + n_seg) % n_seg;
        vec3 Fj, Rj, Uj;
        frame(j, Fj, Rj, Uj);
        ou = dot(o, Fj) + S(j, C_O0); ov = dot(o, Rj) + S(j, C_O0 + 1); ow = dot(o, Uj) + S(j, C_O0 + 2);
        du = dot(d, Fj); dv = dot(d, Rj); dw = dot(d, Uj);
        float pu = ou + t0 * du, pv = ov + t0 * dv, pw = ow + t0 * dw;
        if (abs(pv) > S(j, C_VMAX)) {
            if (d.z < 0.0) return mkhit(INF, FAR, j, j, false, vec3(0.0), vec3(0, 0, 1), MAT_VERGE);
            return mkhit(INF, SKY, j, j, false, vec3(0.0), vec3(0.0), -1);
        }
        float kind_j = S(j, C_KIND);
        if (kind_j == KIND_TUNNEL) {
            if (kind != KIND_TUNNEL) {
                if (inside_profile(j, pv, pw)) inside = true;
                else if (pw < S(j, C_HILL_H))
                    return mkhit(t0, FACE, j, i, inside, vec3(pu, pv, pw), vec3(-float(dirn), 0, 0), MAT_PORTAL);
                else inside = false;
            }
        } else {
            inside = false;
            l_off = S(j, C_L_OFF); l_h = S(j, C_L_H); r_off = S(j, C_R_OFF); r_h = S(j, C_R_H);
            if (pv < -l_off && pw < l_h)
                return mkhit(t0, FACE, j, i, false, vec3(pu, pv, pw), vec3(-float(dirn), 0, 0), int(S(j, C_L_MAT)));
            if (pv > r_off && pw < r_h)
                return mkhit(t0, FACE, j, i, false, vec3(pu, pv, pw), vec3(-float(dirn), 0, 0), int(S(j, C_R_MAT)));
        }
        i = j;
        kind = kind_j;
    }
    return mkhit(INF, SKY, i, i, inside, vec3(0.0), vec3(0.0), -1);
}
