// `partloc simulate --out DIR [--seed N]` (SPEC "Commands"): one virtual job that `partloc run` accepts.
#include <filesystem>
#include <iostream>

#include "commands.hpp"
#include "partloc/io/job_writer.hpp"
#include "partloc/sim/scenario.hpp"

namespace partloc::cli {

int command_simulate(const std::string& out_dir, std::uint64_t seed) {
    namespace fs = std::filesystem;
    try {
        const sim::SimulatedJob s = sim::simulate_random_cell(seed);
        io::write_job(out_dir, s.job);
        io::write_truth(fs::path(out_dir) / "truth.json", s.truth);
        std::size_t points = 0;
        for (const auto& scan : s.job.scans) points += scan.points->points_.size();
        std::cout << "partloc simulate: wrote " << (fs::path(out_dir) / "job.yaml").string() << " ("
                  << s.job.fiducials.size() << " fiducials, " << s.job.scans.size() << " scans, " << points
                  << " points) and truth.json\n";
        return 0;
    } catch (const std::exception& e) {
        std::cerr << "partloc simulate: " << e.what() << "\n";
        return 2;
    }
}

}  // namespace partloc::cli
