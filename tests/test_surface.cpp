// The sample grid must answer exactly what a KD-tree answers: same neighbours, same order, same distances;
// the coarse map (nearest_map.hpp) within a cell of it.
#include <gtest/gtest.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/TriangleMesh.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <thread>
#include <utility>

#include "partloc/core/cloud_stats.hpp"
#include "partloc/core/geometry.hpp"
#include "partloc/core/icp.hpp"
#include "partloc/core/radius_grid.hpp"
#include "partloc/core/sample_grid.hpp"
#include "partloc/core/surface.hpp"
#include "test_note.hpp"

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
        const Eigen::Vector3d p =
            q % 2 ? Eigen::Vector3d(u(rng), u(rng), u(rng))
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
        ASSERT_EQ(static_cast<std::size_t>(found), expected)
            << "query " << q << " k " << k << " bound " << bound;
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

// A box and a cylinder sampled as fiducial models are: the parts of the composed-surface tests.
std::pair<Surface, Surface> box_and_cylinder() {
    const auto box = open3d::geometry::TriangleMesh::CreateBox(40, 25, 10);
    const auto cyl = open3d::geometry::TriangleMesh::CreateCylinder(8, 30, 40, 4);
    return {make_surface(sample_mesh(*box, 0.5), 0.5), make_surface(sample_mesh(*cyl, 0.6), 0.6)};
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

// The coarse map answers, for any point, a sample never more than a cell's diagonal farther than the nearest
// sample, within its reach, and the same answer from any thread.
TEST(NearestMap, AnswersASampleWithinACellDiagonalOfTheNearest) {
    open3d::geometry::TriangleMesh box = *open3d::geometry::TriangleMesh::CreateBox(40, 25, 10);
    box.Translate(Eigen::Vector3d(-20, -12.5, -5));
    Surface s = make_surface(sample_mesh(box, 0.5), 0.5);
    const double cell = 0.8, reach = 4.0;
    add_coarse_map(s, cell, reach);
    ASSERT_TRUE(s.coarse);
    const double diagonal = std::sqrt(3.0) * s.coarse->cell_size();
    std::mt19937_64 rng(11);
    std::uniform_int_distribution<std::size_t> pick(0, s.points.size() - 1);
    std::normal_distribution<double> g(0.0, 1.0);
    std::vector<Eigen::Vector3d> queries;
    for (int q = 0; q < 5000; ++q)
        queries.push_back(s.points[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    int answered = 0;
    std::vector<int> first(queries.size());
    for (std::size_t q = 0; q < queries.size(); ++q) {
        const Eigen::Vector3d& p = queries[q];
        double exact2 = 0.0;
        ASSERT_GE(s.nearest(p, &exact2), 0);
        const int k = s.coarse->nearest(p);
        first[q] = k;
        if (std::sqrt(exact2) + diagonal < reach - diagonal) {
            ASSERT_GE(k, 0) << "query " << q;  // a sample lies within reach of the cell's centre
        }
        if (k < 0) continue;
        ++answered;
        EXPECT_LE((s.points[k] - p).norm(), std::sqrt(exact2) + diagonal + 1e-9) << "query " << q;
    }
    EXPECT_GT(answered, 4900);
    // Far from the block, and outside the map's box: no sample.
    EXPECT_EQ(s.coarse->nearest(Eigen::Vector3d(0, 0, 5.0 + 3 * reach)), -1);
    EXPECT_EQ(s.coarse->nearest(Eigen::Vector3d(1e6, 0, 0)), -1);
    // A second map of the same samples, asked from several threads at once, gives the same answers.
    Surface t = make_surface(sample_mesh(box, 0.5), 0.5);
    add_coarse_map(t, cell, reach);
    std::vector<int> second(queries.size(), -7);
    std::vector<std::thread> workers;
    for (int w = 0; w < 4; ++w)
        workers.emplace_back([&, w] {
            for (std::size_t q = w; q < queries.size() + w; ++q) {
                const std::size_t i = q % queries.size();
                const int k = t.coarse->nearest(queries[i]);
                if (q % 4 == static_cast<std::size_t>(w)) second[i] = k;
            }
        });
    for (auto& w : workers) w.join();
    EXPECT_EQ(first, second);
}

// The fit with approximate coarse stages ends where the exact fit ends: its last stage is exact.
TEST(NearestMap, AFitWithApproximateCoarseStagesEndsAtTheExactFitsPose) {
    // A block with a step, so that every direction is held.
    open3d::geometry::TriangleMesh a = *open3d::geometry::TriangleMesh::CreateBox(40, 25, 10);
    open3d::geometry::TriangleMesh b = *open3d::geometry::TriangleMesh::CreateBox(15, 25, 8);
    b.Translate(Eigen::Vector3d(25, 0, 10));  // a step on the top face, at one end
    a += b;
    Surface target = make_surface(sample_mesh(a, 0.4), 0.4);
    add_coarse_map(target, 0.75, 7.0);
    // The scan: samples of the same block, noisy, moved by a known pose.
    std::mt19937_64 rng(5);
    std::normal_distribution<double> noise(0.0, 0.05);
    const auto dense = sample_mesh(a, 0.3);
    std::vector<Eigen::Vector3d> source;
    for (const auto& p : dense->points_)
        source.push_back(p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
    Eigen::Isometry3d off = Eigen::Isometry3d::Identity();
    off.linear() =
        Eigen::AngleAxisd(6.0 * M_PI / 180.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    off.translation() = Eigen::Vector3d(1.5, -1.0, 0.8);
    IcpSettings exact;
    exact.max_distances = {3.0, 1.5, 0.4};
    IcpSettings approximate = exact;
    approximate.approximate_from = 1.5;
    const IcpResult e = icp_point_to_plane(source, target, off, exact);
    const IcpResult m = icp_point_to_plane(source, target, off, approximate);
    const PoseError to_truth = pose_error(m.T_target_source, Eigen::Isometry3d::Identity());
    EXPECT_LT(to_truth.translation, 0.01);
    EXPECT_LT(to_truth.rotation_deg, 0.01);
    const PoseError between = pose_error(m.T_target_source, e.T_target_source);
    EXPECT_LT(between.translation, 1e-3);
    EXPECT_LT(between.rotation_deg, 1e-3);
    EXPECT_NEAR(static_cast<double>(m.inliers), static_cast<double>(e.inliers), 0.001 * e.inliers);
}

// The scan's radius grid answers the KD-tree's radius search exactly: the same points, ascending.
TEST(RadiusGrid, SamePointsAsTheKdTreesRadiusSearch) {
    std::mt19937_64 rng(3);
    std::normal_distribution<double> g(0.0, 1.0);
    std::uniform_real_distribution<double> u(-80.0, 80.0);
    // A scan-like cloud: two planes and a block's faces, plus far outliers.
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 20000; ++i) pts.emplace_back(u(rng), u(rng), 0.05 * g(rng));
    for (int i = 0; i < 10000; ++i) pts.emplace_back(u(rng), 0.05 * g(rng) + 30.0, 0.5 * std::abs(u(rng)));
    for (int i = 0; i < 50; ++i) pts.emplace_back(1000 * g(rng), 1000 * g(rng), 1000 * g(rng));
    open3d::geometry::PointCloud cloud;
    cloud.points_ = pts;
    const open3d::geometry::KDTreeFlann tree(cloud);
    for (double cell : {3.0, 0.7, 40.0}) {
        const RadiusGrid grid(pts, cell);
        int nonempty = 0;
        for (int q = 0; q < 300; ++q) {
            const Eigen::Vector3d c =
                q % 3 ? pts[q * 97 % pts.size()] : Eigen::Vector3d(u(rng), u(rng), u(rng));
            const double r = 0.5 + 60.0 * (q % 7) / 6.0;
            std::vector<int> ti, gi;
            std::vector<double> td;
            tree.SearchRadius(c, r, ti, td);
            std::sort(ti.begin(), ti.end());
            grid.within(c, r, gi);
            ASSERT_EQ(gi, ti) << "cell " << cell << " query " << q << " radius " << r;
            nonempty += !gi.empty();
            // Unsorted: the same points.
            std::vector<int> unsorted;
            grid.within(c, r, unsorted, false);
            std::sort(unsorted.begin(), unsorted.end());
            ASSERT_EQ(unsorted, ti);
        }
        EXPECT_GT(nonempty, 200);
        // Balls centred outside the grid's box (past the far outliers) that reach into it, or not.
        for (int q = 0; q < 40; ++q) {
            const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
            const Eigen::Vector3d c = 5000.0 * dir;
            const double r = q % 4 ? 5000.0 - 60.0 + q : 1000.0;
            std::vector<int> ti, gi;
            std::vector<double> td;
            tree.SearchRadius(c, r, ti, td);
            std::sort(ti.begin(), ti.end());
            grid.within(c, r, gi);
            ASSERT_EQ(gi, ti) << "cell " << cell << " far query " << q;
        }
    }
    const RadiusGrid empty(std::vector<Eigen::Vector3d>{}, 1.0);
    std::vector<int> none;
    empty.within(Eigen::Vector3d::Zero(), 10.0, none);
    EXPECT_TRUE(none.empty());
}

// A composed surface (the fiducials at their machine poses) answers what one grid over all their samples
// answers: the same k nearest, in the same order, at the same distances.
TEST(ComposedSurface, AnswersWhatOneGridOverAllTheSamplesAnswers) {
    const auto [a, b] = box_and_cylinder();
    std::vector<Eigen::Isometry3d> poses(3, Eigen::Isometry3d::Identity());
    poses[0].translation() = Eigen::Vector3d(-300, 20, 5);
    poses[1].linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    poses[1].translation() = Eigen::Vector3d(250, -80, 40);
    // The third close to the first, so that some queries have neighbours on both.
    poses[2].linear() = Eigen::AngleAxisd(-0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    poses[2].translation() = Eigen::Vector3d(-290, 20, 20);
    const Surface composed = compose_surfaces({&a, &b, &a}, poses);
    ASSERT_EQ(composed.points.size(), 2 * a.points.size() + b.points.size());
    auto cloud = std::make_shared<open3d::geometry::PointCloud>();
    cloud->points_ = composed.points;
    cloud->normals_ = composed.normals;
    const Surface whole = make_surface(cloud, 0.5);
    std::mt19937_64 rng(5);
    std::uniform_int_distribution<std::size_t> pick(0, composed.points.size() - 1);
    std::normal_distribution<double> g(0.0, 1.5);
    std::uniform_real_distribution<double> u(-400, 400);
    int found_some = 0;
    for (int q = 0; q < 6000; ++q) {
        const Eigen::Vector3d p =
            q % 3 ? Eigen::Vector3d(composed.points[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)))
                  : Eigen::Vector3d(u(rng), u(rng), u(rng));
        const int k = 1 + q % 6;
        const double bound = q % 2 ? 2.0 : 1e30;
        int ia[SampleGrid::kMaxK], ib[SampleGrid::kMaxK];
        double da[SampleGrid::kMaxK], db[SampleGrid::kMaxK];
        const int na = composed.nearest(p, k, bound, ia, da);
        const int nb = whole.nearest(p, k, bound, ib, db);
        ASSERT_EQ(na, nb) << "query " << q;
        for (int j = 0; j < na; ++j) {
            // Distances agree to rounding (the composed surface measures in each part's frame).
            EXPECT_NEAR(da[j], db[j], 1e-9) << "query " << q << " neighbour " << j;
            // The same sample, unless two lie at the same distance.
            if (j + 1 < na && std::abs(db[j + 1] - db[j]) < 1e-9) continue;
            if (j > 0 && std::abs(db[j] - db[j - 1]) < 1e-9) continue;
            EXPECT_EQ(ia[j], ib[j]) << "query " << q << " neighbour " << j;
            EXPECT_NEAR((composed.points[ia[j]] - p).squaredNorm(), da[j], 1e-9);
        }
        found_some += na > 0;
    }
    EXPECT_GT(found_some, 3000);
}

// The merge's statistical outlier filter: the points Open3D's filter keeps, exactly, and the scattered ones
// gone.
TEST(StatisticalInliers, KeepWhatOpen3DKeepsAndDropTheScatter) {
    auto box = open3d::geometry::TriangleMesh::CreateBox(60, 40, 25);
    const auto samples = sample_mesh(*box, 0.4);
    std::mt19937_64 rng(11);
    std::uniform_int_distribution<std::size_t> pick(0, samples->points_.size() - 1);
    std::normal_distribution<double> g(0.0, 0.13);
    std::uniform_real_distribution<double> ux(-5, 65), uy(-5, 45), uz(-5, 30);
    open3d::geometry::PointCloud cloud;
    for (int i = 0; i < 30000; ++i)
        cloud.points_.push_back(samples->points_[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    // Scattered returns, each at least 3 mm from the block's surface, after the surface points.
    const std::size_t first_scattered = cloud.points_.size();
    while (cloud.points_.size() < first_scattered + 300) {
        const Eigen::Vector3d p(ux(rng), uy(rng), uz(rng));
        const Eigen::Vector3d inside =
            p.cwiseMax(Eigen::Vector3d::Zero()).cwiseMin(Eigen::Vector3d(60, 40, 25));
        const double to_faces = std::min({p.x(), 60 - p.x(), p.y(), 40 - p.y(), p.z(), 25 - p.z()});
        const double out = (p - inside).norm();
        if ((out > 0 ? out : to_faces) >= 3.0) cloud.points_.push_back(p);
    }
    // Repeated points (a scanner's duplicates): a distance of zero among the neighbours.
    for (int i = 0; i < 200; ++i) cloud.points_.push_back(cloud.points_[static_cast<std::size_t>(i) * 7]);
    for (int k : {1, 8, 20}) {
        const auto ours = statistical_inliers(cloud.points_, k, 2.5);
        const auto theirs = std::get<1>(cloud.RemoveStatisticalOutliers(static_cast<std::size_t>(k), 2.5));
        EXPECT_EQ(ours, theirs) << "k = " << k;
        if (k < 20) continue;
        std::size_t scattered_kept = 0;
        for (std::size_t i : ours) scattered_kept += i >= first_scattered && i < first_scattered + 300;
        EXPECT_LT(scattered_kept, 15u);  // of 300
        EXPECT_GT(ours.size(), 29000u);
    }
    // Fewer points than neighbours asked for: each point's mean over all of them, as Open3D's.
    open3d::geometry::PointCloud few;
    for (int i = 0; i < 12; ++i) few.points_.push_back(cloud.points_[static_cast<std::size_t>(i) * 1000]);
    EXPECT_EQ(statistical_inliers(few.points_, 20, 1.0), std::get<1>(few.RemoveStatisticalOutliers(20, 1.0)));
    // Every point at one place: no mean above zero, nothing kept (as Open3D).
    const std::vector<Eigen::Vector3d> same(50, Eigen::Vector3d(1, 2, 3));
    EXPECT_TRUE(statistical_inliers(same, 20, 2.5).empty());
    EXPECT_THROW(statistical_inliers(same, 0, 2.5), std::invalid_argument);
    EXPECT_THROW(statistical_inliers(same, SampleGrid::kMaxK + 1, 2.5), std::invalid_argument);
}

// The fits' kept searches (NearestCache) answer exactly what the grid answers, bit for bit, while the points
// drift as a fit's do (large steps, then ever smaller), through shrinking stage distances, on a plain and a
// composed surface; and they search the grid for a fraction of the queries only.
TEST(NearestCache, AnswersExactlyWhatTheSearchAnswersAsThePointsDrift) {
    const auto [a, b] = box_and_cylinder();
    std::vector<Eigen::Isometry3d> poses(2, Eigen::Isometry3d::Identity());
    poses[1].linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    poses[1].translation() = Eigen::Vector3d(30, -10, 4);
    const Surface composed = compose_surfaces({&a, &b}, poses);
    for (const Surface* surface : {&a, &composed}) {
        // Points near the samples (the scan of a surface), and some far off (clutter).
        std::mt19937_64 rng(11);
        std::uniform_int_distribution<std::size_t> pick(0, surface->points.size() - 1);
        std::normal_distribution<double> g(0.0, 0.4);
        std::uniform_real_distribution<double> u(-60, 60);
        std::vector<Eigen::Vector3d> pts;
        for (int i = 0; i < 3000; ++i)
            pts.push_back(
                i % 10 ? Eigen::Vector3d(surface->points[pick(rng)] + Eigen::Vector3d(g(rng), g(rng), g(rng)))
                       : Eigen::Vector3d(u(rng), u(rng), u(rng)));
        const std::vector<double> stages = {2.0, 1.0, 0.5, 0.3};
        NearestCache cache(*surface, pts.size(), 1.25 * stages.front());
        Vector6d step;
        step << 0.02, -0.01, 0.015, 0.3, -0.2, 0.25;  // about a degree and half a millimetre
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        std::size_t queries = 0, found_some = 0;
        for (std::size_t stage = 0; stage < stages.size(); ++stage)
            for (int it = 0; it < 8; ++it) {
                T = twist_exp(step) * T;
                step *= 0.3;                                                             // converging
                if (stage == 2 && it == 0) T = twist_exp(Vector6d::Constant(0.01)) * T;  // a jump
                for (std::size_t i = 0; i < pts.size(); ++i) {
                    const Eigen::Vector3d p = T * pts[i];
                    const int k = 1 + static_cast<int>((i + it) % 4);
                    int ia[SampleGrid::kMaxK], ib[SampleGrid::kMaxK];
                    double da[SampleGrid::kMaxK], db[SampleGrid::kMaxK];
                    const int na = cache.nearest(i, p, k, stages[stage], ia, da);
                    const int nb = surface->nearest(p, k, stages[stage], ib, db);
                    ASSERT_EQ(na, nb) << "point " << i << " stage " << stage << " iteration " << it;
                    for (int j = 0; j < na; ++j) {
                        ASSERT_EQ(ia[j], ib[j]) << "point " << i << " stage " << stage << " iteration " << it;
                        ASSERT_EQ(da[j], db[j]);  // to the bit
                        EXPECT_EQ(da[j], surface->squared_distance(p, ia[j]));
                    }
                    ++queries;
                    found_some += na > 0;
                }
            }
        EXPECT_GT(found_some, queries / 4);  // the answers are not all empty
        int none[1];
        double none_d2[1];
        EXPECT_EQ(cache.nearest(0, pts[0], 0, 1.0, none, none_d2), 0);  // k = 0: nothing, as Surface::nearest
        partloc::test::note("NearestCache: %zu searches for %zu queries\n", cache.searches(), queries);
        // The first query of each point searches; most later ones need not.
        EXPECT_GE(cache.searches(), pts.size());
        EXPECT_LT(cache.searches(), queries / 3);
    }
}
