#include "partloc/core/extent.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace partloc {

std::string rank_problem(const Extent& e, int min_rank) {
    if (e.rank >= min_rank) return "";
    if (e.points == 0) return "it has no points";
    if (e.rank == 0)
        return e.points == 1 ? "it has only one point"
                             : "all " + std::to_string(e.points) + " points are one and the same point";
    if (e.rank == 1) return "its points lie on one line";
    char thickness[96];
    std::snprintf(thickness, sizeof thickness, " (thickness %.3g against a size of %.3g)", e.thickness,
                  e.size);
    return std::string("its points lie in one plane") + thickness;
}

Extent extent_of(const std::vector<Eigen::Vector3d>& points, double relative_tolerance) {
    Extent e;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
    long double sum[3] = {0, 0, 0};
    for (const auto& p : points) {
        if (!p.allFinite()) continue;
        ++e.points;
        for (int k = 0; k < 3; ++k) sum[k] += p[k];
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
        e.max_abs = std::max(e.max_abs, p.cwiseAbs().maxCoeff());
    }
    if (e.points == 0) return e;
    for (int k = 0; k < 3; ++k) e.center[k] = static_cast<double>(sum[k] / e.points);
    // The box's diagonal overflows to inf for points near 1e308: long double holds it.
    long double d2 = 0;
    for (int k = 0; k < 3; ++k) d2 += static_cast<long double>(hi[k] - lo[k]) * (hi[k] - lo[k]);
    e.diagonal = static_cast<double>(std::sqrt(d2));
    // Covariance of points scaled by the box, so that neither huge nor tiny coordinates overflow or vanish.
    const double scale = (hi - lo).cwiseAbs().maxCoeff();
    if (!(scale > 0) || !std::isfinite(scale)) {
        e.rank = 0;
        return e;
    }
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : points) {
        if (!p.allFinite()) continue;
        const Eigen::Vector3d q = (p - e.center) / scale;
        C += q * q.transpose();
    }
    C /= static_cast<double>(e.points);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(C, Eigen::EigenvaluesOnly);
    const Eigen::Vector3d ev = solver.eigenvalues().cwiseMax(0.0);  // ascending
    e.size = std::sqrt(ev[2]) * scale;
    e.width = std::sqrt(ev[1]) * scale;
    e.thickness = std::sqrt(ev[0]) * scale;
    const double tol = relative_tolerance * std::sqrt(ev[2]);
    e.rank = std::sqrt(ev[2]) > 0 ? 1 + (std::sqrt(ev[1]) > tol) + (std::sqrt(ev[0]) > tol) : 0;
    return e;
}

std::size_t remove_far_points(std::vector<Eigen::Vector3d>& points, std::vector<Eigen::Vector3d>& normals,
                              double factor) {
    const std::size_t n = points.size();
    if (n < 10) return 0;
    Eigen::Vector3d median, lo, hi;
    std::vector<double> c(n);
    for (int k = 0; k < 3; ++k) {
        for (std::size_t i = 0; i < n; ++i) c[i] = points[i][k];
        const auto at = [&](double q) {
            const std::size_t i = std::min(n - 1, static_cast<std::size_t>(q * (n - 1)));
            std::nth_element(c.begin(), c.begin() + i, c.end());
            return c[i];
        };
        median[k] = at(0.5);
        lo[k] = at(0.01);
        hi[k] = at(0.99);
    }
    const double reach = factor * (hi - lo).norm();
    if (!(reach > 0) || !std::isfinite(reach) || !median.allFinite()) return 0;
    const auto far = [&](const Eigen::Vector3d& p) {
        // Each coordinate first: the norm of a difference near 1e308 overflows.
        return ((p - median).cwiseAbs().array() > reach).any() || (p - median).norm() > reach;
    };
    std::size_t count = 0;
    for (const auto& p : points) count += far(p);
    if (count == 0) return 0;
    const bool with_normals = normals.size() == n;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (far(points[i])) continue;
        points[kept] = points[i];
        if (with_normals) normals[kept] = normals[i];
        ++kept;
    }
    points.resize(kept);
    if (with_normals) normals.resize(kept);
    return count;
}

}  // namespace partloc
