// build/partloc: the command line (SPEC "Commands").
#include <CLI/CLI.hpp>
#include <iostream>

#include "commands.hpp"

int main(int argc, char** argv) {
    CLI::App app{"partloc: locate a workpiece in a CNC machine from 3D scans and fiducials"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "partloc " PARTLOC_VERSION);

    std::string job_file, out_dir, demo_out, sim_out, cache_dir;
    bool no_cache = false, progress = false, quiet = false;
    int threads = 0;
    std::uint64_t seed = 1, demo_seed = 1, sim_seed = 1;

    auto* run = app.add_subcommand("run", "localize each scan, merge, locate the workpiece, write DIR");
    run->add_option("job", job_file, "job file (YAML or JSON)")->required();
    run->add_option("--out", out_dir, "output folder")->required();
    run->add_option("--threads", threads, "worker threads (0: all cores)");
    run->add_option("--seed", seed, "seed for every random choice");
    auto* cache = run->add_option("--cache", cache_dir,
                                  "keep prepared fiducial models in this folder between jobs (default: "
                                  "$PARTLOC_CACHE, else $XDG_CACHE_HOME/partloc, else ~/.cache/partloc)");
    run->add_flag("--no-cache", no_cache, "prepare the fiducial models afresh; keep nothing")
        ->excludes(cache);
    auto* progress_flag =
        run->add_flag("--progress", progress, "tell each stage and scan on stderr (default: on a terminal)");
    run->add_flag("--quiet", quiet, "tell nothing while working")->excludes(progress_flag);

    std::string check_file;
    auto* check =
        app.add_subcommand("check", "load and check a job and its files; print what a run would take");
    check->add_option("job", check_file, "job file (YAML or JSON)")->required();

    auto* demo = app.add_subcommand("demo", "the paper's experiment re-created in a virtual cell");
    demo->add_option("--out", demo_out, "write each test's job and results here");
    demo->add_option("--seed", demo_seed, "seed of the virtual scanner");
    demo->add_option("--threads", threads, "worker threads (0: all cores)");
    auto* demo_progress =
        demo->add_flag("--progress", progress, "tell each test and scan on stderr (default: on a terminal)");
    demo->add_flag("--quiet", quiet, "tell nothing while working")->excludes(demo_progress);

    auto* simulate = app.add_subcommand("simulate", "write one virtual job with its truth.json");
    simulate->add_option("--out", sim_out, "output folder")->required();
    simulate->add_option("--seed", sim_seed, "seed of the virtual cell and scanner");

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        const int code = app.exit(e);
        return code == 0 ? 0 : 2;
    }
    using partloc::cli::Progress;
    const Progress tell = progress ? Progress::On : quiet ? Progress::Off : Progress::Auto;
    if (*run) return partloc::cli::command_run(job_file, out_dir, threads, seed, cache_dir, !no_cache, tell);
    if (*check) return partloc::cli::command_check(check_file);
    if (*demo) return partloc::cli::command_demo(demo_out, demo_seed, threads, tell);
    if (*simulate) return partloc::cli::command_simulate(sim_out, sim_seed);
    return 2;
}
