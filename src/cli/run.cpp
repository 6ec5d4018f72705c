// `partloc run JOB --out DIR` (SPEC "Commands"): load and check the job, run it, write DIR, print a summary.
#include "partloc/pipeline/run.hpp"

#include <open3d/utility/Logging.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <optional>
#include <sstream>

#include "commands.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/io/job_io.hpp"
#include "partloc/io/model_cache.hpp"
#include "partloc/io/output_lock.hpp"
#include "partloc/io/result_io.hpp"

namespace partloc::cli {

namespace {

constexpr int kLocated = 0;
constexpr int kFailed = 1;  // the output could not be written, or a fault in the program itself
constexpr int kBadInput = 2;
constexpr int kNotLocated = 3;

/// The problem as one line on stderr: messages from yaml-cpp or the file system may hold line breaks.
int complain(const std::string& message, int code) {
    std::string line = message;
    for (char& c : line)
        if (c == '\n' || c == '\r') c = ' ';
    std::cerr << "partloc: " << line << std::endl;
    return code;
}

std::string fixed(double v, int decimals) {
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.*f", decimals, v);
    return buffer;
}

std::string triple(const Eigen::Vector3d& v, int decimals) {
    return "[" + fixed(v.x(), decimals) + ", " + fixed(v.y(), decimals) + ", " + fixed(v.z(), decimals) + "]";
}

/// The outcome's word, coloured on a terminal (green located, amber located with warnings, red not located;
/// none when NO_COLOR is set): the same words as the report's banner.
std::string outcome_word(const JobResult& result, bool colour) {
    const char* word = !result.workpiece.valid   ? "NOT LOCATED"
                       : result.warnings.empty() ? "located"
                                                 : "located with warnings";
    if (!colour) return word;
    const char* code = !result.workpiece.valid   ? "\033[1;31m"
                       : result.warnings.empty() ? "\033[1;32m"
                                                 : "\033[1;33m";
    return std::string(code) + word + "\033[0m";
}

void print_summary(std::ostream& out, const std::string& job_file, const Job& job, const JobResult& result,
                   bool colour) {
    const std::string& u = job.units;
    const int d = u == "m" ? 6 : u == "in" ? 4 : 3;
    out << "partloc run " << job_file << ": " << job.scans.size() << " scans, " << job.fiducials.size()
        << " fiducials, units " << u << "\n";
    for (const ScanResult& s : result.scans) {
        out << "  " << s.file << "  ";
        if (s.valid) {
            std::string fids;
            for (const auto& f : s.fiducials) fids += (fids.empty() ? "" : ",") + f;
            out << "registered by " << fids << "  score " << fixed(s.score, 2) << "  rmse "
                << fixed(s.rmse, d) << " " << u << "\n";
        } else {
            out << "rejected: " << s.reason << "\n";
        }
    }
    const WorkpieceResult& w = result.workpiece;
    if (!result.workpiece.valid) {
        out << "workpiece: " << outcome_word(result, colour) << ": " << w.reason << "\n";
        return;
    }
    const Eigen::Isometry3d& nominal = job.workpiece.T_machine_workpiece;
    out << "workpiece: " << outcome_word(result, colour) << "  origin "
        << triple(w.T_machine_workpiece.translation(), d) << " " << u << "  euler_xyz_deg "
        << triple(euler_xyz_deg(w.T_machine_workpiece.linear()), 3) << "\n";
    const PoseError e = pose_error(w.T_machine_workpiece, nominal);
    out << "  deviation from nominal: origin "
        << triple(w.T_machine_workpiece.translation() - nominal.translation(), d) << " " << u << " ("
        << fixed(e.translation, d) << "), rotation " << fixed(e.rotation_deg, 3) << " deg\n";
    out << "  fit rmse " << fixed(w.rmse, d) << " " << u << " over " << w.points << " points\n";
    if (w.uncertainty.available)
        out << "  uncertainty_95: origin +- " << triple(w.uncertainty.origin, d) << " " << u << ", euler +- "
            << triple(w.uncertainty.euler_deg, 3) << " deg\n";
    if (!result.warnings.empty()) {
        out << "  " << result.warnings.size() << " warning" << (result.warnings.size() > 1 ? "s" : "")
            << ": look at " << (result.warnings.size() > 1 ? "them" : "it") << " before cutting\n";
        for (const auto& warning : result.warnings) out << "  warning: " << warning << "\n";
    }
}

}  // namespace

bool telling(Progress p) {
    return p == Progress::On || (p == Progress::Auto && ::isatty(STDERR_FILENO) == 1);
}

int command_run(const std::string& job_file, const std::string& out_dir, int threads, std::uint64_t seed,
                const std::string& cache_dir, bool cache, Progress progress) {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    const bool tell = telling(progress);

    Job job;
    try {
        if (tell) std::cerr << "partloc: reading " << job_file << " and its files" << std::endl;
        job = io::load_job(job_file, io::LoadOptions{threads});
        io::check_job_geometry(job, job_file);
    } catch (const io::InputError& e) {
        return complain(e.what(), kBadInput);
    } catch (const std::exception& e) {
        // Anything else that stops the job being read (a file system error, a file too big for memory) is
        // still a problem with the input.
        return complain(job_file + ": " + e.what(), kBadInput);
    }
    {
        std::error_code ec;
        if (std::filesystem::exists(out_dir, ec) && !std::filesystem::is_directory(out_dir, ec))
            return complain(out_dir + ": --out names a file, not a folder", kBadInput);
    }

    // One run at a time into a folder; taken before the run, so that a second run is refused at once and not
    // after its work (io/output_lock.hpp). Held until the files are written.
    std::optional<io::OutputFolderLock> lock;
    try {
        lock.emplace(out_dir);
    } catch (const io::FolderBusy& e) {
        return complain(e.what(), kBadInput);
    } catch (const std::exception& e) {
        return complain(std::string("cannot write the output: ") + e.what(), kFailed);
    }

    // The fiducials' prepared models, kept between jobs (io/model_cache.hpp); without a folder to keep them
    // in, each job prepares its own.
    std::optional<io::ModelCache> models;
    if (cache) {
        const std::filesystem::path dir =
            cache_dir.empty() ? io::ModelCache::default_dir() : std::filesystem::path(cache_dir);
        if (!dir.empty()) models.emplace(dir);
    }
    JobResult result;
    try {
        RunSettings settings;
        settings.threads = threads;
        settings.seed = seed;
        settings.models = models ? &*models : nullptr;
        if (tell)
            settings.progress = [](const std::string& what) {
                std::cerr << "partloc: " << what << std::endl;
            };
        result = run_job(job, settings);
    } catch (const std::invalid_argument& e) {
        return complain(job_file + ": " + e.what(), kBadInput);
    } catch (const std::exception& e) {
        return complain(std::string("internal error: ") + e.what(), kFailed);
    }

    std::vector<std::filesystem::path> written;
    try {
        written = io::write_outputs(out_dir, job, result, job_file);
    } catch (const std::exception& e) {
        return complain(std::string("cannot write the output: ") + e.what(), kFailed);
    }

    // The cache never changes the result; what it could not do is said, and the job goes on without it.
    if (models)
        for (const auto& p : models->problems()) std::cerr << "partloc: model cache: " << p << std::endl;
    for (const auto& w : job.warnings) std::cerr << "partloc: warning: " << w << std::endl;
    print_summary(std::cout, job_file, job, result,
                  ::isatty(STDOUT_FILENO) == 1 && std::getenv("NO_COLOR") == nullptr);
    std::cout << "wrote";
    for (const auto& p : written) std::cout << " " << p.string();
    std::cout << std::endl;
    return result.workpiece.valid ? kLocated : kNotLocated;
}

}  // namespace partloc::cli
