// Normals of scan points: ours (core/normals.hpp, a grid search) against Open3D's EstimateNormals with the
// same hybrid search (KD-tree), on the same points, in one process (the ratio is what counts on a shared
// machine). One thread each (TBB for ours, OpenMP for Open3D's), so that the ratio is that of the searches.
//   build/bench/partloc_bench normals
// Points: a simulated scan of seed 106's cell (as `partloc simulate` makes), the three searches partloc
// makes: radius 3.5 spacings / 30 (the workpiece points), 3 spacings / 20 (the fits' points), and 1.5
// samplings / 30 on the cloud thinned to half the sampling (the global fit's coarse normals until a8efe12).
// Then the global fit's points and normals as partloc makes them now (voxel_normals, sums per cube, no
// search) against that search with the average per cube of the sampling that it fed.
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <tbb/global_control.h>
#ifdef PARTLOC_BENCH_WITH_OPENMP
#include <omp.h>
#endif

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "common.hpp"
#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/normals.hpp"

namespace partloc::bench {

int normals_main(int, char**) {
    const tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
#ifdef PARTLOC_BENCH_WITH_OPENMP
    omp_set_num_threads(1);
#else
    std::printf("(no OpenMP found at build time: Open3D's side runs on its own threads)\n");
#endif
    CellSpec spec;
    spec.seed = 106;
    const sim::SimulatedJob cell = make_cell(spec);
    const auto& scan = *cell.job.scans.front().points;
    const double spacing = spec.spacing;
    open3d::geometry::PointCloud full;
    full.points_ = scan.points_;
    // The global fit's sampling as run.cpp takes it (with the largest fiducial instead of the median).
    const double sampling = std::max(0.04 * fiducial_diagonal(cell.job), 2.5 * spacing);
    const auto half = full.VoxelDownSample(0.5 * sampling);
    struct Case {
        const char* what;
        const std::vector<Eigen::Vector3d>* pts;
        double radius;
        int max_nn;
    };
    const Case cases[] = {{"workpiece", &full.points_, 3.5 * spacing, 30},
                          {"fit points", &full.points_, 3.0 * spacing, 20},
                          {"coarse", &half->points_, 1.5 * sampling, 30}};
    using Clock = std::chrono::steady_clock;
    std::printf("search       points   radius  max_nn  ours_s  open3d_s  ratio  agree\n");
    for (const Case& c : cases) {
        const auto a = Clock::now();
        const auto ours = estimate_normals(*c.pts, c.radius, c.max_nn);
        const auto b = Clock::now();
        open3d::geometry::PointCloud pc;
        pc.points_ = *c.pts;
        pc.EstimateNormals(open3d::geometry::KDTreeSearchParamHybrid(c.radius, c.max_nn));
        const auto e = Clock::now();
        std::size_t agree = 0;
        for (std::size_t i = 0; i < ours.size(); ++i)
            agree += std::abs(ours[i].dot(pc.normals_[i])) > 1.0 - 1e-6;
        const double so = std::chrono::duration<double>(b - a).count();
        const double st = std::chrono::duration<double>(e - b).count();
        std::printf("%-10s %8zu %8.3f %7d %7.3f %9.3f %6.1f  %.4f\n", c.what, c.pts->size(), c.radius,
                    c.max_nn, so, st, st / so, static_cast<double>(agree) / ours.size());
    }
    const Eigen::Vector3d eye = estimate_viewpoint(scan, spacing);  // as run.cpp finds the scanner
    const auto a = Clock::now();
    auto before = full.VoxelDownSample(0.5 * sampling);
    before->normals_ = estimate_normals(before->points_, 1.5 * sampling, 30);
    orient_towards(before->points_, before->normals_, eye);
    const auto averaged = before->VoxelDownSample(sampling);
    const auto b = Clock::now();
    const OrientedSample now = voxel_normals(full.points_, sampling, eye);
    const auto e = Clock::now();
    const double sb = std::chrono::duration<double>(b - a).count(),
                 sn = std::chrono::duration<double>(e - b).count();
    std::printf(
        "global fit's points: half-grid search and average %.3f s (%zu points), voxel_normals %.3f s (%zu "
        "points): %.1f times\n",
        sb, averaged->points_.size(), sn, now.points.size(), sb / sn);
    return 0;
}

}  // namespace partloc::bench
