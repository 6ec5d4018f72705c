#pragma once
// The job file (SPEC "Job file", docs/job.md): YAML, or JSON, read into a partloc::Job with every model and
// scan loaded and converted to the job's units.
#include <filesystem>

#include "partloc/io/input_error.hpp"
#include "partloc/pipeline/job.hpp"

namespace partloc::io {

struct LoadOptions {
    int threads = 0;  ///< threads reading model and scan files; 0: all cores. The Job does not depend on it.
};

/// Reads and checks the job file, then reads every file it names (relative paths are relative to the job
/// file's folder), scaling each to the job's units (a file entry `{file: F, units: m}` in an mm job is
/// multiplied by 1000). Throws InputError on the first problem: the message names the job file and the
/// field, e.g. "job.yaml: fiducials[1].pose.euler_xyz_deg: expected 3 numbers, found 2 (line 14)", or the
/// data file and what is wrong with it. The whole job is checked before any data file is read; of several
/// bad data files, the first in the job's order is reported.
Job load_job(const std::filesystem::path& job_file, const LoadOptions& options = {});

/// The checks of extent and rank that the algorithms need of a job's data, made before it is run so that a
/// degenerate file is refused naming it (exit 2) instead of failing inside a library: each scan at least 10
/// points spread in three dimensions, each fiducial at least 4 in three dimensions and at most 1000 times
/// the largest scan, reference surfaces and final part at least a surface (3 points not on a line), no
/// coordinate beyond 10 km, and scanner.point_spacing at least a hundredth of what the scans can have.
/// Open3D's hull and Delaunay (Qhull) throw on planar or collinear points, its KD-tree and voxel grid on
/// points of no extent or of more than 2^31 cells along an axis. Throws InputError naming the file (or
/// `job_name` and the field). load_job leaves it to the caller: a loaded job may be a fragment (tests).
void check_job_geometry(const Job& job, const std::string& job_name);

}  // namespace partloc::io
