// EWA projection of 3D Gaussians (forward and its exact vector-Jacobian product).
// Everything per Gaussian runs in double: it is cheap (N, not pixels) and keeps extreme
// scales (1e-10 .. 1e5 m) and ratios finite; the rasteriser gets float32 results.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "splat.h"

namespace ah {

constexpr float kAlphaMin = 1.0f / 255.0f;  // samples below this are skipped
constexpr float kAlphaMax = 0.99f;          // alpha clamp
constexpr float kTransmittanceMin = 1e-4f;  // a pixel stops once T would fall below this
constexpr double kQuatNormEps = 1e-12;      // |q| guard, as F.normalize
constexpr double kDetMin = 1e-10;           // dilated 2D covariance determinant guard

struct Camera {
    double V[9], t[3];  // world-to-camera linear part and translation
    double fx, fy, cx, cy;
    int width, height;
    double near_plane, far_plane, eps2d;
    bool antialiased;
    // Camera-space x/z and y/z are clamped to the view frustum plus 30% when building the
    // EWA Jacobian (as 3DGS / gsplat), so off-screen Gaussians do not explode.
    double lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;

    explicit Camera(const ah_splat_params& p) {
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) V[3 * i + j] = p.viewmat[4 * i + j];
            t[i] = p.viewmat[4 * i + 3];
        }
        fx = p.K[0];
        fy = p.K[4];
        cx = p.K[2];
        cy = p.K[5];
        width = p.width;
        height = p.height;
        near_plane = p.near_plane;
        far_plane = p.far_plane;
        eps2d = p.eps2d;
        antialiased = p.antialiased != 0;
        const double tan_fovx = 0.5 * width / fx, tan_fovy = 0.5 * height / fy;
        lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx;
        lim_x_neg = cx / fx + 0.3 * tan_fovx;
        lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy;
        lim_y_neg = cy / fy + 0.3 * tan_fovy;
    }
};

// All intermediates of one Gaussian's projection; the backward pass recomputes them.
struct Projection {
    bool visible;
    double qn[4], qnorm;
    double s[3];
    bool s_active[3];   // log-scale inside the clamp range (gradient passes)
    double R[9], M[9];  // M = R diag(s), Sigma = M M^T
    double tc[3];
    double VM[9];               // V M
    double Sc[9];               // camera-space covariance V Sigma V^T = VM VM^T
    double rx_ratio, ry_ratio;  // clamped x/z and y/z used in J
    bool x_free, y_free;        // clamp inactive
    double J[6];
    double cov[3];   // 2D covariance a, b, c before dilation
    double covd[3];  // after dilation
    double det_orig, det;
    double conic[3];
    double comp;  // sqrt(det_orig / det), 1 when not antialiased
    double sig;   // sigmoid(logit)
    double opacity;
    double mean2d[2];
};

// Screen footprint of a projected Gaussian, in pixels.
struct Bounds {
    double radius[2];
    int32_t bbox[4];  // inclusive pixel ranges x0, x1, y0, y1
};

inline double sigmoid(double x) {
    if (x >= 0) return 1.0 / (1.0 + std::exp(-x));
    const double e = std::exp(x);
    return e / (1.0 + e);
}

inline void quat_to_rotmat(const double* q, double* R) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z);
    R[1] = 2 * (x * y - w * z);
    R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);
    R[4] = 1 - 2 * (x * x + z * z);
    R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);
    R[7] = 2 * (y * z + w * x);
    R[8] = 1 - 2 * (x * x + y * y);
}

// C = A B (3x3) and C = A B^T (3x3).
inline void mat3_mul(const double* A, const double* B, double* C) {
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[3 * i + j] = A[3 * i] * B[j] + A[3 * i + 1] * B[3 + j] + A[3 * i + 2] * B[6 + j];
}
inline void mat3_mul_bt(const double* A, const double* B, double* C) {
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[3 * i + j] =
                A[3 * i] * B[3 * j] + A[3 * i + 1] * B[3 * j + 1] + A[3 * i + 2] * B[3 * j + 2];
}
// C = A^T B (3x3).
inline void mat3_mul_at(const double* A, const double* B, double* C) {
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            C[3 * i + j] = A[i] * B[j] + A[3 + i] * B[3 + j] + A[6 + i] * B[6 + j];
}

// Culling (P.visible = false): outside (near, far) (which includes behind and at the camera
// centre), a degenerate dilated 2D covariance (determinant <= 1e-10, conic beyond 1e30, only
// possible with eps2d = 0), or opacity below 1/255. Later fields are unset then.
inline Projection project_gaussian(const Camera& cam, const float* mean, const float* log_scale,
                                   const float* quat, float opacity_logit) {
    Projection P;
    P.visible = false;

    const double q[4] = {quat[0], quat[1], quat[2], quat[3]};
    P.qnorm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    const double qinv = 1.0 / std::max(P.qnorm, kQuatNormEps);
    for (int i = 0; i < 4; ++i) P.qn[i] = q[i] * qinv;
    quat_to_rotmat(P.qn, P.R);

    for (int i = 0; i < 3; ++i) {
        const double ls = log_scale[i];
        P.s_active[i] = ls >= AH_LOG_SCALE_MIN && ls <= AH_LOG_SCALE_MAX;
        P.s[i] = std::exp(std::clamp(ls, double(AH_LOG_SCALE_MIN), double(AH_LOG_SCALE_MAX)));
    }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) P.M[3 * i + j] = P.R[3 * i + j] * P.s[j];

    const double m[3] = {mean[0], mean[1], mean[2]};
    for (int i = 0; i < 3; ++i)
        P.tc[i] =
            cam.V[3 * i] * m[0] + cam.V[3 * i + 1] * m[1] + cam.V[3 * i + 2] * m[2] + cam.t[i];
    const double tz = P.tc[2];
    if (!(tz > cam.near_plane && tz < cam.far_plane)) return P;
    P.mean2d[0] = cam.fx * P.tc[0] / tz + cam.cx;
    P.mean2d[1] = cam.fy * P.tc[1] / tz + cam.cy;

    mat3_mul(cam.V, P.M, P.VM);
    mat3_mul_bt(P.VM, P.VM, P.Sc);

    const double rx = P.tc[0] / tz, ry = P.tc[1] / tz;
    P.rx_ratio = std::clamp(rx, -cam.lim_x_neg, cam.lim_x_pos);
    P.ry_ratio = std::clamp(ry, -cam.lim_y_neg, cam.lim_y_pos);
    P.x_free = rx >= -cam.lim_x_neg && rx <= cam.lim_x_pos;
    P.y_free = ry >= -cam.lim_y_neg && ry <= cam.lim_y_pos;
    const double tx = tz * P.rx_ratio, ty = tz * P.ry_ratio, tz2 = tz * tz;
    double* J = P.J;
    J[0] = cam.fx / tz;
    J[1] = 0;
    J[2] = -cam.fx * tx / tz2;
    J[3] = 0;
    J[4] = cam.fy / tz;
    J[5] = -cam.fy * ty / tz2;

    // cov = J Sc J^T, J is 2x3.
    double JS[6];
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
    if (!(P.det > kDetMin)) return P;
    P.conic[0] = P.covd[2] / P.det;
    P.conic[1] = -P.covd[1] / P.det;
    P.conic[2] = P.covd[0] / P.det;
    if (!(std::fabs(P.conic[0]) < 1e30 && std::fabs(P.conic[1]) < 1e30 &&
          std::fabs(P.conic[2]) < 1e30))
        return P;

    P.comp = cam.antialiased ? std::sqrt(std::max(0.0, P.det_orig / P.det)) : 1.0;
    P.sig = sigmoid(opacity_logit);
    P.opacity = P.sig * P.comp;
    P.visible = P.opacity >= double(kAlphaMin);  // else alpha can never reach 1/255
    return P;
}

// Bounds of a visible Gaussian; false when its box misses every pixel centre.
inline bool screen_bounds(const Camera& cam, const Projection& P, Bounds& B) {
    // Opacity-aware extent: opacity * exp(-q/2) >= 1/255  <=>  q <= 2 ln(255 opacity); the
    // tight axis-aligned box of that ellipse has half-widths k sqrt(covd_xx), k sqrt(covd_yy).
    // The small margin keeps samples that pass the float32 threshold test inside the box.
    const double k = std::sqrt(2.0 * std::log(255.0 * P.opacity) + 1e-3);
    B.radius[0] = k * std::sqrt(P.covd[0]);
    B.radius[1] = k * std::sqrt(P.covd[2]);
    // Pixel i has its centre at i + 0.5: i in [ceil(m - r - 0.5), floor(m + r - 0.5)].
    const double lox = std::clamp(P.mean2d[0] - B.radius[0] - 0.5, -1.0, double(cam.width));
    const double hix = std::clamp(P.mean2d[0] + B.radius[0] - 0.5, -1.0, double(cam.width));
    const double loy = std::clamp(P.mean2d[1] - B.radius[1] - 0.5, -1.0, double(cam.height));
    const double hiy = std::clamp(P.mean2d[1] + B.radius[1] - 0.5, -1.0, double(cam.height));
    B.bbox[0] = std::max(0, int32_t(std::ceil(lox)));
    B.bbox[1] = std::min(cam.width - 1, int32_t(std::floor(hix)));
    B.bbox[2] = std::max(0, int32_t(std::ceil(loy)));
    B.bbox[3] = std::min(cam.height - 1, int32_t(std::floor(hiy)));
    return B.bbox[0] <= B.bbox[1] && B.bbox[2] <= B.bbox[3];
}

// Gradients of the projected quantities of one Gaussian (from the rasteriser).
struct ProjectionGrad {
    double mean2d[2];
    double conic[3];  // d/da, d/db, d/dc of conic [[a,b],[b,c]] (b counted once)
    double opacity;
    double depth;
};

// Vector-Jacobian product of project_gaussian: writes d mean (3), d log_scale (3),
// d quat (4), d opacity_logit (1).
inline void project_gaussian_vjp(const Camera& cam, const Projection& P, const ProjectionGrad& g,
                                 double* d_mean, double* d_log_scale, double* d_quat,
                                 double* d_logit) {
    // opacity = sig * comp
    *d_logit = g.opacity * P.comp * P.sig * (1.0 - P.sig);

    // conic = inverse(covd): dL/dcovd = -C G C with G the symmetric gradient of C.
    const double ca = P.conic[0], cb = P.conic[1], cc = P.conic[2];
    const double ga = g.conic[0], gb = 0.5 * g.conic[1], gc = g.conic[2];
    // (C G) then (C G C), all symmetric 2x2 stored as full.
    const double CG00 = ca * ga + cb * gb, CG01 = ca * gb + cb * gc;
    const double CG10 = cb * ga + cc * gb, CG11 = cb * gb + cc * gc;
    double dcov00 = -(CG00 * ca + CG01 * cb);
    double dcov01 = -(CG00 * cb + CG01 * cc);
    double dcov10 = -(CG10 * ca + CG11 * cb);
    double dcov11 = -(CG10 * cb + CG11 * cc);

    if (cam.antialiased && P.comp > 0) {
        // comp = sqrt(det_orig / det); d det(A)/dA = adj(A)^T.
        const double d_comp = g.opacity * P.sig;
        const double dr = d_comp * 0.5 / P.comp;
        const double inv_det = 1.0 / P.det, ratio = P.det_orig * inv_det * inv_det;
        dcov00 += dr * (P.cov[2] * inv_det - ratio * P.covd[2]);
        dcov11 += dr * (P.cov[0] * inv_det - ratio * P.covd[0]);
        dcov01 += dr * (-P.cov[1] * inv_det + ratio * P.covd[1]);
        dcov10 += dr * (-P.cov[1] * inv_det + ratio * P.covd[1]);
    }
    const double dcov[4] = {dcov00, dcov01, dcov10, dcov11};

    const double tz = P.tc[2], tz2 = tz * tz, tz3 = tz2 * tz;
    double dt[3] = {0, 0, g.depth};
    // mean2d = (fx tx / tz + cx, fy ty / tz + cy)
    dt[0] += cam.fx / tz * g.mean2d[0];
    dt[1] += cam.fy / tz * g.mean2d[1];
    dt[2] += -cam.fx * P.tc[0] / tz2 * g.mean2d[0] - cam.fy * P.tc[1] / tz2 * g.mean2d[1];

    // cov = J Sc J^T: dSc = J^T dcov J, dJ = dcov J Sc^T + dcov^T J Sc.
    const double* J = P.J;
    double JSc[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            JSc[3 * i + j] =
                J[3 * i] * P.Sc[j] + J[3 * i + 1] * P.Sc[3 + j] + J[3 * i + 2] * P.Sc[6 + j];
    double dJ[6];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            dJ[3 * i + j] =
                (dcov[2 * i] + dcov[i]) * JSc[j] + (dcov[2 * i + 1] + dcov[2 + i]) * JSc[3 + j];
    double dSc[9];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            dSc[3 * a + b] = J[a] * (dcov[0] * J[b] + dcov[1] * J[3 + b]) +
                             J[3 + a] * (dcov[2] * J[b] + dcov[3] * J[3 + b]);

    // J = [[fx/tz, 0, -fx tx'/tz^2], [0, fy/tz, -fy ty'/tz^2]], tx' = tz clamp(tx/tz).
    const double txp = tz * P.rx_ratio, typ = tz * P.ry_ratio;
    dt[2] += -cam.fx / tz2 * dJ[0] - cam.fy / tz2 * dJ[4] + 2 * cam.fx * txp / tz3 * dJ[2] +
             2 * cam.fy * typ / tz3 * dJ[5];
    const double dtxp = -cam.fx / tz2 * dJ[2], dtyp = -cam.fy / tz2 * dJ[5];
    if (P.x_free)
        dt[0] += dtxp;
    else
        dt[2] += P.rx_ratio * dtxp;
    if (P.y_free)
        dt[1] += dtyp;
    else
        dt[2] += P.ry_ratio * dtyp;

    // tc = V mean + t
    for (int j = 0; j < 3; ++j)
        d_mean[j] = cam.V[j] * dt[0] + cam.V[3 + j] * dt[1] + cam.V[6 + j] * dt[2];

    // Sc = VM VM^T -> dVM = (dSc + dSc^T) VM; VM = V M -> dM = V^T dVM.
    double tmp[9], dVM[9], dM[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) tmp[3 * i + j] = dSc[3 * i + j] + dSc[3 * j + i];
    mat3_mul(tmp, P.VM, dVM);
    mat3_mul_at(cam.V, dVM, dM);

    // M = R diag(s)
    double dR[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) dR[3 * i + j] = dM[3 * i + j] * P.s[j];
    for (int j = 0; j < 3; ++j) {
        const double ds = P.R[j] * dM[j] + P.R[3 + j] * dM[3 + j] + P.R[6 + j] * dM[6 + j];
        d_log_scale[j] = P.s_active[j] ? ds * P.s[j] : 0.0;
    }

    const double w = P.qn[0], x = P.qn[1], y = P.qn[2], z = P.qn[3];
    double dqn[4];
    dqn[0] = 2 * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
    dqn[1] = 2 * (y * dR[1] + z * dR[2] + y * dR[3] - 2 * x * dR[4] - w * dR[5] + z * dR[6] +
                  w * dR[7] - 2 * x * dR[8]);
    dqn[2] = 2 * (-2 * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] +
                  z * dR[7] - 2 * y * dR[8]);
    dqn[3] = 2 * (-2 * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - 2 * z * dR[4] + y * dR[5] +
                  x * dR[6] + y * dR[7]);
    // qn = q / max(|q|, eps)
    if (P.qnorm > kQuatNormEps) {
        const double dot = w * dqn[0] + x * dqn[1] + y * dqn[2] + z * dqn[3];
        for (int i = 0; i < 4; ++i) d_quat[i] = (dqn[i] - P.qn[i] * dot) / P.qnorm;
    } else {
        for (int i = 0; i < 4; ++i) d_quat[i] = dqn[i] / kQuatNormEps;
    }
}

}  // namespace ah
