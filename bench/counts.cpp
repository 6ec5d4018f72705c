// Counts, over many generated cells, how scans end: registered right, registered wrong, rejected while a
// fiducial was in view, rejected with none in view. And the located workpiece's error against truth.
//   build/bench/partloc_bench counts [first_seed] [cells]
// Results go to BENCHMARK.md with the command that produced them.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>

#include "common.hpp"
#include "partloc/pipeline/run.hpp"
#include "partloc/sim/scenario.hpp"

namespace partloc::bench {

int counts_main(int argc, char** argv) {
    const std::uint64_t first = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : 100;
    const int cells = argc > 2 ? std::atoi(argv[2]) : 10;
    int right = 0, wrong = 0, missed = 0, none_in_view = 0, located = 0;
    double worst_origin = 0, worst_rotation = 0, sum_origin = 0, seconds = 0;
    std::printf("seed  registered  wrong  missed  origin_mm  rotation_deg  run_s\n");
    for (int c = 0; c < cells; ++c) {
        const std::uint64_t seed = first + c;
        sim::SimulatedJob sj;
        try {
            sj = sim::simulate_random_cell(seed);
        } catch (const std::exception& e) {  // the generator could not lay out this seed's cell
            std::printf("%4llu  skipped: %s\n", static_cast<unsigned long long>(seed), e.what());
            continue;
        }
        RunSettings rs;
        rs.build_stock = false;
        const auto t0 = std::chrono::steady_clock::now();
        const JobResult r = run_job(sj.job, rs);
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        seconds += s;
        int reg = 0, wr = 0, mi = 0;
        for (std::size_t i = 0; i < r.scans.size(); ++i) {
            if (!r.scans[i].valid) {
                (fiducial_in_view(sj, i) ? mi : none_in_view) += 1;
                continue;
            }
            (registered_right(r.scans[i].T_machine_scan, sj, i) ? reg : wr) += 1;
        }
        right += reg;
        wrong += wr;
        missed += mi;
        double eo = -1, er = -1;
        if (r.workpiece.valid) {
            ++located;
            const PoseError e = pose_error(r.workpiece.T_machine_workpiece, sj.truth.T_machine_workpiece);
            eo = e.translation;
            er = e.rotation_deg;
            worst_origin = std::max(worst_origin, eo);
            worst_rotation = std::max(worst_rotation, er);
            sum_origin += eo;
        }
        std::printf("%4llu  %10d  %5d  %6d  %9.4f  %12.4f  %5.1f\n", static_cast<unsigned long long>(seed),
                    reg, wr, mi, eo, er, s);
        std::fflush(stdout);
    }
    std::printf(
        "\n%d cells, %d scans: %d registered right, %d registered WRONG, %d rejected with a fiducial in "
        "view, %d rejected with none in view\n",
        cells, right + wrong + missed + none_in_view, right, wrong, missed, none_in_view);
    std::printf(
        "located %d of %d; origin error mean %.4f mm, worst %.4f mm; rotation worst %.4f deg; %.1f s per "
        "job\n",
        located, cells, located ? sum_origin / located : 0.0, worst_origin, worst_rotation, seconds / cells);
    return 0;
}

}  // namespace partloc::bench
