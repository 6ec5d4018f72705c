#pragma once
// How far the located workpiece may be from the truth (issue 4): half-widths of 95 % intervals of its origin
// and Euler angles: 1.96 times the first two parts below in quadrature (the third is reported, and is in
// the first already):
//  - the scans: each registered scan brings its own registration error and its own noise and view. Fitting
//    the part again with each scan left out (the jackknife over scans) measures how much the answer moves
//    with them, bias included, which the fit's information matrix alone does not: edge effects and
//    registration errors are not independent per point, so 1/sqrt(points) is far too optimistic;
//  - the fiducials' probing (fiducials[].pose_sigma): an error in a fiducial's probed pose moves every scan
//    it registers the same way, so it does not average out over scans;
//  - the noise of the points, from the fit's information matrix: the bound that the points' number and
//    scatter set. With the probing, the error that noise and probing alone would leave.
// Reported as well: how much of the jackknife's scatter the probing alone explains, where scans differ in
// their fiducials (it is not taken out; uncertainty.cpp says why).
#include <open3d/geometry/PointCloud.h>

#include <Eigen/Geometry>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc {

/// The uncertainty takes every this-th of a scan's `points` points, at most about `most` of them.
inline std::size_t scan_stride(std::size_t points, std::size_t most) {
    return std::max<std::size_t>(1, points / std::max<std::size_t>(most, 1));
}

struct UncertaintyInputs {
    /// Each registered scan's points that the part's fit takes (machine frame, axes at 0; normals if
    /// available, needed at every scan_stride(size, scan_points_most)-th point only).
    std::vector<std::shared_ptr<const open3d::geometry::PointCloud>> scan_points;
    /// At most about this many of each scan's points are refitted: 30 000 covers all of a scan's points near
    /// the reference surfaces (5-10 thousand of 250 k); of all its workpiece points, 8000.
    std::size_t scan_points_most = 30000;
    /// For each of those scans: the fiducials that registered it (indices into job.fiducials).
    std::vector<std::vector<std::size_t>> scan_fiducials;
    /// For each scan, in scan_fiducials' order: each fiducial's share of the scan fit's JtJ (machine frame at
    /// the scan's axes, twist [w, v]). Empty for a scan: its fiducials share its pose error evenly.
    std::vector<std::vector<Matrix6d>> scan_fiducial_jtj;
    /// For each scan, in scan_fiducials' order: the fiducial's motion from where it was probed to where it
    /// was at the scan (machine frame; identity for a fiducial that does not move).
    std::vector<std::vector<Eigen::Isometry3d>> scan_fiducial_motion;
    /// For each scan: machine frame at the scan's axes to the machine frame at axes 0, where the workpiece is
    /// located (the workpiece's motion undone).
    std::vector<Eigen::Isometry3d> scan_to_axes0;
    const Surface* reference = nullptr;  ///< nominal reference surfaces
    Eigen::Isometry3d T_located_nominal =
        Eigen::Isometry3d::Identity();        ///< the fit: located = T_located_nominal * nominal
    double fit_distance = 0.0;                ///< the fit's last correspondence distance
    double noise = 0.0;                       ///< scan noise, 1 sigma
    Matrix6d information = Matrix6d::Zero();  ///< the fit's, machine frame, twist [w, v] (JtJ / noise^2)
    /// The part's fit again on other points (machine frame, normals or null), from the full fit's pose:
    /// the T_located_nominal it finds. Empty: the part fit's last stage (fit_last_stage) on `reference` from
    /// T_located_nominal.
    std::function<std::optional<Eigen::Isometry3d>(const std::vector<Eigen::Vector3d>&,
                                                   const std::vector<Eigen::Vector3d>*)>
        refit;
};

/// Fills result.workpiece.uncertainty (needs result.workpiece.T_machine_workpiece located).
void estimate_uncertainty(const Job& job, const UncertaintyInputs& in, WorkpieceResult& workpiece);

}  // namespace partloc
