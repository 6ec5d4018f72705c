#pragma once
// What `partloc run` found: everything result.json, the output models and report.html need.
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <Eigen/Geometry>
#include <memory>
#include <string>
#include <vector>

#include "partloc/core/geometry.hpp"

namespace partloc {

/// One fiducial tried against one scan (the processor's candidate, paper §3.4.1).
struct FiducialFit {
    std::string fiducial;
    bool accepted = false;
    std::string reason;  ///< why it was not accepted; empty when accepted
    Eigen::Isometry3d T_scan_fiducial = Eigen::Isometry3d::Identity();
    double rmse = 0.0;          ///< RMS point-to-surface distance of the inliers (job units)
    double coverage = 0.0;      ///< fraction of the model surface facing the scanner that was observed [0, 1]
    double violation = 0.0;     ///< fraction of nearby scan points seen inside the model's solid [0, 1]
    double conditioning = 0.0;  ///< smallest eigenvalue of the normalised 6x6 fit information [0, 1]
    double score = 0.0;         ///< larger is better; 0 when rejected
    std::size_t inliers = 0;    ///< scan points on the model surface
    Matrix6d information = Matrix6d::Zero();  ///< of T_scan_fiducial, in (job units)^-2, twist [w, v]
};

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
