#pragma once
// What the virtual cell knows and a real cell would not: the true poses, and what each scan saw. Plain data,
// written to truth.json beside a simulated job.
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "partloc/core/kinematics.hpp"

namespace partloc::sim {

struct ScanTruth {
    std::string file;  ///< the scan's file in the job, e.g. "scans/scan_01.ply"
    AxisValues axes;   ///< axis values when it was taken
    /// The scanner's pose in the machine frame at scan time: maps scan points to where the fixed bodies
    /// (pallet, fiducials) are. Scan frame = scanner frame.
    Eigen::Isometry3d T_machine_scan = Eigen::Isometry3d::Identity();
    std::size_t points = 0;                              ///< points in the scan
    std::size_t outliers = 0;                            ///< of those, spurious returns
    std::size_t workpiece_points = 0;                    ///< true returns from the workpiece
    std::array<std::size_t, 3> reference_points{};       ///< true returns from each datum face (+x, +y, +z)
    std::map<std::string, std::size_t> fiducial_points;  ///< true returns from each fiducial, by name
};

struct Truth {
    std::string scenario;  ///< "paper_test_1" ... "paper_test_5" or "random_cell"
    std::uint64_t seed = 0;
    std::string units = "mm";
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();          ///< true, axes at 0
    Eigen::Isometry3d T_machine_workpiece_nominal = Eigen::Isometry3d::Identity();  ///< as in the job
    std::map<std::string, Eigen::Isometry3d> T_machine_fiducial;  ///< true (= probed) poses, by name
    std::array<double, 3> reference_area{};  ///< area of each datum face (+x, +y, +z), mm^2
    std::vector<ScanTruth> scans;
};

}  // namespace partloc::sim
