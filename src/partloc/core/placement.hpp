#pragma once
// Where to put the final part in the material that is there (SPEC "Machining", placement mode maxmin): the
// move of the final part, about the located datum frame, that maximises its least allowance (a Chebyshev,
// L-infinity, fit; Autodesk PowerInspect's MaxMin, SZTAKI's blank localisation with rotations as well),
// with any of the six degrees of freedom locked and the move limited.
//
// Each iteration linearises the allowance of every sample against its plane of the as-built surface
// (allowance.hpp) in a small move (v, w) of the part: a translation v of the datum origin and a rotation w
// about it, and solves one linear programme, maximise s subject to allowance_i + g_i . (v, w) >= s +
// required for the samples that bind (added as they are violated), with the free degrees of freedom within a
// trust region and the whole move within its limits (cutting planes on the norm: a plane through the
// point where the move would leave the ball, added until it stays inside). GLPK's simplex solves it. The move
// is taken when the least allowance on the planes grows, else the trust region halves. When it stops
// moving, the allowance is measured again from the scan points (new planes, the exact map) and the
// iterations go on from there until the measured and the predicted least allowance agree.
#include <Eigen/Geometry>
#include <array>
#include <limits>
#include <string>

#include "partloc/core/allowance.hpp"

namespace partloc {

struct PlacementSettings {
    /// The degrees of freedom the part may use, about the located datum frame: x, y, z, a, b, c.
    std::array<bool, 6> free{{true, true, true, true, true, true}};
    double max_translation = std::numeric_limits<double>::infinity();  ///< of the datum origin (job units)
    double max_rotation_deg = std::numeric_limits<double>::infinity();
    double required = 0.0;           ///< the allowance wanted everywhere (job units): what `fits` means
    double step_translation = 0.0;   ///< first trust region (job units); 0: 2 % of the part's diagonal
    double step_rotation_deg = 1.0;  ///< first trust region
    int max_iterations = 60;         ///< linear programmes, over all re-measurements
    int max_measurements = 4;        ///< exact maps measured from the scan points after the located one
    /// Stop when a step moves no sample more than this fraction of the scanner's noise.
    double tolerance = 1e-3;
    int rows_per_round = 256;  ///< samples added to the linear programme each time they are violated
};

struct Placement {
    bool valid = false;  ///< a placement was computed (false: `reason`)
    std::string reason;
    bool fits = false;  ///< the least allowance at the placement is at least settings.required
    Eigen::Isometry3d T_move = Eigen::Isometry3d::Identity();  ///< machine frame: located part -> placed part
    AllowanceMap map;           ///< measured from the scan points at the placement
    double translation = 0.0;   ///< how far the datum origin moved (job units)
    double rotation_deg = 0.0;  ///< by how much the part turned
    int iterations = 0;         ///< linear programmes solved
    int measurements = 0;       ///< maps measured from the scan points
};

/// The maxmin placement of `part` (samples in the mesh frame), located at T_located (mesh frame -> machine
/// frame), about the located datum frame T_machine_datum. `located` is measure_allowance at T_located.
Placement place_maxmin(const PartSamples& part, const Eigen::Isometry3d& T_located,
                       const Eigen::Isometry3d& T_machine_datum, const ScannedStock& stock,
                       const AllowanceSettings& allowance, const PlacementSettings& settings,
                       const AllowanceMap& located);

}  // namespace partloc
