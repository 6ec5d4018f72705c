// Our normals (core/normals.hpp) are Open3D's EstimateNormals with a hybrid search: the same neighbours, so
// the same planes, on a noisy scan-like cloud with edges, corners and a curved face.
#include <gtest/gtest.h>
#include <open3d/geometry/KDTreeSearchParam.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>

#include <random>

#include "partloc/core/normals.hpp"
#include "partloc/core/surface.hpp"

using namespace partloc;

namespace {

std::vector<Eigen::Vector3d> noisy_scene(double spacing, double noise, std::uint64_t seed) {
    open3d::geometry::TriangleMesh scene = *open3d::geometry::TriangleMesh::CreateBox(40, 25, 10);
    auto cyl = open3d::geometry::TriangleMesh::CreateCylinder(8, 30, 60, 4);
    cyl->Translate(Eigen::Vector3d(70, 0, 15));
    scene += *cyl;
    const auto samples = sample_mesh(scene, spacing);
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g(0.0, noise);
    std::vector<Eigen::Vector3d> pts;
    for (const auto& p : samples->points_) pts.push_back(p + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    return pts;
}

}  // namespace

TEST(Normals, AgreeWithOpen3dsHybridSearch) {
    const auto pts = noisy_scene(0.4, 0.05, 3);
    for (const auto& [radius, max_nn] : {std::pair<double, int>{1.4, 30}, {1.2, 20}, {0.5, 30}}) {
        open3d::geometry::PointCloud pc;
        pc.points_ = pts;
        pc.EstimateNormals(open3d::geometry::KDTreeSearchParamHybrid(radius, max_nn));
        const auto ours = estimate_normals(pts, radius, max_nn);
        ASSERT_EQ(ours.size(), pts.size());
        std::size_t close = 0, isolated = 0;
        for (std::size_t i = 0; i < pts.size(); ++i) {
            EXPECT_NEAR(ours[i].norm(), 1.0, 1e-9);
            if (std::abs(ours[i].dot(pc.normals_[i])) > 1.0 - 1e-6) ++close;
            isolated += ours[i] == Eigen::Vector3d::UnitZ();
        }
        // Only a point with two neighbours at the same distance at the max_nn-th place may differ.
        EXPECT_GE(close, pts.size() - pts.size() / 1000) << "radius " << radius << " max_nn " << max_nn;
        if (radius < 0.6) EXPECT_GT(isolated, 0u);  // too few neighbours: (0, 0, 1), as Open3D gives
    }
    // A subset: the same normals as for the whole cloud at those points.
    const std::vector<std::size_t> at = {0, 7, 100, pts.size() - 1};
    const auto all = estimate_normals(pts, 1.4, 30);
    const auto some = estimate_normals(pts, 1.4, 30, &at);
    ASSERT_EQ(some.size(), at.size());
    for (std::size_t k = 0; k < at.size(); ++k) EXPECT_EQ(some[k], all[at[k]]);
}

TEST(Normals, OrientedTowardsTheViewpoint) {
    const auto pts = noisy_scene(0.5, 0.02, 4);
    auto n = estimate_normals(pts, 1.5, 30);
    const Eigen::Vector3d eye(20, 300, 200);
    orient_towards(pts, n, eye);
    for (std::size_t i = 0; i < pts.size(); ++i) EXPECT_GE(n[i].dot(eye - pts[i]), 0.0);
}
