// The fits' nearest-sample queries: SampleGrid (core/sample_grid.hpp, ours) against Open3D's KDTreeFlann, on
// the same samples and the same queries, in one process (the ratio is what counts on a shared machine).
//   build/bench/partloc_bench nearest
// Samples: a 60 x 40 x 25 mm block at 0.4 mm (Poisson disk, as a fiducial's dense model). Queries: points
// near the surface (Gaussian 0.3 mm off a random sample, as ICP's and verification's) and points anywhere
// in the block's box grown by 10 mm (as a coarse fit's far points), k = 4 and 6 within 1.2 mm. Then a fit's
// queries, the same points moved a little each iteration: the grid against NearestCache.
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/TriangleMesh.h>

#include <chrono>
#include <cstdio>
#include <random>

#include "partloc/core/icp.hpp"
#include "partloc/core/sample_grid.hpp"
#include "partloc/core/surface.hpp"

namespace partloc::bench {

int nearest_main(int, char**) {
    auto box = open3d::geometry::TriangleMesh::CreateBox(60, 40, 25);
    const auto samples = sample_mesh(*box, 0.4);
    const auto& pts = samples->points_;
    std::mt19937_64 rng(1);
    std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
    std::normal_distribution<double> g(0.0, 0.3);
    std::uniform_real_distribution<double> ux(-10, 70), uy(-10, 50), uz(-10, 35);
    std::vector<Eigen::Vector3d> near, far;
    for (int i = 0; i < 1000000; ++i)
        near.push_back(pts[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    for (int i = 0; i < 1000000; ++i) far.emplace_back(ux(rng), uy(rng), uz(rng));
    using Clock = std::chrono::steady_clock;
    const auto t0 = Clock::now();
    const SampleGrid grid(pts, 0.4);
    const auto t1 = Clock::now();
    open3d::geometry::PointCloud cloud;
    cloud.points_ = pts;
    const open3d::geometry::KDTreeFlann tree(cloud);
    const auto t2 = Clock::now();
    std::printf("%zu samples; build: grid %.1f ms, KD-tree %.1f ms\n", pts.size(),
                1e3 * std::chrono::duration<double>(t1 - t0).count(),
                1e3 * std::chrono::duration<double>(t2 - t1).count());
    std::printf("queries     k  grid_ns  kdtree_ns  ratio\n");
    for (const auto* set : {&near, &far})
        for (int k : {4, 6}) {
            const double bound = 1.2;
            std::size_t found_g = 0, found_t = 0;
            int idx[SampleGrid::kMaxK];
            double d2[SampleGrid::kMaxK];
            const auto a = Clock::now();
            for (const auto& p : *set) found_g += grid.nearest(p, k, bound, idx, d2);
            const auto b = Clock::now();
            std::vector<int> ti;
            std::vector<double> td;
            for (const auto& p : *set) {
                tree.SearchKNN(p, k, ti, td);
                for (double d : td) found_t += d <= bound * bound;
            }
            const auto c = Clock::now();
            const double ng = 1e9 * std::chrono::duration<double>(b - a).count() / set->size();
            const double nt = 1e9 * std::chrono::duration<double>(c - b).count() / set->size();
            std::printf("%-8s %4d %8.0f %10.0f %6.1f   (found %zu / %zu)\n",
                        set == &near ? "near" : "anywhere", k, ng, nt, nt / ng, found_g, found_t);
        }
    // A fit's queries: the same points asked again and again as the pose converges (steps of half a
    // millimetre and a degree shrinking threefold per iteration, eight iterations), k = 4 within 1.2 mm:
    // the grid every time against NearestCache (ours: it keeps each point's nearest samples between
    // iterations), three rounds alternating. Both must find the same samples.
    std::printf("fit-like: %zu points x 8 iterations, k 4 within 1.2 mm\n", std::size_t(200000));
    int idx4[SampleGrid::kMaxK];
    double d24[SampleGrid::kMaxK];
    std::printf("round  grid_ms  cache_ms  ratio  cache_searches\n");
    const std::vector<Eigen::Vector3d> fit_points(near.begin(), near.begin() + 200000);
    const Surface surface = make_surface(samples, 0.4);
    for (int round = 0; round < 3; ++round) {
        double ms[2] = {0, 0};
        std::size_t found[2] = {0, 0}, searches = 0;
        for (int mode = 0; mode < 2; ++mode) {
            NearestCache cache(surface, fit_points.size(), 1.25 * 1.2);
            Vector6d step;
            step << 0.01, -0.008, 0.012, 0.3, -0.2, 0.25;
            Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
            const auto a = Clock::now();
            for (int it = 0; it < 8; ++it) {
                T = twist_exp(step) * T;
                step /= 3.0;
                for (std::size_t i = 0; i < fit_points.size(); ++i) {
                    const Eigen::Vector3d p = T * fit_points[i];
                    found[mode] +=
                        mode ? cache.nearest(i, p, 4, 1.2, idx4, d24) : surface.nearest(p, 4, 1.2, idx4, d24);
                }
            }
            ms[mode] = 1e3 * std::chrono::duration<double>(Clock::now() - a).count();
            if (mode) searches = cache.searches();
        }
        std::printf("%5d %8.1f %9.1f %6.1f %15zu%s\n", round, ms[0], ms[1], ms[0] / ms[1], searches,
                    found[0] == found[1] ? "" : "   DIFFERENT ANSWERS");
    }
    return 0;
}

}  // namespace partloc::bench
