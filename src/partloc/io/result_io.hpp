#pragma once
// The output folder (SPEC "Output folder"): result.json, merged.ply, stock.stl, final_part_located.stl,
// report.html. Every file is written whole or not at all.
#include <filesystem>
#include <string>
#include <vector>

#include "partloc/pipeline/job.hpp"
#include "partloc/pipeline/result.hpp"

namespace partloc::io {

/// The text of result.json: SPEC's schema, plus the fields listed in docs/job.md ("result.json"). Lengths in
/// the job's units, angles in degrees. A pose that was not found (a rejected scan's T_machine_scan, the
/// workpiece when not located) is null, never a stand-in identity. The nominal pose is the job's datum.
std::string result_json(const Job& job, const JobResult& result);

/// Writes the output folder `out_dir` (created when missing): merged.ply, stock.stl and
/// final_part_located.stl when the result has them (an old copy left from an earlier run is removed when
/// it has not), report.html, and result.json last, so that a result.json beside them means they are all
/// of this run. `job_name` is the job file as the user named it, for the report. Returns the files written.
/// Throws std::runtime_error naming the file that cannot be written.
std::vector<std::filesystem::path> write_outputs(const std::filesystem::path& out_dir, const Job& job,
                                                 const JobResult& result, const std::string& job_name = "");

}  // namespace partloc::io
