#pragma once
// What every benchmark method shares: the generated cell, the judge against truth, and the measures (wall
// time, peak memory). A method takes a Job and returns a MethodOutcome; the judge never shows it the truth.
#include <Eigen/Geometry>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "partloc/pipeline/job.hpp"
#include "partloc/sim/scenario.hpp"

namespace partloc::bench {

/// One generated cell: sim::simulate_random_cell(seed) with the scanner and scan plan below.
struct CellSpec {
    std::uint64_t seed = 100;
    double spacing = 0.383;  ///< mm between rays at the working distance (the paper's NextEngine)
    double noise = 0.13;     ///< mm, 1 sigma along the line of sight
    int positions = 3;       ///< A values 0..90 deg, evenly spaced (the paper: 0, 45, 90)
    int per_position = 2;    ///< scans at each A value (the paper: 2)
};

/// Throws std::runtime_error when the generator cannot lay out this seed's cell.
sim::SimulatedJob make_cell(const CellSpec& spec);

/// What a method found. T_machine_scan is empty for a rejected scan.
struct MethodOutcome {
    std::vector<std::optional<Eigen::Isometry3d>> T_machine_scan;
    bool located = false;
    Eigen::Isometry3d T_machine_workpiece = Eigen::Isometry3d::Identity();
    std::string message;  ///< why the workpiece was not located
};

/// Judged against truth: a scan is right when its T_machine_scan moves the true workpiece origin < 0.5 mm
/// and rotates < 0.2 deg.
struct Verdict {
    int right = 0, wrong = 0, rejected = 0;
    bool located = false;
    double origin_mm = -1.0, rotation_deg = -1.0;  ///< -1 when not located
};
Verdict judge(const MethodOutcome& outcome, const sim::SimulatedJob& cell);

/// A scan is registered right when its T_machine_scan moves the true workpiece origin less than 0.5 mm and
/// turns it less than 0.2 degrees from the truth.
bool registered_right(const Eigen::Isometry3d& T_machine_scan, const sim::SimulatedJob& cell,
                      std::size_t scan);

/// A scan "sees a fiducial" when one fiducial got at least this many true returns in it.
constexpr std::size_t kSeenPoints = 4000;
bool fiducial_in_view(const sim::SimulatedJob& cell, std::size_t scan);

// fiducial_at and workpiece_region: pipeline/job.hpp, shared with `run`.

/// Maps the points of a scan taken at its axis values to the machine frame with the workpiece's axes at 0.
Eigen::Isometry3d T_machine0_scan(const Job& job, const Scan& scan, const Eigen::Isometry3d& T_machine_scan);

/// Poisson-disk point model of a fiducial (partloc's sample_mesh, paper §3.2 step 5) at `spacing`, in the
/// fiducial frame, with the mesh's outward normals. Samples on faces that look straight down in the machine
/// (the face the block stands on) are left out. With `feature_only`, only the samples on the three planes of
/// the fiducial feature are kept (the planes x = 0, y = 0, z = 0 of the fiducial frame, which meet at its
/// origin), as the paper's models held only the feature's surfaces (§3.2 step 4, Figs. 2-5).
std::shared_ptr<open3d::geometry::PointCloud> fiducial_points(const Fiducial& f, double spacing,
                                                              bool feature_only = false);

/// Poisson-disk samples of the nominal reference surfaces (machine frame, axes 0) with normals.
std::shared_ptr<open3d::geometry::PointCloud> reference_points(const Job& job, double spacing);

/// Largest diagonal among the fiducial models' bounding boxes.
double fiducial_diagonal(const Job& job);

/// Starts a new peak-memory window (Linux: /proc/self/clear_refs), so the peak read later belongs to the
/// method alone plus what was resident (the job) when it started. Returns false where the kernel refuses.
bool reset_peak_memory();
/// Peak resident set size in MiB since reset_peak_memory() (VmHWM), or since the start (ru_maxrss).
double peak_memory_mib();
/// Resident set size now, MiB.
double current_memory_mib();

double seconds_since(std::chrono::steady_clock::time_point t0);

}  // namespace partloc::bench
