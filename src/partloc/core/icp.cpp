#include "partloc/core/icp.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <cmath>

namespace partloc {

Eigen::Isometry3d twist_exp(const Vector6d& xi) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d w = xi.head<3>();
    const double theta = w.norm();
    if (theta > 1e-12) T.linear() = Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
    T.translation() = xi.tail<3>();
    return T;
}

namespace {

struct Normal {
    Matrix6d A = Matrix6d::Zero();
    Vector6d b = Vector6d::Zero();
    double r2 = 0.0;
    std::size_t n = 0;
    Normal operator+(const Normal& o) const { return {A + o.A, b + o.b, r2 + o.r2, n + o.n}; }
};

// One Gauss-Newton system: residual r = (T p - q) . n, Tukey weight with scale c.
Normal accumulate(const std::vector<Eigen::Vector3d>& source, const Surface& target,
                  const Eigen::Isometry3d& T, double max_distance, bool weighted,
                  const std::vector<Eigen::Vector3d>* normals, double min_cos, bool approximate,
                  NearestCache& cache) {
    // Deterministic: the same chunks, summed in the same order, for any number of threads and any
    // scheduling (parallel_reduce's sums differed in their last bits from run to run of the same job, and
    // with them merged.ply and stock.stl; seed 106).
    Normal sum = tbb::parallel_deterministic_reduce(
        tbb::blocked_range<std::size_t>(0, source.size(), 512), Normal{},
        [&](const tbb::blocked_range<std::size_t>& range, Normal acc) {
            int idx[4];
            double d2[4];
            const double max_d2 = max_distance * max_distance;
            auto coarse_nearest = [&](const Eigen::Vector3d& p, int* i, double* q2) {
                i[0] = target.coarse->nearest(p);
                if (i[0] < 0) return 0;
                q2[0] = (p - target.points[i[0]]).squaredNorm();
                return q2[0] <= max_d2 ? 1 : 0;
            };
            for (std::size_t i = range.begin(); i != range.end(); ++i) {
                const Eigen::Vector3d p = T * source[i];
                // Of the nearest samples, the one whose tangent plane is nearest: at an edge the nearest
                // sample may lie on the other face, and its plane would pull the fit sideways.
                const int found =
                    approximate ? coarse_nearest(p, idx, d2) : cache.nearest(i, p, 4, max_distance, idx, d2);
                if (found < 1) continue;
                double r = 0.0;
                const Eigen::Vector3d np =
                    normals ? Eigen::Vector3d(T.linear() * (*normals)[i]) : Eigen::Vector3d::Zero();
                const int k = nearest_plane(target, p, normals ? &np : nullptr, min_cos, idx, found, &r);
                if (k < 0) continue;
                const Eigen::Vector3d& n = target.normals[k];
                const double w = weighted ? tukey_weight(r, max_distance) : 1.0;
                Vector6d J;
                J << p.cross(n), n;
                // The lower triangle of w J J^T only (mirrored once the sums are in), with the products
                // J_c (w J_r) that the full outer product formed: 21 of 36 products, and the same bits
                // where the solve reads them (LDLT reads the lower triangle).
                const Vector6d wJ = w * J;
                for (int c = 0; c < 6; ++c)
                    for (int r = c; r < 6; ++r) acc.A(r, c) += J(c) * wJ(r);
                acc.b.noalias() -= w * r * J;
                acc.r2 += r * r;
                ++acc.n;
            }
            return acc;
        },
        [](const Normal& a, const Normal& b) { return a + b; });
    sum.A.triangularView<Eigen::StrictlyUpper>() = sum.A.transpose();
    return sum;
}

}  // namespace

// S with S J = [(p - c) x n / L, n] for J = [p x n, n]: the Jacobian of the twist [L w, v] about c.
Matrix6d centred_scaled(const Eigen::Vector3d& c, double L) {
    Matrix6d S = Matrix6d::Identity();
    S.topLeftCorner<3, 3>() /= L;
    S.topRightCorner<3, 3>() = -skew(c) / L;
    return S;
}

// The motion of the twist [L w, v] about c: q -> R(w) (q - c) + c + v.
Eigen::Isometry3d motion_about(const Vector6d& step, const Eigen::Vector3d& c, double L) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d w = step.head<3>() / L;
    const double theta = w.norm();
    if (theta > 1e-15) X.linear() = Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
    X.translation() = c - X.linear() * c + step.tail<3>();
    return X;
}

IcpResult icp_point_to_plane(const std::vector<Eigen::Vector3d>& source, const Surface& target,
                             const Eigen::Isometry3d& init, const IcpSettings& settings,
                             const std::vector<Eigen::Vector3d>* source_normals) {
    if (source_normals && source_normals->size() != source.size()) source_normals = nullptr;
    const double min_cos = std::cos(settings.max_normal_angle_deg * M_PI / 180.0);
    IcpResult result;
    Eigen::Isometry3d T = init;
    const double scale = std::max(target.diameter, 1e-9);
    const double L = 0.5 * scale;
    bool all_converged = true;
    const auto approximate_at = [&](double max_distance) {
        return target.coarse && max_distance >= settings.approximate_from &&
               max_distance <= target.coarse->reach();
    };
    // The exact stages' searches, kept from iteration to iteration (exact; NearestCache), reaching a quarter
    // past the widest exact stage so that points beyond it are kept too.
    double reach = settings.max_distances.empty() ? 0.0 : settings.max_distances.back();
    for (double max_distance : settings.max_distances)
        if (!approximate_at(max_distance)) reach = std::max(reach, max_distance);
    NearestCache cache(target, source.size(), 1.25 * reach);
    for (double max_distance : settings.max_distances) {
        const bool approximate = approximate_at(max_distance);
        bool converged = false;
        for (int it = 0; it < settings.max_iterations; ++it) {
            const Normal sys = accumulate(source, target, T, max_distance, true, source_normals, min_cos,
                                          approximate, cache);
            ++result.iterations;
            if (sys.n < settings.min_correspondences) {
                result.T_target_source = T;
                result.converged = false;
                return result;
            }
            // The step is solved about the target's centre with rotations scaled by its half-diameter
            // (the twist [L w, v] of q -> R(w) (q - c) + c + v), so that the system's two blocks are alike
            // in size in any units and wherever the part sits. Levenberg-style damping, a fixed fraction of
            // that system's trace, keeps directions the data leave free (a plane seen alone) still. It was
            // 1e-9 of the trace of the system about the machine's origin: its rotation block grows with the
            // square of the coordinates, so in micrometres the damping outweighed the translations and the
            // fit stopped short of the optimum (issue 25: a world-2 cell registered 0 of 6 scans in um, 5 in
            // m).
            const Matrix6d S = centred_scaled(target.center, L);
            Matrix6d A = S * sys.A * S.transpose();
            A.diagonal().array() += 1e-9 * A.trace();
            const Vector6d step = A.ldlt().solve(S * sys.b);
            T = motion_about(step, target.center, L) * T;
            if (step.head<3>().norm() / L + step.tail<3>().norm() / scale < settings.min_step) {
                converged = true;
                break;
            }
        }
        all_converged = all_converged && converged;
    }
    const Normal last = accumulate(source, target, T, settings.max_distances.back(), false, source_normals,
                                   min_cos, false, cache);
    result.T_target_source = T;
    result.converged = all_converged;
    result.inliers = last.n;
    result.rmse = last.n ? std::sqrt(last.r2 / last.n) : 0.0;
    result.JtJ = last.A;
    return result;
}

}  // namespace partloc
