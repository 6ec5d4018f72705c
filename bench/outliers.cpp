// The statistical outlier filter of the merge: statistical_inliers (core/cloud_stats.hpp, ours, on the
// nearest-sample grid) against Open3D's PointCloud::RemoveStatisticalOutliers, on the same points with the
// merge's parameters (20 neighbours, 2.5 standard deviations), alternating, in one process; and whether both
// keep the same points.
//   build/bench/partloc_bench outliers [CLOUD.ply]
// Without a file: a 60 x 40 x 25 mm block's surface, 100 000 points with 0.13 mm of Gaussian noise and 1 %
// of them scattered through its box grown by 5 mm (about the merged workpiece points of seed 106). With a
// file: its points (for instance a job's merged.ply).
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/io/PointCloudIO.h>

#include <chrono>
#include <cstdio>
#include <random>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/surface.hpp"

namespace partloc::bench {

int outliers_main(int argc, char** argv) {
    open3d::geometry::PointCloud cloud;
    if (argc > 1) {
        if (!open3d::io::ReadPointCloud(argv[1], cloud) || cloud.points_.empty()) {
            std::fprintf(stderr, "cannot read %s\n", argv[1]);
            return 2;
        }
    } else {
        auto box = open3d::geometry::TriangleMesh::CreateBox(60, 40, 25);
        const auto samples = sample_mesh(*box, 0.25);
        std::mt19937_64 rng(7);
        std::uniform_int_distribution<std::size_t> pick(0, samples->points_.size() - 1);
        std::normal_distribution<double> g(0.0, 0.13);
        std::uniform_real_distribution<double> ux(-5, 65), uy(-5, 45), uz(-5, 30);
        for (int i = 0; i < 99000; ++i)
            cloud.points_.push_back(samples->points_[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)));
        for (int i = 0; i < 1000; ++i) cloud.points_.emplace_back(ux(rng), uy(rng), uz(rng));
    }
    using Clock = std::chrono::steady_clock;
    std::printf(
        "%zu points; 20 neighbours, 2.5 sigma\nround  ours_ms  open3d_ms  kept_ours  kept_open3d  same\n",
        cloud.points_.size());
    for (int round = 0; round < 3; ++round) {
        const auto a = Clock::now();
        const std::vector<std::size_t> ours = statistical_inliers(cloud.points_, 20, 2.5);
        const auto b = Clock::now();
        const auto theirs = std::get<1>(cloud.RemoveStatisticalOutliers(20, 2.5));
        const auto c = Clock::now();
        std::printf("%5d %8.1f %10.1f %10zu %12zu  %s\n", round,
                    1e3 * std::chrono::duration<double>(b - a).count(),
                    1e3 * std::chrono::duration<double>(c - b).count(), ours.size(), theirs.size(),
                    ours == theirs ? "yes" : "NO");
    }
    return 0;
}

}  // namespace partloc::bench
