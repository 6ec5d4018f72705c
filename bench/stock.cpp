// The stock model: ours (core/stock.cpp, an IMLS distance meshed by surface nets) against Open3D's screened
// Poisson as partloc used it (build_stock_poisson), on the same merged points, one thread each.
//   build/bench/partloc_bench stock [--seed N] [--spacing MM] [--sweep]
// Points: the merged workpiece points of the cell's job as partloc's pipeline gives them (result.merged:
// machine frame, axes at 0, one point per voxel of the spacing, normals facing the scanners). Truth: the
// cell's workpiece mesh at its true place. Columns: seconds; triangles; distance of the mesh's vertices to
// the true surface (median, 95th percentile, max, mm); coverage: of the true-surface samples (Poisson disk,
// 0.5 mm) within 1 mm of a merged point (cover_1) and within 0.5 mm of one (cover_.5), the fraction within
// two (scanner) spacings of the mesh's triangles; back_p95: 95th percentile of the distance from those within
// 0.5 mm to the mesh (how closely it follows the scanned surface, edges included). --sweep: ours with other
// settings.
#include "partloc/core/stock.hpp"

#include <open3d/t/geometry/RaycastingScene.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "common.hpp"
#include "partloc/core/radius_grid.hpp"
#include "partloc/core/surface.hpp"
#include "partloc/pipeline/run.hpp"

namespace partloc::bench {
namespace {

using Mesh = open3d::geometry::TriangleMesh;

open3d::core::Tensor as_tensor(const std::vector<Eigen::Vector3d>& pts) {
    std::vector<float> q;
    q.reserve(3 * pts.size());
    for (const auto& p : pts)
        q.insert(q.end(), {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())});
    return open3d::core::Tensor(q, {static_cast<int64_t>(pts.size()), 3}, open3d::core::Float32);
}

std::vector<float> distances_to(const Mesh& mesh, const std::vector<Eigen::Vector3d>& pts) {
    if (pts.empty() || mesh.triangles_.empty()) return std::vector<float>(pts.size(), 1e9f);
    open3d::t::geometry::RaycastingScene scene;
    scene.AddTriangles(open3d::t::geometry::TriangleMesh::FromLegacy(mesh));
    const auto d = scene.ComputeDistance(as_tensor(pts));
    const float* p = d.GetDataPtr<float>();
    return std::vector<float>(p, p + pts.size());
}

double quantile(std::vector<float> v, double q) {
    if (v.empty()) return -1.0;
    const std::size_t k = static_cast<std::size_t>(q * (v.size() - 1));
    std::nth_element(v.begin(), v.begin() + k, v.end());
    return v[k];
}

struct Truth {
    Mesh surface;                          // the workpiece at its true place, machine frame, axes 0
    std::vector<Eigen::Vector3d> scanned;  // true-surface samples within 1 mm of a merged point
    std::vector<std::uint8_t> close;       // ... and within 0.5 mm of one
};

void print_row(const std::string& what, double seconds, const Mesh& mesh, const Truth& truth,
               double spacing) {
    const auto d = distances_to(truth.surface, mesh.vertices_);
    const auto c = distances_to(mesh, truth.scanned);
    std::size_t covered = 0, close = 0, close_covered = 0;
    std::vector<float> back;
    for (std::size_t i = 0; i < c.size(); ++i) {
        covered += c[i] <= 2.0 * spacing;
        if (!truth.close[i]) continue;
        ++close;
        close_covered += c[i] <= 2.0 * spacing;
        back.push_back(c[i]);
    }
    std::printf("%-24s %7.3f %9zu %8.4f %8.4f %8.3f %8.4f %8.4f %8.4f\n", what.c_str(), seconds,
                mesh.triangles_.size(), quantile(d, 0.5), quantile(d, 0.95),
                d.empty() ? -1.0 : *std::max_element(d.begin(), d.end()),
                c.empty() ? 0.0 : static_cast<double>(covered) / c.size(),
                close ? static_cast<double>(close_covered) / close : 0.0, quantile(back, 0.95));
    std::fflush(stdout);
}

}  // namespace

int stock_main(int argc, char** argv) {
    CellSpec spec;
    spec.seed = 106;
    bool sweep = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--seed" && i + 1 < argc)
            spec.seed = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--spacing" && i + 1 < argc)
            spec.spacing = std::atof(argv[++i]);
        else if (a == "--sweep")
            sweep = true;
        else {
            std::fprintf(stderr, "usage: partloc_bench stock [--seed N] [--spacing MM] [--sweep]\n");
            return 2;
        }
    }
    const sim::SimulatedJob cell = make_cell(spec);
    RunSettings rs;
    rs.seed = spec.seed;
    rs.build_stock = false;
    const JobResult result = run_job(cell.job, rs);
    if (!result.merged || result.merged->points_.empty()) {
        std::printf("seed %llu: no merged points (%s)\n", static_cast<unsigned long long>(spec.seed),
                    result.workpiece.reason.c_str());
        return 0;
    }
    const auto& merged = *result.merged;
    // The spacing the pipeline thinned the merged points to and builds the stock with (run.cpp: the median of
    // the scans' spacings).
    std::vector<double> spacings;
    for (const auto& s : result.scans)
        if (s.point_spacing > 0) spacings.push_back(s.point_spacing);
    std::nth_element(spacings.begin(), spacings.begin() + spacings.size() / 2, spacings.end());
    const double spacing = spacings.empty() ? spec.spacing : spacings[spacings.size() / 2];

    Truth truth;
    const int w = cell.cell.find("workpiece");
    if (w < 0) return 4;
    truth.surface = *cell.cell.bodies[w].mesh;
    truth.surface.Transform(cell.cell.bodies[w].T_machine_body.matrix());
    const RadiusGrid near_points(merged.points_, 1.0);
    std::vector<int> found;
    for (const auto& p : sample_mesh(truth.surface, 0.5)->points_) {
        near_points.within(p, 1.0, found, false);
        if (found.empty()) continue;
        truth.scanned.push_back(p);
        near_points.within(p, 0.5, found, false);
        truth.close.push_back(!found.empty());
    }

    std::printf(
        "seed %llu, scanner spacing %.3f mm, noise %.2f mm: %zu merged points at spacing %.3f mm, %zu "
        "true-surface samples on scanned area; one thread each\n",
        static_cast<unsigned long long>(spec.seed), spec.spacing, spec.noise, merged.points_.size(), spacing,
        truth.scanned.size());
    std::printf("%-24s %7s %9s %8s %8s %8s %8s %8s %8s\n", "method", "seconds", "triangles", "med_mm",
                "p95_mm", "max_mm", "cover_1", "cover_.5", "back_p95");
    const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    using Clock = std::chrono::steady_clock;
    StockSettings base;
    base.spacing = spacing;
    auto run = [&](const std::string& what, const StockSettings& s, bool poisson) {
        const auto t0 = Clock::now();
        const auto mesh = poisson ? build_stock_poisson(merged, s) : build_stock(merged, s);
        print_row(what, std::chrono::duration<double>(Clock::now() - t0).count(), *mesh, truth, spacing);
    };
    run("poisson (open3d)", base, true);
    run("imls + surface nets", base, false);
    if (!sweep) return 0;
    char name[64];
    for (double voxel : {1.0, 2.0}) {
        StockSettings s = base;
        s.voxel = voxel;
        std::snprintf(name, sizeof name, "  voxel %.1f", voxel);
        run(name, s, false);
    }
    for (double radius : {3.0, 3.5, 5.0}) {
        StockSettings s = base;
        s.radius = radius;
        std::snprintf(name, sizeof name, "  radius %.1f", radius);
        run(name, s, false);
    }
    for (double support : {0.05, 0.15, 0.3}) {
        StockSettings s = base;
        s.min_support = support;
        std::snprintf(name, sizeof name, "  min_support %.2f", support);
        run(name, s, false);
    }
    return 0;
}

}  // namespace partloc::bench
