#pragma once
// The part (paper §3.4.2): the nominal reference surfaces fitted to the merged, cropped, cleaned points.
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/icp.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct WorkpieceFitSettings {
    double noise = 0.0;    ///< scan noise, 1 sigma (job units)
    double spacing = 0.0;  ///< point spacing (job units)
    double max_start_distance =
        0.0;  ///< largest expected displacement from nominal (job units); 0: 10% of size
    std::size_t min_inliers = 200;
    double min_conditioning = 0.01;  ///< as in verification: all six degrees of freedom fixed
    /// The points on the surfaces may scatter about them at most this many times the noise (RMS). The
    /// scanner's noise is along its rays, so a right fit shows less than all of it along the normals.
    double max_rmse_noise = 1.25;
};

struct WorkpieceFit {
    bool valid = false;
    std::string reason;
    /// Moves the nominal reference surfaces onto the measured ones: located = T_located_nominal * nominal.
    Eigen::Isometry3d T_located_nominal = Eigen::Isometry3d::Identity();
    double rmse = 0.0;
    std::size_t inliers = 0;
    double conditioning = 0.0;
    Matrix6d JtJ = Matrix6d::Zero();  ///< in the nominal reference frame (machine), twist [w, v]
    int iterations = 0;
    double distance = 0.0;  ///< the last stage's correspondence distance
};

/// Fits the nominal reference surfaces (oriented samples at nominal position, machine frame) to the merged
/// workpiece points (machine frame, axes at 0), starting at nominal. `normals` (optional, the points'
/// normals) keep points of faces that meet a reference surface at its edge off that surface in the last
/// stage.
WorkpieceFit fit_reference_surfaces(const std::vector<Eigen::Vector3d>& merged, const Surface& reference,
                                    const WorkpieceFitSettings& settings,
                                    const std::vector<Eigen::Vector3d>* normals = nullptr);

/// The fit's last stage on `points` (machine frame; `normals` optional, as in the fit) from the pose
/// T_nominal_located (the inverse of a fit's T_located_nominal), at the last stage's correspondence distance
/// (WorkpieceFit::distance): fit_reference_surfaces' own last stage, and the same fit again on other points
/// (every scanned point near the surfaces, the uncertainty's jackknife).
IcpResult fit_last_stage(const std::vector<Eigen::Vector3d>& points, const Surface& reference,
                         const Eigen::Isometry3d& T_nominal_located, double distance,
                         const std::vector<Eigen::Vector3d>* normals = nullptr);

/// A scan's own part lies off the located part when its own fit moves its points along the reference
/// surfaces' normals by more than this many noise sigmas: part_disowns_scan (a lone fiducial's scan) and
/// the part stage's scans_off_part (every scan in the fit) judge by it alike.
inline constexpr double own_fit_limit_noises = 5.0;

/// Whether the part confirms a scan that one fiducial's fit alone registered (a look-alike of that fiducial,
/// or the fiducial moved, can place such a scan): the part fitted again on the scan's workpiece points alone
/// (machine frame, axes at 0; normals optional), from `located`, the part located from all the registered
/// scans (`located.valid`), or from nominal where it was not. Empty when the part confirms the scan, else why
/// not:
/// - fewer than min_inliers of its points on the reference surfaces (unconfirmed);
/// - with the part located: its own fit moves its points along the surfaces' normals by more than five times
///   the noise (RMS over its points on the surfaces; directions the scan leaves free move no point along a
///   normal and do not count);
/// - with the part not located: its own fit does not fix all six degrees of freedom even weakly (conditioning
///   under 0.2 of the minimum).
/// Not the residual gate, nor the full conditioning: on the real bunny scans the own fits' RMS is 1.6-1.8
/// times the noise estimated from the data, and the top view's conditioning is 0.0095 (against 0.010); the
/// wrongly placed scans of seeds 1320 and 1355 had 0.0000 (points on one plane).
std::string part_disowns_scan(const std::vector<Eigen::Vector3d>& points,
                              const std::vector<Eigen::Vector3d>* normals, const WorkpieceFit& located,
                              const Surface& reference, const WorkpieceFitSettings& settings);

/// How far the part that a scan's points alone show lies from `located` (valid): part_disowns_scan's
/// measure, the RMS move along the reference surfaces' normals of its points on them when the surfaces are
/// fitted again on them from `located` (directions the scan leaves free do not count). Negative when
/// `located` is not valid or fewer than min_inliers of its points lie on the reference surfaces (nothing to
/// compare).
double scan_part_offset(const std::vector<Eigen::Vector3d>& points,
                        const std::vector<Eigen::Vector3d>* normals, const WorkpieceFit& located,
                        const Surface& reference, const WorkpieceFitSettings& settings);

}  // namespace partloc
