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

}  // namespace partloc::io
