#pragma once
// Parameters from the data (issue 4 "Trust"): a scan's point spacing and noise, measured on the scan itself,
// so that every radius and threshold can follow from them in any units.
#include <open3d/geometry/PointCloud.h>

#include <cstdint>

namespace partloc {

struct CloudStats {
    double spacing = 0.0;  ///< median distance to the nearest neighbour (cloud units)
    double noise = 0.0;    ///< robust 1-sigma scatter about local planes (cloud units)
};

/// Measures spacing and noise on up to `samples` points drawn with `seed`. Noise is the median, over
/// neighbourhoods of 24 points, of the RMS distance to the local best-fit plane; on curved or edged regions
/// that over-estimates, which the median keeps small.
CloudStats measure_cloud(const open3d::geometry::PointCloud& cloud, std::size_t samples = 3000,
                         std::uint64_t seed = 1);

}  // namespace partloc

#include <Eigen/Core>

namespace partloc {

/// Where the scanner was, in the scan's frame. Most scanners report points in their own frame, with the
/// sensor at the origin: that is taken unless more than 4 % of the surface is seen edge-on (within 10
/// degrees) from the origin, which a scanner there would not have returned. Otherwise (a scan already moved
/// into another frame, as the Stanford bunny's are) the surface's mean outward normal gives the viewing
/// direction, and the viewpoint is put far along it.
Eigen::Vector3d estimate_viewpoint(const open3d::geometry::PointCloud& cloud, double spacing);

}  // namespace partloc

#include <vector>

namespace partloc {

/// The points that a statistical outlier filter keeps, ascending: the mean distance from each point to its
/// k nearest points (itself included) is taken, and a point is kept when that mean is above zero and below
/// the mean of all of them plus std_ratio standard deviations (with Bessel's correction). The same points as
/// open3d::geometry::PointCloud::RemoveStatisticalOutliers(k, std_ratio) keeps (test StatisticalInliers in
/// tests/test_surface.cpp). Ours because Open3D's KD-tree took 0.17 s of seed 106's 2.3 s on the merged
/// workpiece points (about 100 k); on the nearest-sample grid and both cores the same points take half to
/// three fifths of its time (`partloc_bench outliers`, BENCHMARK.md). k <= SampleGrid::kMaxK.
std::vector<std::size_t> statistical_inliers(const std::vector<Eigen::Vector3d>& points, int k,
                                             double std_ratio);

}  // namespace partloc
