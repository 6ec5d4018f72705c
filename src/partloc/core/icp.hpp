#pragma once
// Fine least-squares fit (paper §3.4.1, "final fit"): point-to-plane ICP of scan points onto oriented model
// samples, with Tukey weights and a shrinking correspondence distance. Our own loop rather than
// open3d::pipelines::registration::RegistrationICP because the model's KD-tree is built once per job and
// reused for every scan and candidate (Open3D rebuilds the target tree on every call), and because the
// result needs the fit's information matrix in the model frame for the verification and the uncertainty.
#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct IcpSettings {
    std::vector<double> max_distances;  ///< correspondence distance per stage, decreasing (job units)
    int max_iterations = 30;            ///< per stage
    double min_step = 1e-5;  ///< stop a stage when the update is smaller (radians, job units/diameter)
    std::size_t min_correspondences = 12;
    /// With source normals: a sample is a correspondence only if its normal is within this angle of the
    /// point's. At an open surface's edge (a datum face meeting a face that is not a reference), points on
    /// the other face lie within the correspondence distance of the datum's plane and, all on one side of
    /// it, pull it over; their normals tell them apart.
    double max_normal_angle_deg = 30.0;
    /// Stages whose distance is at least this look the nearest sample up in the target's coarse map (when
    /// it has one, and the distance is within the map's reach): one sample per point, the one nearest the
    /// centre of the point's cell. For screening fits from poses degrees off, where any sample of the right
    /// face gives the right plane; the stages that decide a pose stay exact.
    double approximate_from = std::numeric_limits<double>::infinity();
};

struct IcpResult {
    Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
    bool converged = false;
    int iterations = 0;
    std::size_t inliers = 0;  ///< correspondences within the last stage's distance
    double rmse = 0.0;        ///< RMS point-to-plane residual of the inliers (job units)
    /// Sum of J J^T over the inliers, J = [p x n; n] in the target frame (twist order [w, v]).
    /// Divide by the noise variance for the information matrix of T_target_source.
    Matrix6d JtJ = Matrix6d::Zero();
};

/// Aligns source points (their own frame) onto `target` starting from init (T_target_source).
/// `source_normals`, when not null, holds the points' normals (unit, either sign) for the normal check.
IcpResult icp_point_to_plane(const std::vector<Eigen::Vector3d>& source, const Surface& target,
                             const Eigen::Isometry3d& init, const IcpSettings& settings,
                             const std::vector<Eigen::Vector3d>* source_normals = nullptr);

/// Of the samples idx[0..found) near p, the one whose tangent plane lies nearest p, and p's signed distance
/// from that plane in *r; -1 when none. At an edge the nearest sample may lie on the other face, whose plane
/// would pull a fit sideways. With `np` (p's own normal, either sign), samples whose normal is more than
/// acos(min_cos) from it are passed over.
inline int nearest_plane(const Surface& target, const Eigen::Vector3d& p, const Eigen::Vector3d* np,
                         double min_cos, const int* idx, int found, double* r) {
    int k = -1;
    for (int j = 0; j < found; ++j) {
        if (np && std::abs(np->dot(target.normals[idx[j]])) < min_cos) continue;
        const double rj = (p - target.points[idx[j]]).dot(target.normals[idx[j]]);
        if (k < 0 || std::abs(rj) < std::abs(*r)) {
            *r = rj;
            k = idx[j];
        }
    }
    return k;
}

/// Tukey's biweight of a residual r within the correspondence distance c.
inline double tukey_weight(double r, double c) {
    const double u = r / c;
    return (1 - u * u) * (1 - u * u);
}

/// S with S J = [(p - c) x n / L, n] for J = [p x n, n]: the Jacobian of the twist [L w, v] about c, in which
/// rotations and translations weigh alike in any units (S JtJ S^T is the system in that twist).
Matrix6d centred_scaled(const Eigen::Vector3d& c, double L);

/// The motion of the twist [L w, v] about c: q -> R(w) (q - c) + c + v.
Eigen::Isometry3d motion_about(const Vector6d& step, const Eigen::Vector3d& c, double L);

/// exp of a twist [w, v] as a rigid transform.
Eigen::Isometry3d twist_exp(const Vector6d& xi);

}  // namespace partloc
