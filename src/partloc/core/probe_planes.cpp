#include "partloc/core/probe_planes.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <cmath>
#include <cstdio>

namespace partloc {

namespace {

std::string fmt(const char* f, double a, double b = 0, double c = 0) {
    char buf[256];
    std::snprintf(buf, sizeof buf, f, a, b, c);
    return buf;
}

/// Angle between two vectors in degrees, accurate also near 0 (acos is not).
double angle_deg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / M_PI;
}

/// Least-squares plane through the points; the reason is set when there is none.
PlaneFit fit_plane(const std::vector<Eigen::Vector3d>& pts, const ProbePlaneSettings& st,
                   std::string& reason) {
    PlaneFit f;
    f.points = pts.size();
    if (pts.size() < 3) {
        reason = "needs at least 3 points, found " + std::to_string(pts.size());
        return f;
    }
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (const auto& p : pts) c += p;
    c /= static_cast<double>(pts.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : pts) C += (p - c) * (p - c).transpose();
    C /= static_cast<double>(pts.size());
    for (std::size_t i = 0; i < pts.size(); ++i)
        for (std::size_t j = i + 1; j < pts.size(); ++j)
            f.extent = std::max(f.extent, (pts[i] - pts[j]).norm());
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    const Eigen::Vector3d lambda = es.eigenvalues().cwiseMax(0.0);  // ascending
    if (!(f.extent > 0)) {
        reason = "the points coincide";
        return f;
    }
    if (std::sqrt(lambda(1)) < st.min_width_fraction * std::sqrt(lambda(2))) {
        reason = "the points are (nearly) collinear: they do not fix a plane";
        return f;
    }
    f.normal = es.eigenvectors().col(0).normalized();
    f.offset = f.normal.dot(c);
    double sum2 = 0.0;
    for (const auto& p : pts) {
        const double d = std::abs(f.normal.dot(p) - f.offset);
        sum2 += d * d;
        f.max = std::max(f.max, d);
    }
    f.rms = std::sqrt(sum2 / static_cast<double>(pts.size()));
    if (f.rms > st.max_rms_fraction * f.extent)
        reason = fmt(
            "the points are not on one plane: RMS residual %.4g is more than %.3g %% of their extent %.4g "
            "(a point on another face?)",
            f.rms, 100.0 * st.max_rms_fraction, f.extent);
    return f;
}

}  // namespace

ProbedFrame frame_from_probe_planes(const std::array<std::vector<Eigen::Vector3d>, 3>& planes,
                                    const ProbePlaneSettings& st) {
    ProbedFrame out;
    for (int i = 0; i < 3; ++i) {
        std::string reason;
        out.planes[i] = fit_plane(planes[i], st, reason);
        if (!reason.empty()) {
            out.reason = reason;
            out.plane = i;
            return out;
        }
    }
    for (int i = 0; i < 3; ++i)
        for (int j = i + 1; j < 3; ++j) {
            const Eigen::Vector3d& a = out.planes[i].normal;
            const Eigen::Vector3d& b = out.planes[j].normal;
            const double angle = angle_deg(a, b.dot(a) < 0 ? -b : b);
            if (angle < st.min_angle_deg) {
                out.reason = fmt(
                    "planes %.0f and %.0f are near-parallel (%.3g degrees apart): they do not fix a corner",
                    i, j, angle);
                return out;
            }
        }
    // Each normal towards the other two planes' points: from the corner along the edges (see the header).
    for (int i = 0; i < 3; ++i) {
        PlaneFit& f = out.planes[i];
        std::size_t above = 0, below = 0;  // beyond the plane's own scatter
        const double tol = 3.0 * f.rms + 1e-9 * f.extent;
        for (int j = 0; j < 3; ++j) {
            if (j == i) continue;
            for (const auto& p : planes[j]) {
                const double side = f.normal.dot(p) - f.offset;
                above += side > tol;
                below += side < -tol;
            }
        }
        if (4 * std::min(above, below) > above + below || above + below == 0) {
            out.reason =
                "the other planes' points lie on both sides of this plane: not the faces of one corner";
            out.plane = i;
            return out;
        }
        if (below > above) {
            f.normal = -f.normal;
            f.offset = -f.offset;
        }
    }
    Eigen::Matrix3d N;
    for (int i = 0; i < 3; ++i) N.col(i) = out.planes[i].normal;
    if (N.determinant() <= 0) {
        out.reason =
            "the planes, in this order, make a left-handed frame: list them in the order of the model's x = "
            "0, "
            "y = 0, z = 0 faces";
        return out;
    }
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(N, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
    for (int i = 0; i < 3; ++i)
        out.nonorthogonality_deg =
            std::max(out.nonorthogonality_deg, angle_deg(R.col(i), out.planes[i].normal));
    if (out.nonorthogonality_deg > st.max_nonorthogonality_deg) {
        out.reason =
            fmt("the planes are %.3g degrees from mutually perpendicular (at most %.3g allowed): not the "
                "three faces of a datum corner",
                out.nonorthogonality_deg, st.max_nonorthogonality_deg);
        return out;
    }
    // The corner: least squares over the three planes n_i . x = d_i (with three, their intersection).
    Eigen::Matrix3d A;
    Eigen::Vector3d d;
    for (int i = 0; i < 3; ++i) {
        A.row(i) = out.planes[i].normal.transpose();
        d(i) = out.planes[i].offset;
    }
    out.T.linear() = R;
    out.T.translation() = A.colPivHouseholderQr().solve(d);
    out.valid = true;
    return out;
}

}  // namespace partloc
