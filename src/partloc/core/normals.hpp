#pragma once
// Normals of scan points from their neighbours: the least axis of the covariance of the up to max_nn nearest
// points within a radius, as Open3D's EstimateNormals with KDTreeSearchParamHybrid computes them.
//
// Our own because Open3D's builds a KD-tree over the cloud and keeps each query's neighbours sorted as it
// finds them (nanoflann's KNN result set): on seed 106 those searches were 16-18 % of a job's CPU (perf), for
// three uses (the global fit's coarse normals, the fits' points, the workpiece points). Here the points sit
// in cells of the radius (RadiusGrid) and only a query with more than max_nn neighbours sorts them, partly.
// `partloc_bench normals` measures both on the same points, one thread each (BENCHMARK.md): ours is 3.0
// times faster on the workpiece's points, 2.6 on the fits', 1.5 on the whole scan thinned to half the global
// fit's sampling. (Open3D's also runs OpenMP threads inside our TBB tasks.) tests/test_normals.cpp checks
// that the normals agree with Open3D's.
#include <Eigen/Core>
#include <cstddef>
#include <vector>

namespace partloc {

/// Unit normals, either sign, of points[at[i]] (of every point when `at` is null), each from its up to
/// `max_nn` nearest points (itself included) closer than `radius`; (0, 0, 1) where fewer than three are, as
/// Open3D gives. Deterministic for any number of threads.
std::vector<Eigen::Vector3d> estimate_normals(const std::vector<Eigen::Vector3d>& points, double radius,
                                              int max_nn, const std::vector<std::size_t>* at = nullptr);

class RadiusGrid;
/// The neighbour grid estimate_normals builds over `points` for `radius`: for a caller that asks for the
/// normals of the same points more than once.
RadiusGrid normals_grid(const std::vector<Eigen::Vector3d>& points, double radius);
/// The same normals, with `grid` = normals_grid(points, radius) built beforehand.
std::vector<Eigen::Vector3d> estimate_normals(const std::vector<Eigen::Vector3d>& points,
                                              const RadiusGrid& grid, double radius, int max_nn,
                                              const std::vector<std::size_t>* at = nullptr);

/// Flips each normal to face `viewpoint` (Open3D's OrientNormalsTowardsCameraLocation): a scanner sees only
/// surfaces that face it.
void orient_towards(const std::vector<Eigen::Vector3d>& points, std::vector<Eigen::Vector3d>& normals,
                    const Eigen::Vector3d& viewpoint);
/// The normal n of the point p facing `viewpoint`; a zero normal becomes the direction to it (or +z).
Eigen::Vector3d facing(const Eigen::Vector3d& n, const Eigen::Vector3d& p, const Eigen::Vector3d& viewpoint);

/// Points thinned to one per cube of `cell` (the mean of the points in it), each with the normal of the
/// points within the cube of twice `cell` around its own (the least axis of their covariance, from sums kept
/// per cube of half `cell`: no neighbour search), facing `viewpoint`. The output follows the order in which
/// the points first reach each cube. Empty when `cell` is not > 0.
struct OrientedSample {
    std::vector<Eigen::Vector3d> points, normals;
};
OrientedSample voxel_normals(const std::vector<Eigen::Vector3d>& points, double cell,
                             const Eigen::Vector3d& viewpoint);

/// Unit normal, either sign, of the points pts[idx]: the least axis of their covariance; zero for fewer than
/// three points or a degenerate neighbourhood.
Eigen::Vector3d pca_normal(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>& idx);

}  // namespace partloc
