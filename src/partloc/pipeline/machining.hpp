#pragma once
// From the located frame to a set-up that can be cut (SPEC "Machining"): the allowance of the final part in
// the material the scans show (core/allowance.hpp), and, where the job asks, its maxmin placement
// (core/placement.hpp). run_job's last stage.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/allowance.hpp"
#include "partloc/core/placement.hpp"
#include "partloc/pipeline/job.hpp"

namespace partloc {

struct MachiningSettings {
    /// The final part is sampled at the merged points' spacing times this (SPEC: "about the scanner's
    /// spacing"); the allowance map and allowance.ply have one sample each.
    double sample_spacings = 1.0;
    /// The placement's iterations measure on samples this many times farther apart (a sixteenth of the
    /// samples at 4: the least allowance moves by less than the noise's standard error between them); the
    /// map at the placement is measured on all of them.
    double placement_sample_spacings = 4.0;
    /// A warning when more of the final part's surface than this fraction was not seen by any scan.
    double warn_unscanned_fraction = 0.2;
    AllowanceSettings allowance;  ///< spacing and noise set from the merged points and the scans
    PlacementSettings placement;  ///< free, limits and required set from the job
};

struct MachiningResult {
    bool available = false;  ///< an allowance map was measured (false: `reason`, or no final part)
    std::string reason;
    PartSamples part;                     ///< the final part's samples (mesh frame: nominal, machine frame)
    std::vector<std::string> face_names;  ///< per part.faces, e.g. "face 2 (+X)" in the datum axes
    double required = 0.0;                ///< job.workpiece.allowance_min, or 0
    AllowanceMap located;                 ///< the map with the final part at its located pose
    AllowanceMap map;                     ///< at the placement (the located map in mode located)
    bool maxmin = false;                  ///< the placement's mode
    bool fits = false;                    ///< map.all.min >= required
    std::string placement_reason;         ///< a maxmin placement that could not be computed, why
    Eigen::Isometry3d T_move = Eigen::Isometry3d::Identity();          ///< machine frame: located -> placed
    Eigen::Isometry3d T_machine_part = Eigen::Isometry3d::Identity();  ///< the placed datum frame
    double translation = 0.0, rotation_deg = 0.0;                      ///< the move from the located pose
    std::shared_ptr<open3d::geometry::TriangleMesh> final_part_placed;
    std::vector<std::string> warnings;  ///< for result.json's warnings
    double seconds = 0.0;               ///< the whole stage
    double placement_seconds = 0.0;     ///< of those, the maxmin search (its coarse samples' map included)
};

/// The allowance and placement of job.workpiece.final_part (a mesh; points give no allowance), located at
/// T_located_nominal (nominal -> located, machine frame) with its datum frame at T_machine_workpiece, in the
/// merged points (machine frame, axes at 0, normals facing out of the material) of spacing `spacing` and
/// noise `noise`. Not available, with the reason, when the final part is no mesh or there are no normals.
MachiningResult plan_machining(const Job& job, const open3d::geometry::PointCloud& merged,
                               const Eigen::Isometry3d& T_located_nominal,
                               const Eigen::Isometry3d& T_machine_workpiece, double spacing, double noise,
                               MachiningSettings settings = {});

}  // namespace partloc
