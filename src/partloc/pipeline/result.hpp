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
#include "partloc/pipeline/machining.hpp"

namespace partloc {

/// One scan's outcome: `valid` means registered (result.json's "registered"), else "rejected" with the
/// reason.
struct ScanResult {
    std::string file;
    bool valid = false;
    std::vector<std::string> fiducials;  ///< the fiducials that fixed the scan
    double score = 0.0;
    double rmse = 0.0;
    /// Maps scan points to the machine frame at the scan's axis values (where the fixed bodies are).
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    /// The scanner's scale as fitted (ScanRegistration::scale): a scan point p lies in the machine at
    /// T_machine_scan * (scale_centre + scale (p - scale_centre)); 1 where not fitted.
    double scale = 1.0;
    Eigen::Vector3d scale_centre = Eigen::Vector3d::Zero();  ///< scan frame
    double scale_sigma = 0.0;  ///< its 1 sigma from the noise alone; 0 where not fitted
    std::string reason;        ///< why it was rejected; empty when registered (result.json's "message")
    std::vector<std::string>
        warnings;  ///< registered, but something a person should know (a fiducial left out)
    /// Information of T_machine_scan (twist [w, v] in the machine frame) from the joint fit: JtJ / noise^2.
    Matrix6d information = Matrix6d::Zero();
    /// Each fiducial's share of the joint fit's JtJ (same frame and twist), in `fiducials`' order; empty when
    /// the scan was placed by one fiducial's fit without the joint one.
    std::vector<Matrix6d> JtJ_per_fiducial;
    std::size_t points = 0;         ///< valid points in the scan
    double point_spacing = 0.0;     ///< used for this scan (given or estimated), job units
    double noise = 0.0;             ///< used for this scan (given or estimated), job units
    std::vector<FiducialFit> fits;  ///< every fiducial tried
    double seconds = 0.0;
};

/// Half-widths of 95 % intervals of the located pose (pipeline/uncertainty.hpp), and the 1-sigma parts they
/// come from (origin in job units, angles in degrees).
struct Uncertainty {
    bool available = false;
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();     ///< 95 % half-widths of origin x, y, z
    Eigen::Vector3d euler_deg = Eigen::Vector3d::Zero();  ///< 95 % half-widths of euler_xyz_deg a, b, c
    Eigen::Vector3d origin_scans = Eigen::Vector3d::Zero(),
                    euler_scans = Eigen::Vector3d::Zero();  ///< jackknife
    Eigen::Vector3d origin_probing = Eigen::Vector3d::Zero(), euler_probing = Eigen::Vector3d::Zero();
    /// The part of the jackknife's scatter that the probing explains (scans differing in their fiducials).
    Eigen::Vector3d origin_probing_in_scans = Eigen::Vector3d::Zero(),
                    euler_probing_in_scans = Eigen::Vector3d::Zero();
    Eigen::Vector3d origin_noise = Eigen::Vector3d::Zero(), euler_noise = Eigen::Vector3d::Zero();
    int scans = 0;  ///< scans in the jackknife
};

/// The workpiece's outcome: `valid` means located (result.json's status "located"), else the reason.
struct WorkpieceResult {
    bool valid = false;
    std::string reason;  ///< why it was not located; empty when located (result.json's "message")
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();  ///< located, axes at 0
    Eigen::Isometry3d T_machine_workpiece_nominal = Eigen::Isometry3d::Identity();
    double rmse = 0.0;        ///< RMS distance of the merged points to the fitted reference surfaces
    std::size_t points = 0;   ///< merged workpiece points used in the fit
    std::size_t inliers = 0;  ///< of those, the points on the reference surfaces
    Matrix6d information = Matrix6d::Zero();
    Uncertainty uncertainty;
    std::string fit = "simultaneous";   ///< "simultaneous" or "datums" (3-2-1), as job.workpiece.fit
    std::vector<DatumResidual> datums;  ///< per datum of the job, its points and rmse at the result
};

/// What report.html's 3D view draws of the registered workpiece points: an even subsample of them, machine
/// frame with every axis at 0.
struct ViewPoints {
    std::vector<Eigen::Vector3f> points;
    std::vector<int> scan;  ///< per point, its index into JobResult::scans
    /// Per point, its signed distance from the located reference surfaces along their outward normal (job
    /// units; positive outside the material); NaN where no reference surface lies within `reach`, or where
    /// the part was not located.
    std::vector<float> deviation;
    double reach = 0.0;
};

struct JobResult {
    std::string units = "mm";
    std::vector<ScanResult> scans;
    WorkpieceResult workpiece;
    std::shared_ptr<open3d::geometry::PointCloud> merged;   ///< machine frame, axes at 0
    std::shared_ptr<open3d::geometry::TriangleMesh> stock;  ///< as-built workpiece
    std::shared_ptr<open3d::geometry::TriangleMesh> final_part_located;
    ViewPoints view;  ///< for report.html's 3D view
    /// The final part's allowance and placement (SPEC "Machining"); not available without a final part.
    MachiningResult machining;
    /// What a person must look at before cutting (SPEC "Status with warnings"), one sentence each: the
    /// job's (Job::warnings, what reading its files found), then every scan's, named by the scan. A located
    /// result with warnings is still located.
    std::vector<std::string> warnings;
    double seconds = 0.0;
};

}  // namespace partloc
