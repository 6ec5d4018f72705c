// The sample grid must answer exactly what a KD-tree answers: same neighbours, same order, same distances.
#include <gtest/gtest.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/TriangleMesh.h>

#include <random>

#include "partloc/core/sample_grid.hpp"
#include "partloc/core/surface.hpp"

using namespace partloc;

namespace {

void expect_same_as_kdtree(const std::vector<Eigen::Vector3d>& pts, double grid_spacing, double spacing,
                           double extent, std::uint64_t seed) {
    const SampleGrid grid(pts, grid_spacing);
    open3d::geometry::PointCloud cloud;
    cloud.points_ = pts;
    const open3d::geometry::KDTreeFlann tree(cloud);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-extent, extent);
    std::uniform_int_distribution<int> kk(1, 8);
    const double bounds[] = {0.5 * spacing, 2.0 * spacing, 10.0 * spacing, 1e30};
    int compared = 0, nonempty = 0;
    for (int q = 0; q < 4000; ++q) {
        // Half the queries near a sample (as the fits ask), half anywhere.
        std::uniform_int_distribution<std::size_t> pick(0, pts.size() - 1);
        std::normal_distribution<double> g(0.0, spacing);
        const Eigen::Vector3d p = q % 2 ? Eigen::Vector3d(u(rng), u(rng), u(rng))
                                        : Eigen::Vector3d(pts[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)));
        const int k = kk(rng);
        const double bound = bounds[q % 4];
        std::vector<int> ti;
        std::vector<double> td;
        tree.SearchKNN(p, k, ti, td);
        std::size_t expected = 0;
        while (expected < td.size() && td[expected] <= bound * bound) ++expected;
        int gi[SampleGrid::kMaxK];
        double gd[SampleGrid::kMaxK];
        const int found = grid.nearest(p, k, bound, gi, gd);
        ASSERT_EQ(static_cast<std::size_t>(found), expected) << "query " << q << " k " << k << " bound " << bound;
        for (int j = 0; j < found; ++j) {
            EXPECT_NEAR(gd[j], td[j], 1e-12 * (1 + td[j]));
            // Equal distances may come in either order; the point must then be as far as the tree's.
            if (gi[j] != ti[j]) EXPECT_NEAR((pts[gi[j]] - p).squaredNorm(), td[j], 1e-12 * (1 + td[j]));
        }
        ++compared;
        nonempty += found > 0;
    }
    EXPECT_EQ(compared, 4000);
    EXPECT_GT(nonempty, 2000);  // the test queries near and far, not only empty space
}

}  // namespace

TEST(SampleGrid, SameNeighboursAsTheKdTreeOnABlockSurface) {
    open3d::geometry::TriangleMesh box = *open3d::geometry::TriangleMesh::CreateBox(40, 25, 10);
    box.Translate(Eigen::Vector3d(-20, -12.5, -5));
    const auto samples = sample_mesh(box, 0.5);
    expect_same_as_kdtree(samples->points_, 0.5, 0.5, 25.0, 1);
}

TEST(SampleGrid, SameNeighboursOnUnevenPointsWithAWrongSpacing) {
    // A dense cluster and sparse points far away, and a spacing ten times too large and too small: still
    // exact, only slower.
    std::mt19937_64 rng(7);
    std::normal_distribution<double> g(0.0, 1.0);
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 3000; ++i) pts.emplace_back(g(rng), g(rng), 0.1 * g(rng));
    for (int i = 0; i < 300; ++i) pts.emplace_back(30 * g(rng), 30 * g(rng), 30 * g(rng));
    expect_same_as_kdtree(pts, 5.0, 0.5, 60.0, 2);
    expect_same_as_kdtree(pts, 0.05, 0.5, 60.0, 3);
}

TEST(SampleGrid, EmptyAndFarQueries) {
    const SampleGrid empty;
    int i[4];
    double d[4];
    EXPECT_EQ(empty.nearest(Eigen::Vector3d::Zero(), 4, 1e30, i, d), 0);
    const std::vector<Eigen::Vector3d> one = {Eigen::Vector3d(1, 2, 3)};
    const SampleGrid g(one, 1.0);
    EXPECT_EQ(g.nearest(Eigen::Vector3d(1e6, 0, 0), 4, 10.0, i, d), 0);
    ASSERT_EQ(g.nearest(Eigen::Vector3d(1e6, 0, 0), 4, 1e30, i, d), 1);
    EXPECT_EQ(i[0], 0);
    ASSERT_EQ(g.nearest(Eigen::Vector3d(1, 2, 3.5), 4, 1.0, i, d), 1);
    EXPECT_NEAR(d[0], 0.25, 1e-12);
}
