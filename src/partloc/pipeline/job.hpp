#pragma once
// A job in memory: what `partloc run` reads from job.yaml and its files (SPEC "Job file"). Every length is
// in the job's units; the readers convert files that carry other units.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <array>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "partloc/core/kinematics.hpp"
#include "partloc/core/probe_planes.hpp"

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
    ModelSource model;                                                     ///< in the fiducial's own frame
    Eigen::Isometry3d T_machine_fiducial = Eigen::Isometry3d::Identity();  ///< as probed at probed_at
    AxisValues probed_at;                 ///< axis values when probed (default all 0)
    std::vector<std::string> moves_with;  ///< axes that carry it, base first
    /// 1-sigma probing uncertainty of the pose (job units). load_job always sets it: as given, or
    /// default_pose_sigma(units). The initial value is that default for a job in mm (Job's default units);
    /// an in-memory job in other units must set it. 0 means the probed pose is taken as exact.
    double pose_sigma = 0.005;
};

/// 0.005 mm, the default probing uncertainty of a fiducial's pose, in `units`.
double default_pose_sigma(const std::string& units);

/// A datum feature of the workpiece (paper §4: primary, secondary, tertiary datum).
struct Datum {
    std::string name;
    ModelSource surfaces;  ///< nominal position, machine frame, axes at 0
};

enum class WorkpieceFitMode {
    Simultaneous,  ///< one least-squares fit of all reference surfaces at once (paper §3.4.2)
    Datums,        ///< 3-2-1: the primary fixes 3 degrees of freedom, the secondary 2, the tertiary 1
};

/// Where the final part goes in the material (SPEC "Machining", workpiece.placement).
struct PlacementSpec {
    bool maxmin = false;  ///< mode maxmin; false: located (the part moves with the located datum frame)
    /// The degrees of freedom a maxmin placement may use, about the located datum frame: x, y, z, a, b, c.
    std::array<bool, 6> free{{true, true, true, true, true, true}};
    double max_translation = std::numeric_limits<double>::infinity();  ///< of the datum origin (job units)
    double max_rotation_deg = std::numeric_limits<double>::infinity();
};

struct Workpiece {
    ModelSource reference_surfaces;  ///< nominal position, machine frame, axes at 0
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();  ///< nominal datum frame
    std::optional<ModelSource> final_part;  ///< the part to be cut, at its nominal position
    std::vector<std::string> moves_with;
    std::optional<Eigen::AlignedBox3d> region;  ///< crop box, machine frame, axes at 0
    std::vector<Datum> datums;                  ///< empty, or three: primary, secondary, tertiary
    WorkpieceFitMode fit = WorkpieceFitMode::Simultaneous;
    /// The least stock required on the final part's surface (job units; workpiece.allowance.min): what
    /// placement status `fits` means. Not given: 0, the final part inside the material.
    std::optional<double> allowance_min;
    PlacementSpec placement;
};

/// A pose the job gave as probed points on three planes, with the fit's residuals, for the report.
struct ProbedPose {
    std::string field;  ///< where in the job, e.g. "fiducials[0].pose"
    ProbedFrame frame;
};

struct Scan {
    std::string file;                                            ///< as written in the job
    std::shared_ptr<const open3d::geometry::PointCloud> points;  ///< scan frame
    AxisValues axes;                                             ///< axis values when the scan was taken
};

/// What `run` writes besides result.json and the models (SPEC "Machining").
struct OutputSpec {
    std::vector<std::string> offsets;  ///< work-offset dialects: fanuc, siemens, heidenhain, linuxcnc
    int work_offset = 1;               ///< 1 = G54 / the first preset, 2 = G55 ..., at most 6
};

struct Job {
    std::string units = "mm";
    ScannerSpec scanner;
    Machine machine;
    std::vector<Fiducial> fiducials;
    Workpiece workpiece;
    std::vector<Scan> scans;
    std::vector<ProbedPose> probed_poses;  ///< every pose given as probe_planes, in the job's order
    OutputSpec output;
    /// What reading the files found that a person should know (data beyond a header's count, far points
    /// dropped from a scan): sentences naming the file, for result.json's top-level warnings.
    std::vector<std::string> warnings;
};

/// Factor that converts a length in `units` to millimetres; throws std::invalid_argument on an unknown unit.
double millimetres_per_unit(const std::string& units);

/// Axis-aligned bounding box of a model's vertices or points (empty for an empty model).
Eigen::AlignedBox3d bounding_box(const ModelSource& model);

/// Where fiducial `f` is at axis values `q`: its probed pose moved by its axes from where it was probed.
Eigen::Isometry3d fiducial_at(const Machine& machine, const Fiducial& f, const AxisValues& q);

/// The region of the machine frame (axes at 0) where the workpiece's points are looked for: the job's crop
/// box, or the nominal reference surfaces and final part with a margin for the part's uncertain pose
/// (0.15 of their diagonal plus 5 point spacings).
Eigen::AlignedBox3d workpiece_region(const Job& job, double spacing);

/// The union of the datums' surfaces as one model (the reference surfaces of a job that names only datums):
/// one mesh when every datum is a mesh, else points (meshes sampled at 1/400 of their union's diagonal;
/// normals kept only when every part has them). Its file is "datums". Empty when there are no datums.
ModelSource union_of_datums(const std::vector<Datum>& datums);

}  // namespace partloc
