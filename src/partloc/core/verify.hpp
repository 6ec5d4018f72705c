#pragma once
// Verification of a fitted pose: the evidence that decides whether a fiducial really is where the fit put
// it. Overlap scores alone are fooled by planar clutter (a model face lying on the pallet fits perfectly),
// so three independent tests must agree:
//   coverage     - the model surface that faces the scanner must be observed;
//   violation    - the scanner must not have seen through the model's solid (points behind its faces);
//   conditioning - the observed faces must fix all six degrees of freedom (a plane fixes three).
#include <Eigen/Geometry>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct VerifySettings {
    double inlier_distance = 0.0;  ///< a scan point this close to the model surface is on it (job units)
    double cover_distance = 0.0;   ///< a model sample with a scan point this close is observed (job units)
    double facing_cos = 0.17;      ///< a model sample faces the scanner within 80 degrees of incidence
    double lateral_factor = 2.0;   ///< "behind a face" means within this many model spacings of its foot
};

struct Verification {
    std::size_t inliers = 0;   ///< scan points on the model surface
    std::size_t inside = 0;    ///< scan points inside the model's solid
    std::size_t visible = 0;   ///< model samples facing the scanner
    std::size_t covered = 0;   ///< of those, observed
    double rmse = 0.0;         ///< RMS point-to-plane distance of the inliers
    double coverage = 0.0;     ///< covered / visible
    double violation = 0.0;    ///< inside / (inside + inliers)
    double conditioning = 0.0; ///< smallest eigenvalue of the normalised information (see below)
    /// Sum of J J^T over inliers, J = [p x n; n] in the model frame, twist [w, v].
    Matrix6d JtJ = Matrix6d::Zero();
};

/// Evaluates the pose T_model_scan of `model` against scan points near it. `viewpoint_scan` is the scanner's
/// position in the scan frame (the origin for scanners that report in their own frame). Conditioning is the
/// smallest eigenvalue of (1/n) sum J J^T with J = [((p - c) x n) / (d/2); n], c and d the model's centre
/// and diameter: 1/3 for a perfect corner of three equal faces, 0 for a single plane.
Verification verify_pose(const std::vector<Eigen::Vector3d>& scan_points, const Surface& model,
                         const Eigen::Isometry3d& T_model_scan, const Eigen::Vector3d& viewpoint_scan,
                         const VerifySettings& settings);

}  // namespace partloc
