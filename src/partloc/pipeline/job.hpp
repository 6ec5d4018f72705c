#pragma once
// A job in memory: what `partloc run` reads from job.yaml and its files (SPEC "Job file"). Every length is
// in the job's units; the readers convert files that carry other units.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "partloc/core/kinematics.hpp"

namespace partloc {

/// A model given either as a mesh (STL, PLY, OBJ) or as points (PLY, PCD, XYZ). Exactly one is set.
struct ModelSource {
    std::string file;  ///< as written in the job, for messages
    std::shared_ptr<const open3d::geometry::TriangleMesh> mesh;
    std::shared_ptr<const open3d::geometry::PointCloud> points;
};

struct ScannerSpec {
    std::optional<double> point_spacing;  ///< typical distance between neighbouring points (job units)
    std::optional<double> noise;          ///< 1-sigma noise along the line of sight (job units)
};

struct Fiducial {
    std::string name;
    ModelSource model;                                           ///< in the fiducial's own frame
    Eigen::Isometry3d T_machine_fiducial = Eigen::Isometry3d::Identity();  ///< as probed at probed_at
    AxisValues probed_at;                                        ///< axis values when probed (default all 0)
    std::vector<std::string> moves_with;                         ///< axes that carry it, base first
    double pose_sigma = 0.0;  ///< 1-sigma probing uncertainty (job units); 0: the default 0.005 mm
};

struct Workpiece {
    ModelSource reference_surfaces;  ///< nominal position, machine frame, axes at 0
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();  ///< nominal datum frame
    std::optional<ModelSource> final_part;  ///< the part to be cut, at its nominal position
    std::vector<std::string> moves_with;
    std::optional<Eigen::AlignedBox3d> region;  ///< crop box, machine frame, axes at 0
};

struct Scan {
    std::string file;  ///< as written in the job
    std::shared_ptr<const open3d::geometry::PointCloud> points;  ///< scan frame
    AxisValues axes;   ///< axis values when the scan was taken
};

struct Job {
    std::string units = "mm";
    ScannerSpec scanner;
    Machine machine;
    std::vector<Fiducial> fiducials;
    Workpiece workpiece;
    std::vector<Scan> scans;
};

/// Factor that converts a length in `units` to millimetres; throws std::invalid_argument on an unknown unit.
double millimetres_per_unit(const std::string& units);

}  // namespace partloc
