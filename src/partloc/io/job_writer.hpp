#pragma once
// Writes a job in memory to disk (SPEC "Job file"): job.yaml, and every model and scan at its relative
// `file` path. Used by `partloc simulate` and `partloc demo --out`. Every file appears whole or not at all.
#include <filesystem>

#include "partloc/pipeline/job.hpp"
#include "partloc/sim/truth.hpp"

namespace partloc::io {

/// Writes dir/job.yaml and, under dir, each fiducial model, the workpiece's reference surfaces, final
/// part and datums' surfaces (a mesh as STL, PLY or OBJ by its file's extension; points as binary PLY) and
/// each scan (binary PLY, float x y z, scan frame), through the writers of cloud_io.hpp. Lengths are written
/// in job.units as they are. Throws std::invalid_argument for a model or scan without data or without a
/// relative file name inside dir, and std::runtime_error naming the file when one cannot be written.
void write_job(const std::filesystem::path& dir, const Job& job);

/// Writes the truth of a simulated job as JSON (poses as 4x4 row-major matrices and as origin and
/// euler_xyz_deg, per-scan point counts).
void write_truth(const std::filesystem::path& path, const sim::Truth& truth);

}  // namespace partloc::io
