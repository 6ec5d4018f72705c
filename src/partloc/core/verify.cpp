#include "partloc/core/verify.hpp"

#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>

#include <Eigen/Eigenvalues>
#include <cmath>

namespace partloc {

Verification verify_pose(const std::vector<Eigen::Vector3d>& scan_points, const Surface& model,
                         const Eigen::Isometry3d& T_model_scan, const Eigen::Vector3d& viewpoint_scan,
                         const VerifySettings& s) {
    Verification v;
    if (scan_points.empty() || model.points.empty()) return v;
    const double L = std::max(model.diameter / 2.0, 1e-12);
    const double lateral_max = s.lateral_factor * std::max(model.spacing, s.inlier_distance);

    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    cloud->points_.reserve(scan_points.size());
    for (const auto& p : scan_points) cloud->points_.push_back(T_model_scan * p);

    double r2 = 0.0;
    Matrix6d Jn = Matrix6d::Zero();
    for (const auto& p : cloud->points_) {
        double d2 = 0;
        const int k = model.nearest(p, &d2);
        if (k < 0) continue;
        const Eigen::Vector3d& n = model.normals[k];
        const Eigen::Vector3d d = p - model.points[k];
        const double along = d.dot(n);
        if (std::sqrt(d2) <= s.inlier_distance) {
            ++v.inliers;
            r2 += along * along;
            Vector6d J;
            J << p.cross(n), n;
            v.JtJ.noalias() += J * J.transpose();
            Vector6d Jc;
            Jc << (p - model.center).cross(n) / L, n;
            Jn.noalias() += Jc * Jc.transpose();
        } else if (along < -s.inlier_distance && along > -L &&
                   (d - along * n).norm() <= lateral_max) {
            ++v.inside;  // straight behind a model face: the scanner saw through solid material
        }
    }
    if (v.inliers) {
        v.rmse = std::sqrt(r2 / v.inliers);
        Eigen::SelfAdjointEigenSolver<Matrix6d> es(Jn / static_cast<double>(v.inliers));
        v.conditioning = std::max(0.0, es.eigenvalues()(0));
    }
    v.violation = static_cast<double>(v.inside) / std::max<std::size_t>(1, v.inside + v.inliers);

    open3d::geometry::KDTreeFlann tree(*cloud);
    const Eigen::Vector3d eye = T_model_scan * viewpoint_scan;
    std::vector<int> idx(1);
    std::vector<double> dd(1);
    const double c2 = s.cover_distance * s.cover_distance;
    for (std::size_t i = 0; i < model.points.size(); ++i) {
        const Eigen::Vector3d to_eye = eye - model.points[i];
        if (to_eye.dot(model.normals[i]) <= s.facing_cos * to_eye.norm()) continue;
        ++v.visible;
        if (tree.SearchKNN(model.points[i], 1, idx, dd) == 1 && dd[0] <= c2) ++v.covered;
    }
    v.coverage = v.visible ? static_cast<double>(v.covered) / v.visible : 0.0;
    return v;
}

}  // namespace partloc
