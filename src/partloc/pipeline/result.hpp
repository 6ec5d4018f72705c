#pragma once
// What `partloc run` found: everything result.json, the output models and report.html need.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/datum_fit.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/localize.hpp"

namespace partloc {

struct ScanResult {
    std::string file;
    bool registered = false;
    std::vector<std::string> fiducials;  ///< the fiducials that fixed the scan
    double score = 0.0;
    double rmse = 0.0;
    /// Maps scan points to the machine frame at the scan's axis values (where the fixed bodies are).
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    std::string message;  ///< why it was rejected; empty when registered
    std::size_t points = 0;          ///< valid points in the scan
    double point_spacing = 0.0;      ///< used for this scan (given or estimated), job units
    double noise = 0.0;              ///< used for this scan (given or estimated), job units
    std::vector<FiducialFit> fits;   ///< every fiducial tried
    double seconds = 0.0;
};

struct WorkpieceResult {
    bool located = false;
    std::string message;  ///< why it was not located; empty when located
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();  ///< located, axes at 0
    Eigen::Isometry3d T_machine_workpiece_nominal = Eigen::Isometry3d::Identity();
    double rmse = 0.0;        ///< RMS distance of the merged points to the fitted reference surfaces
    std::size_t points = 0;   ///< merged workpiece points used in the fit
    std::size_t inliers = 0;  ///< of those, the points on the reference surfaces
    Matrix6d information = Matrix6d::Zero();
    std::string fit = "simultaneous";   ///< "simultaneous" or "datums" (3-2-1), as job.workpiece.fit
    std::vector<DatumResidual> datums;  ///< per datum of the job, its points and rmse at the result
};

struct JobResult {
    bool located = false;
    std::string units = "mm";
    std::vector<ScanResult> scans;
    WorkpieceResult workpiece;
    std::shared_ptr<open3d::geometry::PointCloud> merged;            ///< machine frame, axes at 0
    std::shared_ptr<open3d::geometry::TriangleMesh> stock;           ///< as-built workpiece
    std::shared_ptr<open3d::geometry::TriangleMesh> final_part_located;
    double seconds = 0.0;
};

}  // namespace partloc
