// `ProjectLanes<L>`: the EWA projection of L Gaussians at a time (forward and its exact
// vector-Jacobian product), one Gaussian per float64 lane. Branch-free: a culled lane
// computes on (its values are discarded by the visible mask), so every lane runs the same
// operations as the others and the results do not depend on the vector width. No include
// guard: dispatch.hpp includes it once per instruction set, like raster_lanes.hpp. Include
// projection.hpp first.

template <int L>
struct ProjectLanes {
    typedef typename DVectors<L>::d vd;
    typedef typename DVectors<L>::m vm;  // lane masks, -1 or 0

    static vd splat(double x) { return vd{} + x; }
    static vd vmax(vd a, vd b) { return a > b ? a : b; }
    static vd vmin(vd a, vd b) { return a < b ? a : b; }
    static vd vclamp(vd x, double lo, double hi) { return vmin(vmax(x, splat(lo)), splat(hi)); }
    static vd vabs(vd x) { return x < 0.0 ? -x : x; }
    static vm vnot(vm m) { return ~m; }
    static vd vsqrt(vd x) {
        vd r;
        for (int i = 0; i < L; ++i) r[i] = __builtin_sqrt(x[i]);
        return r;
    }

    // exp (Cephes' Pade form, about 1 ulp) for x in [-708, 709] (log-scales and logits
    // are far inside: the scale clamp and sigmoid's exp(-|x|)).
    static vd vexp(vd x) {
        x = vclamp(x, -708.0, 709.0);
        const vd n = (x * 1.4426950408889634 + 6755399441055744.0) - 6755399441055744.0;
        const vd r = (x - n * 6.93145751953125e-1) - n * 1.42860682030941723212e-6;
        const vd r2 = r * r;
        const vd p = r * ((1.26177193074810590878e-4 * r2 + 3.02994407707441961300e-2) * r2 +
                          9.99999999999999999910e-1);
        const vd q = ((3.00198505138664455042e-6 * r2 + 2.52448340349684104192e-3) * r2 +
                      2.27265548208155028766e-1) *
                         r2 +
                     2.00000000000000000009e0;
        const vd e = 1.0 + 2.0 * (p / (q - p));
        const vm bits = (__builtin_convertvector(n, vm) + 1023) << 52;
        return e * (vd)bits;
    }

    // log for positive finite x (fdlibm's method, about 1 ulp): x = m 2^e with m in
    // [sqrt(1/2), sqrt(2)), f = m - 1, s = f / (2 + f), log(m) = f - f^2/2 + s (f^2/2 + R(s^2)).
    static vd vlog(vd x) {
        const vm bits = (vm)x;
        const vd m0 = (vd)((bits & 0x000fffffffffffffLL) | 0x3ff0000000000000LL);  // [1, 2)
        const vm big = m0 > 1.4142135623730951;
        const vd m = big ? m0 * 0.5 : m0;
        // the biased exponent (1 .. 2047) as a double, exactly, through its bits
        const vm biased = ((bits >> 52) & 0x7ff) - big;
        const vd e = ((vd)(biased | 0x4330000000000000LL) - 4503599627370496.0) - 1023.0;
        const vd f = m - 1.0, s = f / (2.0 + f), z = s * s, w = z * z;
        const vd R = z * (6.666666666666735130e-01 +
                          w * (2.857142874366239149e-01 +
                               w * (1.818357216161805012e-01 + w * 1.479819860511658591e-01))) +
                     w * (3.999999999940941908e-01 +
                          w * (2.222219843214978396e-01 + w * 1.531383769920937332e-01));
        const vd hfsq = 0.5 * f * f;
        return e * 6.93147180369123816490e-01 -
               ((hfsq - (s * (hfsq + R) + e * 1.90821492927058770002e-10)) - f);
    }

    static vd vceil(vd x) { return vround<true>(x); }
    static vd vfloor(vd x) { return vround<false>(x); }
    template <bool up>
    static vd vround(vd x) {
#ifdef __x86_64__
        constexpr int mode =
            (up ? _MM_FROUND_TO_POS_INF : _MM_FROUND_TO_NEG_INF) | _MM_FROUND_NO_EXC;
        if constexpr (L == 4) return (vd)_mm256_round_pd((__m256d)x, mode);
        if constexpr (L == 8)  // masked: the plain form's undefined source draws a warning
            return (vd)_mm512_mask_roundscale_pd((__m512d)x, 0xff, (__m512d)x, mode);
#endif
        for (int i = 0; i < L; ++i) x[i] = up ? std::ceil(x[i]) : std::floor(x[i]);
        return x;
    }
    // x rounded to float32 and back
    static vd f32(vd x) {
        for (int i = 0; i < L; ++i) x[i] = double(float(x[i]));
        return x;
    }

    static vd sigmoid(vd x) {
        const vd e = vexp(-vabs(x));
        return x >= 0.0 ? 1.0 / (1.0 + e) : e / (1.0 + e);
    }

    // The inputs of L Gaussians (ids: their indices).
    struct In {
        vd mean[3], log_scale[3], quat[4], logit;
    };

    static In gather(const Gaussians& g, const int32_t* ids) {
        In in;
        for (int l = 0; l < L; ++l) {
            const int64_t i = ids[l];
            for (int c = 0; c < 3; ++c) {
                in.mean[c][l] = g.means[3 * i + c];
                in.log_scale[c][l] = g.log_scales[3 * i + c];
            }
            for (int c = 0; c < 4; ++c) in.quat[c][l] = g.quats[4 * i + c];
            in.logit[l] = g.logits[i];
        }
        return in;
    }

    // All intermediates of the projection that its VJP reads.
    struct Proj {
        vm visible;
        vd qn[4], qnorm;
        vd s[3];
        vm s_active[3];         // log-scale inside the clamp range (gradient passes)
        vd R[9], VM[9];         // rotation; V R diag(s)
        vd Sc[9];               // camera-space covariance VM VM^T
        vd tc[3];               // camera-space mean
        vd rx_ratio, ry_ratio;  // clamped x/z and y/z used in J
        vm x_free, y_free;      // clamp inactive
        vd J[6];
        vd cov[3], covd[3];  // 2D covariance a, b, c before and after dilation
        vd det_orig, det;
        vd conic[3];
        vd comp;  // sqrt(det_orig / det), 1 when not antialiased
        vd sig;   // sigmoid(logit)
        vd opacity;
        vd mean2d[2];
    };

    static void quat_to_rotmat(const vd* q, vd* R) {
        const vd w = q[0], x = q[1], y = q[2], z = q[3];
        R[0] = 1.0 - 2.0 * (y * y + z * z);
        R[1] = 2.0 * (x * y - w * z);
        R[2] = 2.0 * (x * z + w * y);
        R[3] = 2.0 * (x * y + w * z);
        R[4] = 1.0 - 2.0 * (x * x + z * z);
        R[5] = 2.0 * (y * z - w * x);
        R[6] = 2.0 * (x * z - w * y);
        R[7] = 2.0 * (y * z + w * x);
        R[8] = 1.0 - 2.0 * (x * x + y * y);
    }

    // Culling (visible = 0): outside (near, far) (which includes behind and at the camera
    // centre), a degenerate dilated 2D covariance (determinant <= 1e-10, conic beyond 1e30,
    // only possible with eps2d = 0), or opacity below 1/255.
    static Proj project(const Camera& cam, const In& in) {
        Proj P;
        const vd* q = in.quat;
        P.qnorm = vsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        const vd qinv = 1.0 / vmax(P.qnorm, splat(kQuatNormEps));
        for (int i = 0; i < 4; ++i) P.qn[i] = q[i] * qinv;
        quat_to_rotmat(P.qn, P.R);

        for (int i = 0; i < 3; ++i) {
            const vd ls = in.log_scale[i];
            P.s_active[i] = (ls >= double(AH_LOG_SCALE_MIN)) & (ls <= double(AH_LOG_SCALE_MAX));
            P.s[i] = vexp(vclamp(ls, AH_LOG_SCALE_MIN, AH_LOG_SCALE_MAX));
        }
        vd M[9];  // R diag(s)
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) M[3 * i + j] = P.R[3 * i + j] * P.s[j];

        for (int i = 0; i < 3; ++i)
            P.tc[i] = cam.V[3 * i] * in.mean[0] + cam.V[3 * i + 1] * in.mean[1] +
                      cam.V[3 * i + 2] * in.mean[2] + cam.t[i];
        const vd tz = P.tc[2];
        P.visible = (tz > cam.near_plane) & (tz < cam.far_plane);
        P.mean2d[0] = cam.fx * P.tc[0] / tz + cam.cx;
        P.mean2d[1] = cam.fy * P.tc[1] / tz + cam.cy;

        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                P.VM[3 * i + j] =
                    cam.V[3 * i] * M[j] + cam.V[3 * i + 1] * M[3 + j] + cam.V[3 * i + 2] * M[6 + j];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                P.Sc[3 * i + j] = P.VM[3 * i] * P.VM[3 * j] + P.VM[3 * i + 1] * P.VM[3 * j + 1] +
                                  P.VM[3 * i + 2] * P.VM[3 * j + 2];

        const vd rx = P.tc[0] / tz, ry = P.tc[1] / tz;
        P.rx_ratio = vclamp(rx, -cam.lim_x_neg, cam.lim_x_pos);
        P.ry_ratio = vclamp(ry, -cam.lim_y_neg, cam.lim_y_pos);
        P.x_free = (rx >= -cam.lim_x_neg) & (rx <= cam.lim_x_pos);
        P.y_free = (ry >= -cam.lim_y_neg) & (ry <= cam.lim_y_pos);
        const vd tx = tz * P.rx_ratio, ty = tz * P.ry_ratio, tz2 = tz * tz;
        vd* J = P.J;
        J[0] = cam.fx / tz;
        J[1] = splat(0.0);
        J[2] = -cam.fx * tx / tz2;
        J[3] = splat(0.0);
        J[4] = cam.fy / tz;
        J[5] = -cam.fy * ty / tz2;

        // cov = J Sc J^T, J is 2x3.
        vd JS[6];
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 3; ++j)
                JS[3 * i + j] =
                    J[3 * i] * P.Sc[j] + J[3 * i + 1] * P.Sc[3 + j] + J[3 * i + 2] * P.Sc[6 + j];
        P.cov[0] = JS[0] * J[0] + JS[1] * J[1] + JS[2] * J[2];
        P.cov[1] = JS[0] * J[3] + JS[1] * J[4] + JS[2] * J[5];
        P.cov[2] = JS[3] * J[3] + JS[4] * J[4] + JS[5] * J[5];
        P.det_orig = P.cov[0] * P.cov[2] - P.cov[1] * P.cov[1];
        P.covd[0] = P.cov[0] + cam.eps2d;
        P.covd[1] = P.cov[1];
        P.covd[2] = P.cov[2] + cam.eps2d;
        P.det = P.covd[0] * P.covd[2] - P.covd[1] * P.covd[1];
        P.visible &= P.det > kDetMin;
        P.conic[0] = P.covd[2] / P.det;
        P.conic[1] = -P.covd[1] / P.det;
        P.conic[2] = P.covd[0] / P.det;
        for (int k = 0; k < 3; ++k) P.visible &= vabs(P.conic[k]) < 1e30;

        P.comp = cam.antialiased ? vsqrt(vmax(splat(0.0), P.det_orig / P.det)) : splat(1.0);
        P.sig = sigmoid(in.logit);
        P.opacity = P.sig * P.comp;
        P.visible &= P.opacity >= double(kAlphaMin);  // else alpha can never reach 1/255
        return P;
    }

    // Gradients of the projected quantities (from the rasteriser).
    struct Grad {
        vd mean2d[2];
        vd conic[3];  // d/da, d/db, d/dc of conic [[a,b],[b,c]] (b counted once)
        vd opacity;
        vd depth;
    };

    struct InGrad {
        vd mean[3], log_scale[3], quat[4], logit;
    };

    // Vector-Jacobian product of project().
    static InGrad vjp(const Camera& cam, const Proj& P, const Grad& g) {
        InGrad d;
        // opacity = sig * comp
        d.logit = g.opacity * P.comp * P.sig * (1.0 - P.sig);

        // conic = inverse(covd): dL/dcovd = -C G C with G the symmetric gradient of C.
        const vd ca = P.conic[0], cb = P.conic[1], cc = P.conic[2];
        const vd ga = g.conic[0], gb = 0.5 * g.conic[1], gc = g.conic[2];
        const vd CG00 = ca * ga + cb * gb, CG01 = ca * gb + cb * gc;
        const vd CG10 = cb * ga + cc * gb, CG11 = cb * gb + cc * gc;
        vd dcov[4] = {-(CG00 * ca + CG01 * cb), -(CG00 * cb + CG01 * cc), -(CG10 * ca + CG11 * cb),
                      -(CG10 * cb + CG11 * cc)};

        if (cam.antialiased) {
            // comp = sqrt(det_orig / det); d det(A)/dA = adj(A)^T. No gradient where comp = 0.
            const vd dr = P.comp > 0.0 ? g.opacity * P.sig * 0.5 / P.comp : splat(0.0);
            const vd inv_det = 1.0 / P.det, ratio = P.det_orig * inv_det * inv_det;
            dcov[0] += dr * (P.cov[2] * inv_det - ratio * P.covd[2]);
            dcov[3] += dr * (P.cov[0] * inv_det - ratio * P.covd[0]);
            dcov[1] += dr * (-P.cov[1] * inv_det + ratio * P.covd[1]);
            dcov[2] += dr * (-P.cov[1] * inv_det + ratio * P.covd[1]);
        }

        const vd tz = P.tc[2], tz2 = tz * tz, tz3 = tz2 * tz;
        vd dt[3] = {splat(0.0), splat(0.0), g.depth};
        // mean2d = (fx tx / tz + cx, fy ty / tz + cy)
        dt[0] += cam.fx / tz * g.mean2d[0];
        dt[1] += cam.fy / tz * g.mean2d[1];
        dt[2] += -cam.fx * P.tc[0] / tz2 * g.mean2d[0] - cam.fy * P.tc[1] / tz2 * g.mean2d[1];

        // cov = J Sc J^T: dSc = J^T dcov J, dJ = dcov J Sc^T + dcov^T J Sc.
        const vd* J = P.J;
        vd JSc[6];
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 3; ++j)
                JSc[3 * i + j] =
                    J[3 * i] * P.Sc[j] + J[3 * i + 1] * P.Sc[3 + j] + J[3 * i + 2] * P.Sc[6 + j];
        vd dJ[6];
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 3; ++j)
                dJ[3 * i + j] =
                    (dcov[2 * i] + dcov[i]) * JSc[j] + (dcov[2 * i + 1] + dcov[2 + i]) * JSc[3 + j];
        vd dSc[9];
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b)
                dSc[3 * a + b] = J[a] * (dcov[0] * J[b] + dcov[1] * J[3 + b]) +
                                 J[3 + a] * (dcov[2] * J[b] + dcov[3] * J[3 + b]);

        // J = [[fx/tz, 0, -fx tx'/tz^2], [0, fy/tz, -fy ty'/tz^2]], tx' = tz clamp(tx/tz).
        const vd txp = tz * P.rx_ratio, typ = tz * P.ry_ratio;
        dt[2] += -cam.fx / tz2 * dJ[0] - cam.fy / tz2 * dJ[4] + 2.0 * cam.fx * txp / tz3 * dJ[2] +
                 2.0 * cam.fy * typ / tz3 * dJ[5];
        const vd dtxp = -cam.fx / tz2 * dJ[2], dtyp = -cam.fy / tz2 * dJ[5];
        dt[0] += P.x_free ? dtxp : splat(0.0);
        dt[2] += P.x_free ? splat(0.0) : P.rx_ratio * dtxp;
        dt[1] += P.y_free ? dtyp : splat(0.0);
        dt[2] += P.y_free ? splat(0.0) : P.ry_ratio * dtyp;

        // tc = V mean + t
        for (int j = 0; j < 3; ++j)
            d.mean[j] = cam.V[j] * dt[0] + cam.V[3 + j] * dt[1] + cam.V[6 + j] * dt[2];

        // Sc = VM VM^T -> dVM = (dSc + dSc^T) VM; VM = V M -> dM = V^T dVM.
        vd tmp[9], dVM[9], dM[9];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) tmp[3 * i + j] = dSc[3 * i + j] + dSc[3 * j + i];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                dVM[3 * i + j] = tmp[3 * i] * P.VM[j] + tmp[3 * i + 1] * P.VM[3 + j] +
                                 tmp[3 * i + 2] * P.VM[6 + j];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                dM[3 * i + j] =
                    cam.V[i] * dVM[j] + cam.V[3 + i] * dVM[3 + j] + cam.V[6 + i] * dVM[6 + j];

        // M = R diag(s)
        vd dR[9];
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) dR[3 * i + j] = dM[3 * i + j] * P.s[j];
        for (int j = 0; j < 3; ++j) {
            const vd ds = P.R[j] * dM[j] + P.R[3 + j] * dM[3 + j] + P.R[6 + j] * dM[6 + j];
            d.log_scale[j] = P.s_active[j] ? ds * P.s[j] : splat(0.0);
        }

        const vd w = P.qn[0], x = P.qn[1], y = P.qn[2], z = P.qn[3];
        vd dqn[4];
        dqn[0] = 2.0 * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
        dqn[1] = 2.0 * (y * dR[1] + z * dR[2] + y * dR[3] - 2.0 * x * dR[4] - w * dR[5] +
                        z * dR[6] + w * dR[7] - 2.0 * x * dR[8]);
        dqn[2] = 2.0 * (-2.0 * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] -
                        w * dR[6] + z * dR[7] - 2.0 * y * dR[8]);
        dqn[3] = 2.0 * (-2.0 * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - 2.0 * z * dR[4] +
                        y * dR[5] + x * dR[6] + y * dR[7]);
        // qn = q / max(|q|, eps)
        const vm normed = P.qnorm > kQuatNormEps;
        const vd dot = w * dqn[0] + x * dqn[1] + y * dqn[2] + z * dqn[3];
        for (int i = 0; i < 4; ++i)
            d.quat[i] = normed ? (dqn[i] - P.qn[i] * dot) / P.qnorm : dqn[i] / kQuatNormEps;
        return d;
    }

    // Screen footprint of L projected Gaussians, in pixels: the opacity-aware box, drawn (a
    // visible Gaussian whose box holds a pixel centre), and the Span of each.
    struct Footprint {
        vd radius[2];
        vd box[4];  // inclusive pixel ranges x0, x1, y0, y1 (whole numbers)
        vm drawn;
        vd span[4];      // Span: slope, g, inv_ca, q
        vm ca_positive;  // the conic's first entry is positive (else the box's span)
    };

    static Footprint footprint(const Camera& cam, const Proj& P) {
        Footprint F;
        // opacity exp(-q/2) >= 1/255  <=>  q <= q_max = 2 ln(255 opacity); the tight
        // axis-aligned box of that ellipse has half-widths sqrt(q_max covd_xx), sqrt(q_max
        // covd_yy). The small margin keeps samples that pass the float32 threshold test
        // inside the box. Pixel i has its centre at i + 0.5: i in [ceil(m - r - 0.5),
        // floor(m + r - 0.5)].
        const vd q_max = 2.0 * vlog(255.0 * P.opacity) + 1e-3;
        const vd k = vsqrt(q_max);
        const double size[2] = {double(cam.width), double(cam.height)};
        for (int a = 0; a < 2; ++a) {
            const vd m = P.mean2d[a];
            F.radius[a] = k * vsqrt(P.covd[2 * a]);
            F.box[2 * a] = vmax(vceil(vclamp(m - F.radius[a] - 0.5, -1.0, size[a])), splat(0.0));
            F.box[2 * a + 1] =
                vmin(vfloor(vclamp(m + F.radius[a] - 0.5, -1.0, size[a])), splat(size[a] - 1));
        }
        F.drawn = P.visible & (F.box[0] <= F.box[1]) & (F.box[2] <= F.box[3]);

        // Span (raster.hpp), from the conic as the tiles read it (float32). The largest |dx|,
        // |dy| at any lane a step evaluates: its rows are the box's, its columns at most a
        // tile past the box's.
        const vd ca = f32(P.conic[0]), cb = f32(P.conic[1]), cc = f32(P.conic[2]);
        const vd x = P.mean2d[0], y = P.mean2d[1];
        const vd X =
            vmax(vabs(x - (F.box[0] - kMaxTile + 0.5)), vabs(x - (F.box[1] + kMaxTile + 0.5)));
        const vd Y = vmax(vabs(y - (F.box[2] + 0.5)), vabs(y - (F.box[3] + 0.5)));
        const vd terms = ca * X * X + 2.0 * vabs(cb) * X * Y + cc * Y * Y;
        const vd inv_ca = 1.0 / ca, slope = cb * inv_ca;
        F.span[0] = slope;
        F.span[1] = cc - cb * slope;
        F.span[2] = inv_ca;
        F.span[3] = f32(q_max) + 1e-5 * terms;
        F.ca_positive = ca > 0.0;
        return F;
    }

    // Lane l of F's span; the box's where `ellipse` is off, the conic's first entry is not positive
    // or a coefficient is not finite.
    static Span span_at(const Footprint& F, int l, bool ellipse) {
        const Span s{float(F.span[0][l]), float(F.span[1][l]), float(F.span[2][l]),
                     float(F.span[3][l])};
        const bool finite = std::isfinite(s.slope) && std::isfinite(s.g) &&
                            std::isfinite(s.inv_ca) && std::isfinite(s.q);
        if (ellipse && F.ca_positive[l] && finite) return s;
        return Span{0.0f, 0.0f, 1.0f, std::numeric_limits<float>::infinity()};
    }

    // Projects Gaussians [i0, i1) into out (ProjectOut; culled Gaussians leave
    // ah_splat_project's arrays as they are).
    static void project_range(const Camera& cam, const Gaussians& g, int64_t i0, int64_t i1,
                              const ProjectOut& out) {
        for (int64_t b = i0; b < i1; b += L) {
            int32_t ids[L];
            const int count = int(std::min<int64_t>(L, i1 - b));
            for (int l = 0; l < count; ++l) ids[l] = int32_t(b + l);
            for (int l = count; l < L; ++l) ids[l] = int32_t(b + count - 1);
            const Proj P = project(cam, gather(g, ids));
            const Footprint F = footprint(cam, P);
            for (int l = 0; l < count; ++l) {
                const int64_t i = b + l;
                const bool drawn = F.drawn[l] != 0;
                if (out.visible) out.visible[i] = drawn;
                if (!drawn) continue;
                int32_t box[4];
                for (int k = 0; k < 4; ++k) box[k] = int32_t(F.box[k][l]);
                if (out.splats) {
                    Splat2D& s = out.splats[i];
                    s.x = P.mean2d[0][l];
                    s.y = P.mean2d[1][l];
                    s.ca = float(P.conic[0][l]);
                    s.cb = float(P.conic[1][l]);
                    s.cc = float(P.conic[2][l]);
                    s.op = float(P.opacity[l]);
                    s.r = out.colors[3 * i];
                    s.g = out.colors[3 * i + 1];
                    s.b = out.colors[3 * i + 2];
                    s.z = float(P.tc[2][l]);
                    s.span = span_at(F, l, out.ellipse);
                    std::copy_n(box, 4, s.bbox);
                    std::copy_n(box, 4, out.bbox + 4 * i);
                    out.depth64[i] = P.tc[2][l];
                }
                if (out.mean2d) {
                    out.mean2d[2 * i] = P.mean2d[0][l];
                    out.mean2d[2 * i + 1] = P.mean2d[1][l];
                    for (int k = 0; k < 3; ++k) out.conic[3 * i + k] = float(P.conic[k][l]);
                    out.opacity[i] = float(P.opacity[l]);
                    out.depth[i] = float(P.tc[2][l]);
                    for (int k = 0; k < 2; ++k)
                        out.radii[2 * i + k] = int32_t(std::ceil(F.radius[k][l]));
                }
            }
        }
    }

    // Input gradients of the visible Gaussians ids[k0 .. k1), given acc (kEntryGrad summed
    // rasteriser gradients per k, in entry order, from k0's on); colours are the caller's.
    static void vjp_range(const Camera& cam, const Gaussians& g, const int32_t* ids,
                          const double* acc, int64_t k0, int64_t k1, const GradOut& out) {
        for (int64_t b = k0; b < k1; b += L) {
            int32_t lane_ids[L];
            int64_t ks[L];
            const int count = int(std::min<int64_t>(L, k1 - b));
            for (int l = 0; l < L; ++l) {
                ks[l] = b + std::min(l, count - 1);
                lane_ids[l] = ids[ks[l]];
            }
            Grad gr;
            for (int l = 0; l < L; ++l) {
                const double* a = acc + (ks[l] - k0) * kEntryGrad;
                gr.mean2d[0][l] = a[0];
                gr.mean2d[1][l] = a[1];
                for (int c = 0; c < 3; ++c) gr.conic[c][l] = a[2 + c];
                gr.opacity[l] = a[5];
                gr.depth[l] = a[9];
            }
            const InGrad d = vjp(cam, project(cam, gather(g, lane_ids)), gr);
            for (int l = 0; l < count; ++l) {
                const int64_t i = lane_ids[l];
                for (int c = 0; c < 3; ++c) {
                    out.d_means[3 * i + c] = saturate(d.mean[c][l]);
                    out.d_log_scales[3 * i + c] = saturate(d.log_scale[c][l]);
                }
                for (int c = 0; c < 4; ++c) out.d_quats[4 * i + c] = saturate(d.quat[c][l]);
                out.d_logits[i] = saturate(d.logit[l]);
            }
        }
    }
};
