#pragma once
// The subcommands of build/partloc (SPEC "Commands"). Each returns the process exit code.
#include <cstdint>
#include <string>

namespace partloc::cli {

/// How much a command tells on stderr while it works: each stage and each scan as it ends, or nothing.
enum class Progress { Auto, On, Off };  ///< Auto: on when stderr is a terminal

/// Whether `p` tells: On, or Auto on a terminal.
bool telling(Progress p);

/// `partloc run JOB --out DIR`: 0 located, 2 bad input, 3 not located. With `cache`, the prepared fiducial
/// models are kept in `cache_dir` (io::ModelCache::default_dir() when empty) between jobs.
int command_run(const std::string& job_file, const std::string& out_dir, int threads, std::uint64_t seed,
                const std::string& cache_dir, bool cache, Progress progress = Progress::Auto);

/// `partloc demo [--out DIR]`: the paper's experiment re-created in the virtual cell; prints the table of
/// true vs located poses. Writes each test's job and results under DIR when given.
int command_demo(const std::string& out_dir, std::uint64_t seed, int threads,
                 Progress progress = Progress::Auto);

/// `partloc check JOB`: loads and checks the job and its files, prints what a run would take and the
/// warnings that can be seen before registering; 0, or 2 for bad input (one line naming the file).
int command_check(const std::string& job_file);

/// `partloc simulate --out DIR [--seed N]`: writes one virtual job (scans, models, job.yaml, truth.json).
int command_simulate(const std::string& out_dir, std::uint64_t seed);

}  // namespace partloc::cli
