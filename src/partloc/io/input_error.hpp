#pragma once
// The one error of the I/O layer (STYLE "One error policy"): bad input throws an InputError whose message is
// one line naming the file and the problem, e.g.
//   scans/scan_01.ply: file is truncated (expected 250000 vertices, found 1203)
//   job.yaml: fiducials[1].pose.euler_xyz_deg: expected 3 numbers, found 2 (line 14)
#include <stdexcept>
#include <string>

namespace partloc::io {

struct InputError : std::runtime_error {
    /// `file` as the user wrote it (a path in the job, or the job file itself); `problem` without the file.
    InputError(std::string file, std::string problem)
        : std::runtime_error(file + ": " + problem), file_(std::move(file)), problem_(std::move(problem)) {}

    const std::string& file() const { return file_; }
    const std::string& problem() const { return problem_; }

  private:
    std::string file_;
    std::string problem_;
};

}  // namespace partloc::io
