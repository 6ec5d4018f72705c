#include "partloc/core/scale_fit.hpp"

#include <cmath>

#include "partloc/core/icp.hpp"

namespace partloc {

namespace {

using Matrix7d = Eigen::Matrix<double, 7, 7>;
using Vector7d = Eigen::Matrix<double, 7, 1>;

struct System {
    Matrix7d A = Matrix7d::Zero();  ///< J = [p x n, n, n . (p - T c)], machine frame
    Vector7d b = Vector7d::Zero();
    double r2 = 0.0;
    std::size_t n = 0;
};

// One Gauss-Newton system at pose T and scale s: residual r = (T (c + s (p - c)) - q) . n.
System accumulate(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>* normals,
                  const Surface& target, const Eigen::Isometry3d& T, double s, const Eigen::Vector3d& c,
                  double max_distance, bool weighted) {
    const double min_cos = std::cos(IcpSettings{}.max_normal_angle_deg * M_PI / 180.0);  // as the rigid fit
    const Eigen::Vector3d at = T * c;
    System sys;
    int idx[4];
    double d2[4];
    for (std::size_t i = 0; i < source.size(); ++i) {
        const Eigen::Vector3d p = T * (c + s * (source[i] - c));
        const int found = target.nearest(p, 4, max_distance, idx, d2);
        if (found < 1) continue;
        const Eigen::Vector3d np =
            normals ? Eigen::Vector3d(T.linear() * (*normals)[i]) : Eigen::Vector3d::Zero();
        double r = 0.0;
        const int k = nearest_plane(target, p, normals ? &np : nullptr, min_cos, idx, found, &r);
        if (k < 0) continue;
        const Eigen::Vector3d& n = target.normals[k];
        const double w = weighted ? tukey_weight(r, max_distance) : 1.0;
        Vector7d J;
        J << p.cross(n), n, n.dot(p - at);
        sys.A.noalias() += w * J * J.transpose();
        sys.b.noalias() -= w * r * J;
        sys.r2 += r * r;
        ++sys.n;
    }
    return sys;
}

}  // namespace

ScaleFit fit_scale(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>* normals,
                   const Surface& target, const Eigen::Isometry3d& init, const Eigen::Vector3d& centre,
                   double max_distance, const ScaleFitSettings& settings) {
    if (normals && normals->size() != source.size()) normals = nullptr;
    ScaleFit out;
    out.T_machine_scan = init;
    out.centre = centre;
    if (source.size() < 12 || target.points.empty() || !(max_distance > 0)) return out;
    Eigen::Isometry3d T = init;
    double s = 1.0;
    // Solved, as icp.cpp solves, about the target's centre with rotations scaled by its half-diameter; the
    // scale as the move it gives at the target's centre (D times it), so that all seven weigh alike in any
    // units.
    const double L = 0.5 * std::max(target.diameter, 1e-12);
    const double D = std::max((T * centre - target.center).norm(), L);
    Eigen::Matrix<double, 7, 7> S = Eigen::Matrix<double, 7, 7>::Identity();
    S.topLeftCorner<6, 6>() = centred_scaled(target.center, L);
    S(6, 6) = 1.0 / D;
    for (int it = 0; it < settings.max_iterations; ++it) {
        const System sys = accumulate(source, normals, target, T, s, centre, max_distance, true);
        if (sys.n < 12) return out;
        Eigen::Matrix<double, 7, 7> A = S * sys.A * S.transpose();
        A.diagonal().array() += 1e-9 * A.trace();
        const Vector7d step = A.ldlt().solve(S * sys.b);
        // The scale first (about the centre, where T puts it), then the rigid step: T (c + s (1 + d) (p -
        // c)).
        s *= 1.0 + step(6) / D;
        T = motion_about(step.head<6>(), target.center, L) * T;
        if (step.head<3>().norm() / L + step.segment<3>(3).norm() / D + std::abs(step(6)) / D <
            settings.min_step)
            break;
    }
    const System last = accumulate(source, normals, target, T, s, centre, max_distance, false);
    if (last.n < 12) return out;
    out.valid = true;
    out.scale = s;
    out.T_machine_scan = T;
    out.JtJ = last.A;
    out.inliers = last.n;
    out.rmse = std::sqrt(last.r2 / last.n);
    // The scale's variance: the same in any parametrisation of the rigid part, so read off the well
    // conditioned system (u = D d).
    const Eigen::Matrix<double, 7, 7> Ac = S * last.A * S.transpose();
    const Eigen::Matrix<double, 7, 7> cov = Ac.ldlt().solve(Eigen::Matrix<double, 7, 7>::Identity());
    out.scale_sigma_per_noise = cov(6, 6) > 0 ? std::sqrt(cov(6, 6)) / D : 0.0;
    // The pose's information with the scale unknown (its Schur complement); about a centre amid the points
    // the two are nearly independent.
    out.JtJ_pose = last.A.topLeftCorner<6, 6>();
    if (last.A(6, 6) > 0)
        out.JtJ_pose -=
            last.A.topRightCorner<6, 1>() * last.A.topRightCorner<6, 1>().transpose() / last.A(6, 6);
    return out;
}

}  // namespace partloc
