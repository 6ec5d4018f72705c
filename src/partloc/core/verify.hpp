#pragma once
// Verification of a pose: the evidence that decides whether a model really is where a fit put it. Overlap
// scores alone are fooled by planar clutter (a model face lying on the pallet fits perfectly) and by blocks
// of like shape, so the test follows the scanner's rays: seen from the scanner, every bit of model surface
// that faces it must either be observed (a return at the model's range), or be hidden by something well in
// front of it; a return from *behind* the model surface means the scanner saw through where the model
// claims solid material, and a return just in front of it means material where the model says there is
// air, next to the model: no correct pose allows either. On top, the points on the model must fix all six
// degrees of freedom (a plane fixes three).
#include <Eigen/Geometry>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct VerifySettings {
    double inlier_distance = 0.0;  ///< a scan point this close to the model surface is on it (job units)
    double bin_size = 0.0;         ///< ray bins, as a length at the model's distance (job units)
    double facing_cos = 0.26;      ///< model surface within 75 degrees of incidence counts as facing
    double near_fraction = 0.2;    ///< a return this close in front of the model (x diameter) crowds it
    /// A visible sample holds the fit's weakest direction when |J . weakest| is at least this share of the
    /// most a sample could give it (Verification::weakest_observed).
    double holding_share = 0.3;
};

struct Verification {
    std::size_t inliers = 0;       ///< scan points on the model surface
    std::size_t overflow = 0;      ///< scan points continuing a facing model face past the model's edge
    std::size_t observed = 0;      ///< ray bins of facing model surface with a return at the model's range
    std::size_t seen_through = 0;  ///< ... with a return from behind the model surface and none on it
    std::size_t crowded = 0;       ///< ... with a return just in front of it, where nothing can stand
    std::size_t occluded = 0;      ///< ... with a return well in front of it only
    std::size_t missing = 0;       ///< ... with no return at all
    double rmse = 0.0;             ///< RMS point-to-plane distance of the inliers
    double coverage = 0.0;         ///< observed / (observed + seen_through + crowded + missing)
    double violation = 0.0;        ///< (seen_through + crowded) / (observed + seen_through + crowded)
    double conditioning = 0.0;     ///< smallest eigenvalue of the normalised information (see below)
    /// Smallest eigenvalue of the inliers' mean n n^T: 0 for one plane or two (an edge), 1/3 for a corner of
    /// three equal faces. A model lying flush in a plane with a few stray points has little spread.
    double spread = 0.0;
    /// Sum of J J^T over inliers, J = [p x n; n] in the model frame, twist [w, v].
    Matrix6d JtJ = Matrix6d::Zero();
    /// The same over the inliers the scanner faces (within 75 degrees of incidence, facing_cos): a direction
    /// that only surfaces seen edge-on hold has next to none of JtJ here (least_share).
    Matrix6d JtJ_facing = Matrix6d::Zero();
    /// The direction the inliers hold least (issue 25, slid fits): the smallest eigenvector of the
    /// normalised information, as a twist [w d/2, v] about the model's centre.
    Vector6d weakest = Vector6d::Zero();
    /// Of the facing ray bins whose visible sample holds the weakest direction (|J . weakest| at least
    /// holding_share of its largest), how many are observed and how many contradicted (seen through or
    /// crowded): the faces that fix that direction seen where the pose puts them, or not.
    std::size_t weakest_observed = 0;
    std::size_t weakest_against = 0;
};

/// Evaluates the pose T_model_scan of `model` against scan points near it. `viewpoint_scan` is the scanner's
/// position in the scan frame. Conditioning is the smallest eigenvalue of (1/n) sum J J^T with
/// J = [((p - c) x n) / (d/2); n], c and d the model's centre and diameter: 1/3 for a corner of three equal
/// faces, 0 for a single plane.
Verification verify_pose(const std::vector<Eigen::Vector3d>& scan_points, const Surface& model,
                         const Eigen::Isometry3d& T_model_scan, const Eigen::Vector3d& viewpoint_scan,
                         const VerifySettings& settings);

}  // namespace partloc
