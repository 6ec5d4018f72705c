#pragma once
// The part (paper §3.4.2): the nominal reference surfaces fitted to the merged, cropped, cleaned points.
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

struct WorkpieceFitSettings {
    double noise = 0.0;               ///< scan noise, 1 sigma (job units)
    double spacing = 0.0;             ///< point spacing (job units)
    double max_start_distance = 0.0;  ///< largest expected displacement from nominal (job units); 0: 10% of size
    std::size_t min_inliers = 200;
    double min_conditioning = 0.01;   ///< as in verification: all six degrees of freedom fixed
    /// The points on the surfaces may scatter about them at most this many times the noise (RMS). The
    /// scanner's noise is along its rays, so a right fit shows less than all of it along the normals.
    double max_rmse_noise = 1.25;
};

struct WorkpieceFit {
    bool ok = false;
    std::string reason;
    /// Moves the nominal reference surfaces onto the measured ones: located = T_correction * nominal.
    Eigen::Isometry3d T_correction = Eigen::Isometry3d::Identity();
    double rmse = 0.0;
    std::size_t inliers = 0;
    double conditioning = 0.0;
    Matrix6d JtJ = Matrix6d::Zero();  ///< in the nominal reference frame (machine), twist [w, v]
    int iterations = 0;
    double distance = 0.0;  ///< the last stage's correspondence distance
};

/// Fits the nominal reference surfaces (oriented samples at nominal position, machine frame) to the merged
/// workpiece points (machine frame, axes at 0), starting at nominal. `normals` (optional, the points'
/// normals) keep points of faces that meet a reference surface at its edge off that surface in the last stage.
WorkpieceFit fit_reference_surfaces(const std::vector<Eigen::Vector3d>& merged, const Surface& reference,
                                    const WorkpieceFitSettings& settings,
                                    const std::vector<Eigen::Vector3d>* normals = nullptr);

}  // namespace partloc
