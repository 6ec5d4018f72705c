// The benchmark driver (issue 3). Figures go to BENCHMARK.md with the commands that produced them;
// bench/run_all.sh regenerates every table.
//
//   partloc_bench counts [first_seed] [cells]
//       partloc over many generated cells: how scans end, the workpiece's error.
//   partloc_bench compare --method partloc|open3d|paper --seed N [--spacing MM] [--noise MM]
//                         [--positions P] [--per-position K] [--stock] [--isolate] [--header]
//       --stock: partloc also builds the stock model (off: like for like with the baselines, which do not);
//       --cache DIR: partloc keeps its prepared fiducial models in DIR (io/model_cache.hpp); a second run
//       with the same DIR reads them instead of preparing them (a note says which);
//       --isolate: each scan cut down to the fiducial it sees best (a check that a method works without
//       clutter; the workpiece is cut away too).
//       one method on one generated cell, in this process: one table row (scans right / wrong / rejected,
//       workpiece origin and rotation error, wall time and peak memory of the method alone).
//   partloc_bench header         the column names of the rows.
//   partloc_bench nearest        SampleGrid against KDTreeFlann on the fits' nearest-sample queries.
//   partloc_bench outliers [CLOUD.ply]
//                                our statistical outlier filter (core/cloud_stats) against Open3D's, same
//                                points.
//   partloc_bench normals        our normals (core/normals) against Open3D's EstimateNormals, same points.
//   partloc_bench stock [--seed N] [--spacing MM] [--sweep]
//                                our stock mesh (core/stock) against Open3D's Poisson, same merged points:
//                                time and distance to the true workpiece.
//   partloc_bench scaling ...    the same as compare --method partloc (a name for the scaling runs).
//
// Exit codes: 0 a row was printed (whatever the method found), 2 bad arguments, 4 the generator could not
// lay out this seed's cell, 5 the method is not built (paper without PCL).
#include <malloc.h>
#include <open3d/geometry/BoundingVolume.h>
#include <open3d/utility/Logging.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <optional>
#include <string>
#include <vector>

#include "common.hpp"
#include "open3d_baseline.hpp"
#include "paper_baseline.hpp"
#include "partloc/io/model_cache.hpp"
#include "partloc/pipeline/run.hpp"

namespace partloc::bench {

int counts_main(int argc, char** argv);
int nearest_main(int argc, char** argv);
int normals_main(int argc, char** argv);
int outliers_main(int argc, char** argv);
int stock_main(int argc, char** argv);

namespace {

int usage() {
    std::fprintf(
        stderr,
        "usage: partloc_bench counts [first_seed] [cells]\n"
        "       partloc_bench compare --method partloc|open3d|paper --seed N [--spacing MM] [--noise MM]\n"
        "                             [--positions P] [--per-position K] [--stock] [--isolate] [--header]\n"
        "                             [--cache DIR]  (partloc: prepared models kept in DIR between runs)\n"
        "       partloc_bench scaling (as compare, method partloc)\n");
    return 2;
}

MethodOutcome run_partloc(const Job& job, std::uint64_t seed, bool stock, io::ModelCache* cache,
                          std::vector<std::string>& notes) {
    RunSettings rs;
    rs.seed = seed;
    rs.build_stock = stock;
    rs.models = cache;
    const JobResult r = run_job(job, rs);
    if (cache)
        notes.push_back("model cache " + cache->dir().string() + ": " + std::to_string(cache->hits()) +
                        " read, " + std::to_string(cache->misses()) + " prepared");
    MethodOutcome out;
    for (std::size_t i = 0; i < r.scans.size(); ++i)
        if (!r.scans[i].valid)
            notes.push_back("scan " + std::to_string(i) + " rejected: " + r.scans[i].reason);
    for (const auto& s : r.scans)
        out.T_machine_scan.push_back(s.valid ? std::optional<Eigen::Isometry3d>(s.T_machine_scan)
                                             : std::nullopt);
    out.located = r.workpiece.valid;
    out.T_machine_workpiece = r.workpiece.T_machine_workpiece;
    out.message = r.workpiece.reason;
    return out;
}

/// A check of the method, not a benchmark: each scan keeps only its points within 60 mm of the centre of the
/// fiducial it sees best (by truth), so registration meets no clutter. The workpiece is cropped away with the
/// rest, so it cannot be located.
void isolate_fiducials(sim::SimulatedJob& cell) {
    for (std::size_t i = 0; i < cell.job.scans.size(); ++i) {
        std::string best;
        std::size_t most = 0;
        for (const auto& [name, n] : cell.truth.scans[i].fiducial_points)
            if (n > most) most = n, best = name;
        for (const auto& f : cell.job.fiducials) {
            if (f.name != best || !f.model.mesh) continue;
            const Eigen::Vector3d centre = cell.truth.scans[i].T_machine_scan.inverse() *
                                           fiducial_at(cell.job.machine, f, cell.job.scans[i].axes) *
                                           f.model.mesh->GetAxisAlignedBoundingBox().GetCenter();
            auto kept = std::make_shared<open3d::geometry::PointCloud>();
            for (const auto& p : cell.job.scans[i].points->points_)
                if ((p - centre).norm() < 60.0) kept->points_.push_back(p);
            cell.job.scans[i].points = kept;
        }
    }
}

void print_header() {
    std::printf("%-8s %5s %5s %9s %5s %5s %8s %7s %9s %8s %8s %8s %8s %7s\n", "method", "seed", "scans",
                "pts/scan", "right", "wrong", "rejected", "located", "origin_mm", "rot_deg", "wall_s",
                "peak_MiB", "input_MiB", "sim_s");
}

int compare_main(int argc, char** argv, std::string method) {
    CellSpec spec;
    bool header = false, stock = false, isolate = false;
    std::string cache_dir;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const bool has_value = i + 1 < argc;
        if (a == "--method" && has_value)
            method = argv[++i];
        else if (a == "--seed" && has_value)
            spec.seed = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--spacing" && has_value)
            spec.spacing = std::atof(argv[++i]);
        else if (a == "--noise" && has_value)
            spec.noise = std::atof(argv[++i]);
        else if (a == "--positions" && has_value)
            spec.positions = std::atoi(argv[++i]);
        else if (a == "--per-position" && has_value)
            spec.per_position = std::atoi(argv[++i]);
        else if (a == "--stock")
            stock = true;
        else if (a == "--cache" && has_value)
            cache_dir = argv[++i];
        else if (a == "--isolate")
            isolate = true;
        else if (a == "--header")
            header = true;
        else
            return usage();
    }
    if (method.empty() && header) {
        print_header();
        return 0;
    }
    if (method != "partloc" && method != "open3d" && method != "paper") return usage();
    if (spec.spacing <= 0 || spec.positions < 1 || spec.per_position < 1) return usage();
    if (method == "paper" && !paper_pipeline_available()) {
        std::fprintf(stderr, "partloc_bench: the paper's pipeline is not built (no PCL)\n");
        return 5;
    }
    if (header) print_header();

    const auto ts = std::chrono::steady_clock::now();
    sim::SimulatedJob cell;
    try {
        cell = make_cell(spec);
    } catch (const std::exception& e) {
        std::printf("%-8s %5llu skipped: %s\n", method.c_str(), static_cast<unsigned long long>(spec.seed),
                    e.what());
        return 4;
    }
    const double sim_s = seconds_since(ts);
    cell.scans.clear();  // what each ray hit: only the judge's truth is kept
    cell.cell = sim::Cell{};
    malloc_trim(0);  // so that the input's size below is the job's, not the simulator's leftovers
    std::size_t points = 0;
    for (const auto& s : cell.job.scans) points += s.points->points_.size();

    if (isolate) isolate_fiducials(cell);
    std::optional<io::ModelCache> cache;
    if (!cache_dir.empty()) cache.emplace(cache_dir);
    const double input_mib = current_memory_mib();
    reset_peak_memory();
    const auto t0 = std::chrono::steady_clock::now();
    MethodOutcome out;
    std::vector<std::string> notes;
    if (method == "partloc")
        out = run_partloc(cell.job, spec.seed, stock, cache ? &*cache : nullptr, notes);
    else if (method == "open3d") {
        Open3DSettings o;
        o.seed = spec.seed;
        out = run_open3d(cell.job, o);
    } else {
        PaperSettings p;
        p.seed = spec.seed;
        out = run_paper(cell.job, p);
    }
    const double wall = seconds_since(t0);
    const double peak = peak_memory_mib();
    const Verdict v = judge(out, cell);
    const std::size_t n = cell.job.scans.size();
    std::printf("%-8s %5llu %5zu %9zu %5d %5d %8d %7s %9.4f %8.4f %8.2f %8.0f %8.0f %7.1f\n", method.c_str(),
                static_cast<unsigned long long>(spec.seed), n, n ? points / n : 0, v.right, v.wrong,
                v.rejected, v.located ? "yes" : "no", v.origin_mm, v.rotation_deg, wall, peak, input_mib,
                sim_s);
    if (!v.located && !out.message.empty())
        std::printf("# %s seed %llu: %s\n", method.c_str(), static_cast<unsigned long long>(spec.seed),
                    out.message.c_str());
    for (const auto& n : notes)
        std::printf("# %s seed %llu: %s\n", method.c_str(), static_cast<unsigned long long>(spec.seed),
                    n.c_str());
    std::fflush(stdout);
    return 0;
}

}  // namespace
}  // namespace partloc::bench

int main(int argc, char** argv) {
    using namespace partloc::bench;
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    if (argc < 2) return usage();
    const std::string cmd = argv[1];
    if (cmd == "counts") return counts_main(argc - 1, argv + 1);
    if (cmd == "nearest") return nearest_main(argc - 1, argv + 1);
    if (cmd == "outliers") return outliers_main(argc - 1, argv + 1);
    if (cmd == "normals") return normals_main(argc - 1, argv + 1);
    if (cmd == "stock") return stock_main(argc - 1, argv + 1);
    if (cmd == "compare") return compare_main(argc - 1, argv + 1, "");
    if (cmd == "header") {
        print_header();
        return 0;
    }
    if (cmd == "scaling") return compare_main(argc - 1, argv + 1, "partloc");
    return usage();
}
