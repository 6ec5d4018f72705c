#pragma once
// The datum hierarchy (paper §4 and §5: "performing a least square fit individually on each plane and
// treating them as primary, secondary, and tertiary datum"; 3-2-1 locating): the primary datum fixes the
// three degrees of freedom it constrains best, the secondary the two of the remaining three it constrains
// best, the tertiary the last one. For plane datums these are, in turn: the translation along the primary's
// normal and the two rotations about axes in it; the translation along the secondary's normal (in the
// primary) and the rotation about the primary's normal; the translation along the line both share.
//
// Each Gauss-Newton step is solved in that order (a block-triangular system): the primary's step uses only
// the primary's points, the secondary's only the secondary's given the primary's step, and so on. At
// convergence each datum's points are fitted in least squares in its own degrees of freedom, whatever the
// later datums say: a tertiary face that is not square to the others moves only the last degree of freedom.
#include <Eigen/Geometry>
#include <array>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"
#include "partloc/core/surface.hpp"

namespace partloc {

/// One datum feature: its nominal surfaces as oriented samples (machine frame, nominal position).
struct DatumSurface {
    std::string name;
    Surface surface;
};

struct DatumFitSettings {
    double noise = 0.0;    ///< scan noise, 1 sigma (job units)
    double spacing = 0.0;  ///< point spacing of the merged points (job units)
    /// Correspondence distance of the last stage (job units); 0: as the simultaneous fit's last stage,
    /// sqrt(9 noise^2 + (sample spacing / 2)^2). Points within it of two datums (at a shared edge) are left
    /// out.
    double max_distance = 0.0;
    std::array<int, 3> dof = {3, 2, 1};  ///< degrees of freedom of the primary, secondary, tertiary
    int max_iterations = 40;             ///< per stage
    double min_step = 1e-8;              ///< stop when the update is smaller (radians, job units / size)
    std::size_t min_points = 50;         ///< points each datum needs
    /// Smallest eigenvalue per point of a datum's information in its own degrees of freedom (rotations
    /// scaled by half the datums' size), below which it does not fix them.
    double min_conditioning = 1e-3;
};

struct DatumResidual {
    std::string name;
    std::size_t points = 0;     ///< merged points on this datum (within the last stage's distance)
    double rmse = 0.0;          ///< their RMS point-to-plane distance (job units)
    int dof = 0;                ///< degrees of freedom it fixed (0 when only evaluated)
    double conditioning = 0.0;  ///< see DatumFitSettings::min_conditioning
};

struct DatumFit {
    bool valid = false;
    std::string reason;  ///< why not, when not valid
    /// Moves the nominal surfaces onto the measured ones: located = T_located_nominal * nominal.
    Eigen::Isometry3d T_located_nominal = Eigen::Isometry3d::Identity();
    std::vector<DatumResidual> datums;  ///< in the order given
    bool converged = false;
    int iterations = 0;
    std::size_t inliers = 0;  ///< points on any datum
    double rmse = 0.0;        ///< over all of them (job units)
    /// Covariance of the hierarchical estimate for unit noise (multiply by noise^2), as a twist [w, v] of
    /// T_located_nominal^-1 (merged points -> nominal) about the machine origin, like IcpResult::JtJ; and its
    /// inverse, the information for unit noise (comparable to IcpResult::JtJ).
    Matrix6d covariance = Matrix6d::Zero();
    Matrix6d information = Matrix6d::Zero();
};

/// Fits the datums in order of precedence to the merged workpiece points (machine frame, axes at 0),
/// starting from T_correction_start (the simultaneous fit's). Needs exactly three datums; a failure is a
/// result with a reason.
DatumFit fit_datums(const std::vector<Eigen::Vector3d>& merged, const std::vector<DatumSurface>& datums,
                    const Eigen::Isometry3d& T_correction_start, const DatumFitSettings& settings);

/// Each datum's points and residual at a given pose (for a simultaneous fit); T_located_nominal as above.
std::vector<DatumResidual> evaluate_datums(const std::vector<Eigen::Vector3d>& merged,
                                           const std::vector<DatumSurface>& datums,
                                           const Eigen::Isometry3d& T_located_nominal,
                                           const DatumFitSettings& settings);

}  // namespace partloc
