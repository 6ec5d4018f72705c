#pragma once
// The extent and rank of a set of points: the check that guards every library call that fails on degenerate
// geometry (Qhull's hull and Delaunay on planar or collinear points, KD-trees and voxel grids on points
// of no extent or of an extent beyond what an int index can count).
#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

namespace partloc {

struct Extent {
    std::size_t points = 0;                            ///< how many were measured (finite ones)
    Eigen::Vector3d center = Eigen::Vector3d::Zero();  ///< mean of the points
    double size = 0.0;       ///< the largest standard deviation along a principal axis (length)
    double width = 0.0;      ///< the middle one: 0 for collinear points
    double thickness = 0.0;  ///< the smallest one: 0 for planar points
    double max_abs = 0.0;    ///< the largest absolute coordinate
    double diagonal = 0.0;   ///< of the axis-aligned bounding box
    /// 0 (one point, or all identical), 1 (on a line), 2 (in a plane) or 3: a direction counts when its
    /// spread is more than `relative_tolerance` (1e-6) of the largest.
    int rank = 0;
};

/// Extent and rank of `points`; non-finite points are left out. Computed about the mean, in long double
/// where the sums could lose the spread of points far from the origin.
Extent extent_of(const std::vector<Eigen::Vector3d>& points, double relative_tolerance = 1e-6);

/// What keeps points of rank < `min_rank` from being what an algorithm needs, as a phrase that can follow a
/// file's name ("all 500 points are one and the same point", "its points lie on one line", "its points lie
/// in one plane (thickness 1e-09 against a size of 14.4)"); empty when the rank is enough.
std::string rank_problem(const Extent& e, int min_rank = 3);

/// Removes the points (and their normals, when there is one per point) that lie farther from the points'
/// median than `factor` times the diagonal of the box that holds the middle 98 % of them on each axis (a
/// single point at 1e9 in a scan of 200 mm, say). Returns how many were removed; a cloud without such
/// points is left as it is, bit for bit.
std::size_t remove_far_points(std::vector<Eigen::Vector3d>& points, std::vector<Eigen::Vector3d>& normals,
                              double factor = 100.0);

}  // namespace partloc
