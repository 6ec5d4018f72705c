#pragma once
// The scanner's scale, fitted beside the scan's rigid pose (issue 25, item 1). A structured-light or
// stereo sensor out of calibration by a fraction of a percent scales its scan about its optical centre:
// a rigid fit on one fiducial then lands it right, while the part and the other fiducials, 100-200 mm
// away, are off by scale x distance, and the fit on two fiducials turns by about the scale in radians
// (world 2: 0.12 % turned two-fiducial fits by 0.06-0.14 deg). Fiducials spread about the part measure
// the scale through their distances, which a probe fixed: a similarity fit of the scan onto them
// (point-to-plane, seven parameters) recovers it.
//
// Ours: Open3D's TransformationEstimationPointToPoint has with_scaling, its point-to-plane estimation has
// none, and a point-to-point fit of scan points onto a fiducial's samples is biased by the sampling.
#include <Eigen/Geometry>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct ScaleFitSettings {
    int max_iterations = 20;
    /// Stop when the step is smaller: rotation (radians) + translation and scale's move at the target
    /// (both over the target's distance from the centre of scale).
    double min_step = 1e-7;
};

/// A scan's pose and scale: machine point = T_machine_scan * (centre + scale (p - centre)) for a scan point
/// p. Any centre gives the same similarities; one amid the points keeps T_machine_scan the rigid map that
/// places them, as a fit without the scale would, and the scale nearly independent of it.
struct ScaleFit {
    bool valid = false;
    double scale = 1.0;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< the centre of scale, scan frame
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    /// Sum of J J^T over the inliers, J = [p x n, n, n . (p - T centre)] in the machine frame (twist [w, v],
    /// then the scale); divide by the noise variance for the information.
    Eigen::Matrix<double, 7, 7> JtJ = Eigen::Matrix<double, 7, 7>::Zero();
    /// The pose's information where the scale is unknown: JtJ's rigid block with the scale marginalised
    /// out (its Schur complement).
    Matrix6d JtJ_pose = Matrix6d::Zero();
    /// 1 sigma of `scale` per unit of noise: sqrt of (JtJ^-1)'s scale entry.
    double scale_sigma_per_noise = 0.0;
    double rmse = 0.0;
    std::size_t inliers = 0;
};

/// Fits scale and pose of `source` (scan points, with their normals of either sign, or none) onto `target`
/// (machine frame) from T_machine_scan `init` at scale 1, with correspondences within `max_distance`
/// (Tukey-weighted) whose normals agree as in the rigid fit (IcpSettings::max_normal_angle_deg), the scale
/// about `centre` (scan frame).
ScaleFit fit_scale(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>* normals,
                   const Surface& target, const Eigen::Isometry3d& init, const Eigen::Vector3d& centre,
                   double max_distance, const ScaleFitSettings& settings = {});

}  // namespace partloc
