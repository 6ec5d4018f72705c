#pragma once
// The paper's processor (§3.4.1) and part (§3.4.2) constructs on PCL, behind an interface of plain arrays so
// that no PCL header meets Open3D's or partloc's in one translation unit. Every length in millimetres; the
// defaults are the paper's Tables 2 and 3 (in metres there) times 1000, squared quantities times 10^6.
#include <array>
#include <cstdint>
#include <vector>

namespace partloc::bench::paper {

using Points = std::vector<std::array<float, 3>>;
using Normals = std::vector<std::array<float, 3>>;
using Matrix4 = std::array<double, 16>;  ///< row-major 4x4 rigid transform

/// Table 2, in mm.
struct ProcessorParams {
    double normal_radius = 1.0;       ///< normal estimation radius (0.001 m)
    double model_voxel = 4.0;         ///< downsampling radius for fiducial features (0.004 m)
    double model_fpfh_radius = 20.0;  ///< FPFH radius for fiducial feature models (0.02 m)
    double scan_voxel = 4.0;          ///< downsampling radius for scan data (0.004 m)
    double scan_fpfh_radius = 20.0;   ///< FPFH radius for scan data (0.02 m)
    int sac_samples = 3;              ///< SAC-IA number of samples
    int sac_randomness = 2;           ///< SAC-IA correspondence randomness
    int sac_iterations = 4000;        ///< SAC-IA maximum iterations
    /// SAC-IA's truncation distance, left at PCL's default of 100 (metres in the paper's data): 10^5 mm.
    double sac_max_distance = 1.0e5;
    int icp_iterations = 400;                  ///< ICP maximum iterations
    double icp_max_distance = 5.0;             ///< ICP maximum correspondence distance (0.005 m)
    double icp_transformation_epsilon = 1e-3;  ///< 1e-9 m^2: PCL compares it with a squared translation
    double icp_fitness_epsilon = 2.54;         ///< 2.54e-6 m^2: PCL compares it with a change of mean squared
                                               ///< distance
    /// §4: a fit succeeds when N_f / sum d^2 exceeds 6,250,000 m^-2 (mean squared distance below
    /// (0.4 mm)^2): 6.25 mm^-2.
    double metric_threshold = 6.25;
    int threads = 0;         ///< OpenMP threads for normals and FPFH; 0: all
    std::uint64_t seed = 1;  ///< SAC-IA draws from std::rand; seeded here for repeatable runs
};

struct FiducialFit {
    bool converged = false;
    Matrix4 T_scan_model{};  ///< maps model points into the scan
    double metric = 0.0;     ///< N_f / sum d^2 over the model points with an ICP correspondence, mm^-2
    std::size_t correspondences = 0;
    double sac_score = 0.0;  ///< SAC-IA's fitness score
};

/// Fits each model to the scan: normals, voxel grid, FPFH, SAC-IA, ICP with normals, the metric (1).
/// `scan` is in the scan frame with the scanner at its origin; models carry outward normals.
std::vector<FiducialFit> fit_fiducials(const Points& scan, const std::vector<Points>& models,
                                       const std::vector<Normals>& model_normals,
                                       const ProcessorParams& params);

/// Table 3, in mm.
struct PartParams {
    double icp_max_distance = 5.0;             ///< 0.005 m
    double icp_transformation_epsilon = 1e-3;  ///< 1e-9 m^2
    double icp_fitness_epsilon = 2.54;         ///< 2.54e-6 m^2
    int icp_iterations = 600;
    double mls_radius = 2.0;     ///< MLS search radius (0.002 m)
    int mls_order = 3;           ///< MLS polynomial fit order
    double mls_sqr_gauss = 4.0;  ///< MLS square gauss parameter (0.002^2 m^2)
    double voxel = 0.5;          ///< final voxel-grid filter (0.0005 m)
    int threads = 0;             ///< OpenMP threads for MLS; 0: all
};

struct PartFit {
    bool converged = false;
    Matrix4 T_data_nominal{};  ///< moves the nominal reference surfaces onto the merged scans
    double fitness = 0.0;      ///< PCL's fitness score (mean squared distance, mm^2)
    std::size_t points = 0;    ///< merged points after MLS and the voxel grid
};

/// The part construct: MLS smoothing of the merged, clipped scans, voxel grid, ICP of the reference
/// surface points (at nominal) onto them.
PartFit fit_part(const Points& merged, const Points& reference, const PartParams& params);

}  // namespace partloc::bench::paper
