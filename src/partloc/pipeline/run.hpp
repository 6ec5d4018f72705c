#pragma once
// The whole job (paper §3.4): localize each scan by its fiducials (processor), merge the registered scans,
// fit the nominal reference surfaces (part) and build the stock and the located final part.
#include <cstdint>
#include <functional>
#include <string>

#include "partloc/core/localize.hpp"
#include "partloc/pipeline/config.hpp"
#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc {

/// Where prepared fiducial models are kept from one job to the next (io::ModelCache keeps them on disk): the
/// fiducials are the same job after job, and preparing them (sampling, the coarse map, the PPF table) is
/// work done before any scan can start. prepare() returns what prepare_model returns for the same
/// arguments; it is called from several threads at once.
class ModelStore {
  public:
    virtual ~ModelStore() = default;
    virtual PreparedModel prepare(const std::string& name, const open3d::geometry::TriangleMesh* mesh,
                                  const open3d::geometry::PointCloud* points, double dense_spacing,
                                  double sampling) = 0;
};

struct RunSettings {
    int threads = 0;          ///< 0: all cores. Results do not depend on it.
    std::uint64_t seed = 1;   ///< seeds every random choice; same seed, same result
    bool build_stock = true;  ///< triangulate the merged workpiece points into result.stock
    Config config;            ///< every tuning constant (pipeline/config.hpp)
    /// Prepared fiducial models kept between jobs; null: each job prepares its own (prepare_model).
    ModelStore* models = nullptr;
    /// Told, in a sentence, of each stage as it starts and of each scan as its registration ends (from the
    /// worker threads, one call at a time); never changes a result. Empty: nothing is told.
    std::function<void(const std::string&)> progress;
};

/// What every scan and fiducial of a job share before any scan is registered: run_job's first step.
struct JobPreparation {
    std::vector<Scale> scales;          ///< each scan's: the scanner's specification, or measured on the scan
    double spacing = 0.0;               ///< the scans' median point spacing (job units)
    double sampling = 0.0;              ///< the global fit's sampling (job units)
    std::vector<PreparedModel> models;  ///< the fiducials', in the job's order
    Eigen::AlignedBox3d region;         ///< where the workpiece's points are looked for, machine0
};

/// Measures each scan's scale, chooses the global fit's sampling from the fiducials' size and the scans'
/// spacing (ScaleSettings), and prepares every fiducial's model.
JobPreparation prepare_job(const Job& job, const RunSettings& settings = {});

/// Runs the job. Never throws for "no solution": a scan that no fiducial fits is rejected with a reason, a
/// workpiece that cannot be fitted is not located with a reason. Throws std::invalid_argument only for a
/// job that is inconsistent in itself (an axis named in moves_with that the machine lacks, say).
JobResult run_job(const Job& job, const RunSettings& settings = {});

}  // namespace partloc
