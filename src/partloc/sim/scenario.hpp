#pragma once
// Complete virtual jobs with their truth: the paper's experiment (§4, Table 4) and random cells with shapes
// never seen before. The job is ready for run_job in memory, or for write_job to disk.
#include <cstdint>
#include <vector>

#include "partloc/pipeline/job.hpp"
#include "partloc/sim/cell.hpp"
#include "partloc/sim/scanner.hpp"
#include "partloc/sim/truth.hpp"

namespace partloc::sim {

struct ScenarioOptions {
    ScannerSettings scanner;  ///< the paper's NextEngine; its seed is replaced by one per scan
    std::vector<double> a_values = {0.0, 45.0, 90.0};  ///< degrees; paper §4: two scans at each
    int scans_per_position = 2;
    /// Points each datum face must get in every scan: min_face_points, or for a small face
    /// min_face_coverage times the points it would get square to the scanner (area / spacing^2).
    std::size_t min_face_points = 800;
    double min_face_coverage = 0.2;
    std::size_t min_fiducial_points = 4000;      ///< points the best-seen fiducial must get in every scan
    std::size_t min_fiducial_axis_points = 300;  ///< ... on its faces of each normal direction (x, y, z),
                                                 ///< so that it fixes all six degrees of freedom
    int view_attempts = 80;                      ///< candidate viewpoints tried per scan
    double preview_factor = 4.0;  ///< candidates are checked with a ray grid this many times sparser
};

struct SimulatedJob {
    Job job;  ///< complete: models as meshes, scans as points, files named but not written
    Truth truth;
    Cell cell;                         ///< the cell as simulated, workpiece at its true pose
    std::vector<SimulatedScan> scans;  ///< per scan, what each point hit (same points as job.scans)
};

/// Points datum face `face` (0: +x wall, 1: +y wall, 2: floor) must get in every scan.
std::size_t required_face_points(const ScenarioOptions& options, const Truth& truth, int face);

/// A pose from Table 4: origin (mm) and euler_xyz_deg (α, β, γ).
struct PaperPose {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    Eigen::Vector3d euler_deg = Eigen::Vector3d::Zero();
};
/// Table 4, measured (probed, treated as true) pose of test 1..5. Throws std::invalid_argument otherwise.
PaperPose paper_measured_pose(int test);
/// Table 4, pose located by the paper's system in test 1..5.
PaperPose paper_located_pose(int test);
/// Nominal datum of the paper's workpiece (§4): corner at (-76.20, -12.70, 20.32) mm, euler 0.
PaperPose paper_nominal_pose();

/// The paper's experiment, test 1..5: two step-shaped fiducial blocks of unique shape on the pallet, the
/// workpiece at Table 4's measured pose, six scans (two each at A = 0, 45, 90 degrees) from operator-like
/// viewpoints that vary with the seed; each scan sees the three datum faces and at least one fiducial.
SimulatedJob simulate_paper_test(int test, std::uint64_t seed = 1, const ScenarioOptions& options = {});

/// A cell never seen: 2 or 3 random fiducial blocks of unique shape, a random workpiece (notched bar or
/// L-section bar) with a datum corner, perturbed from nominal by a few mm and degrees; scans as above.
SimulatedJob simulate_random_cell(std::uint64_t seed = 1, const ScenarioOptions& options = {});

/// Probing as a person does it: each fiducial's probed pose moved off by its probing uncertainty (pose_sigma
/// per axis in translation, pose_sigma over half the block's size in each turn, about the block's centre),
/// drawn from `seed`. The truth keeps the fiducials where they are.
void disturb_probing(Job& job, std::uint64_t seed);

}  // namespace partloc::sim
