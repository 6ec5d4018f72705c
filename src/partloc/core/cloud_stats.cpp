#include "partloc/core/cloud_stats.hpp"

#include <open3d/geometry/BoundingVolume.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "partloc/core/median.hpp"
#include "partloc/core/sample_grid.hpp"

namespace partloc {

CloudStats measure_cloud(const open3d::geometry::PointCloud& cloud, std::size_t samples, std::uint64_t seed) {
    CloudStats stats;
    const std::size_t n = cloud.points_.size();
    if (n < 30) return stats;
    open3d::geometry::KDTreeFlann tree(cloud);
    std::mt19937_64 rng(seed);
    std::uniform_int_distribution<std::size_t> pick(0, n - 1);
    std::vector<double> nn, scatter;
    std::vector<int> idx;
    std::vector<double> d2;
    const std::size_t m = std::min(samples, n);
    for (std::size_t s = 0; s < m; ++s) {
        const auto& p = cloud.points_[m == n ? s : pick(rng)];
        if (tree.SearchKNN(p, 24, idx, d2) < 24) continue;
        nn.push_back(std::sqrt(d2[1]));
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (int i : idx) mean += cloud.points_[i];
        mean /= idx.size();
        Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
        for (int i : idx) {
            const Eigen::Vector3d d = cloud.points_[i] - mean;
            C += d * d.transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C / (idx.size() - 3.0));
        scatter.push_back(std::sqrt(std::max(0.0, es.eigenvalues()(0))));
    }
    stats.spacing = median_of(nn);
    stats.noise = median_of(scatter);
    return stats;
}

}  // namespace partloc

namespace partloc {

Eigen::Vector3d estimate_viewpoint(const open3d::geometry::PointCloud& cloud, double spacing) {
    if (cloud.points_.size() < 50) return Eigen::Vector3d::Zero();
    const auto box = cloud.GetAxisAlignedBoundingBox();
    const double extent = (box.max_bound_ - box.min_bound_).norm();
    const double voxel = std::max(spacing * 2.0, extent / 150.0);
    // One point per voxel (the centroid), only for voxels that hold a fair share of points: a surface fills
    // its voxels with many returns, spurious returns (displaced along their rays) scatter one or two per
    // voxel over a thick shell. With 5 % of them, their random normals, many edge-on, took the scanner to
    // be elsewhere (measured, issue 4).
    struct Acc {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        int n = 0;
    };
    std::unordered_map<std::uint64_t, Acc> cells;
    const double inv = 1.0 / voxel;
    auto key = [&](const Eigen::Vector3d& p) {
        const auto q = [&](double v) {
            return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v * inv)) + (1 << 20)) &
                   0x1FFFFF;
        };
        return (q(p.x()) << 42) | (q(p.y()) << 21) | q(p.z());
    };
    for (const auto& p : cloud.points_) {
        Acc& a = cells[key(p)];
        a.sum += p;
        ++a.n;
    }
    std::vector<int> counts;
    counts.reserve(cells.size());
    for (const auto& [k, a] : cells) counts.push_back(a.n);
    std::nth_element(counts.begin(), counts.begin() + counts.size() / 2, counts.end());
    const int min_count = std::max(3, counts[counts.size() / 2] / 5);
    auto sub = std::make_shared<open3d::geometry::PointCloud>();
    for (const auto& [k, a] : cells)
        if (a.n >= min_count) sub->points_.push_back(a.sum / a.n);
    // The map's order is not fixed across library versions: sort, for a result that never varies.
    std::sort(sub->points_.begin(), sub->points_.end(),
              [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
                  return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
              });
    if (sub->points_.size() < 30) return Eigen::Vector3d::Zero();
    sub = std::get<0>(sub->RemoveStatisticalOutliers(12, 2.0));
    if (sub->points_.size() < 30) return Eigen::Vector3d::Zero();
    sub->EstimateNormals(open3d::geometry::KDTreeSearchParamKNN(15));
    // A scanner at the origin sees no surface edge-on: it loses returns toward grazing incidence. Surfaces
    // seen edge-on from the origin mean the points were seen from elsewhere. (Measured: 0.7-1.6 % of
    // samples within 10 degrees of edge-on in our virtual scans, 7-16 % for the bunny scans seen from
    // their frame's origin.)
    std::size_t grazing = 0;
    for (std::size_t i = 0; i < sub->points_.size(); ++i)
        grazing += std::abs(sub->normals_[i].dot(sub->points_[i].normalized())) < 0.17;
    if (grazing <= 0.04 * sub->points_.size()) return Eigen::Vector3d::Zero();

    sub->OrientNormalsConsistentTangentPlane(10);
    const std::size_t n = sub->points_.size();
    // Outward: away from the centroid of the observed shell (which lies inside the object).
    const Eigen::Vector3d c = sub->GetCenter();
    std::size_t outward = 0;
    for (std::size_t i = 0; i < n; ++i) outward += sub->normals_[i].dot(sub->points_[i] - c) > 0;
    const double sign = outward * 2 >= n ? 1.0 : -1.0;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& nn : sub->normals_) mean += sign * nn;
    if (mean.norm() < 1e-12) return Eigen::Vector3d::Zero();
    return c + mean.normalized() * 20.0 * extent;
}

}  // namespace partloc

namespace partloc {

std::vector<std::size_t> statistical_inliers(const std::vector<Eigen::Vector3d>& points, int k,
                                             double std_ratio) {
    if (k < 1 || k > SampleGrid::kMaxK || !(std_ratio > 0))
        throw std::invalid_argument("statistical_inliers: k must be 1-" + std::to_string(SampleGrid::kMaxK) +
                                    " and std_ratio > 0");
    std::vector<std::size_t> kept;
    if (points.empty()) return kept;
    // The grid's spacing as if the points covered a surface the size of their box: about right for a scan,
    // and any positive value gives the exact neighbours.
    Eigen::AlignedBox3d box;
    for (const auto& p : points) box.extend(p);
    const double d = box.diagonal().norm();
    const double spacing =
        std::max(d / std::sqrt(static_cast<double>(points.size())), 1e-9 * std::max(d, 1.0));
    // The grid's cells are 1.5 x 1.6 of that spacing: `partloc_bench outliers` took 64-86 ms at 1.6, on its
    // block and on seed 106's merged points, against 63-170 ms from 1.0 to 1.3 and 106-254 ms from 3 to 6.
    const SampleGrid grid(points, 1.6 * spacing);
    std::vector<double> mean(points.size());
    const double unbounded = std::numeric_limits<double>::infinity();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points.size(), 1024), [&](const auto& range) {
        int idx[SampleGrid::kMaxK];
        double d2[SampleGrid::kMaxK];
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
            const int found = grid.nearest(points[i], k, unbounded, idx, d2);
            // Summed nearest first, as the KD-tree's sorted answer is: the same bits.
            double sum = 0.0;
            for (int j = 0; j < found; ++j) sum += std::sqrt(d2[j]);
            mean[i] = found > 0 ? sum / found : -1.0;
        }
    });
    // Every point has at least itself as a neighbour, so every mean counts (the library's valid distances).
    const std::size_t valid = points.size();
    double cloud_mean = 0.0;
    for (double m : mean)
        if (m > 0) cloud_mean += m;
    cloud_mean /= static_cast<double>(valid);
    double sq_sum = 0.0;
    for (double m : mean) sq_sum += m > 0 ? (m - cloud_mean) * (m - cloud_mean) : 0.0;
    const double std_dev = valid > 1 ? std::sqrt(sq_sum / static_cast<double>(valid - 1)) : 0.0;
    const double threshold = cloud_mean + std_ratio * std_dev;
    for (std::size_t i = 0; i < mean.size(); ++i)
        if (mean[i] > 0 && mean[i] < threshold) kept.push_back(i);
    return kept;
}

}  // namespace partloc
