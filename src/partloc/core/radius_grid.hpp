#pragma once
// Every point of a scan within a distance of a centre: the query the fits make to take the points around a
// fiducial (tens of thousands of a scan's hundreds of thousands), a few hundred times per scan.
//
// Ours instead of Open3D's KDTreeFlann: building the tree on a scan of 250 k points cost 0.08 s, a third of
// what the whole query work then took (issue 3, seed 106: 0.49 s of trees for six scans), where these cells
// take two passes over the points. The answer is the same set, in ascending index order.
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "partloc/core/sample_grid.hpp"

namespace partloc {

class RadiusGrid {
  public:
    RadiusGrid() = default;
    /// `cell`: about a tenth of the radii to be asked (any positive value gives exact answers); it grows when
    /// the points' box would need more than about two million cells.
    RadiusGrid(const std::vector<Eigen::Vector3d>& points, double cell);

    /// Indices of the points closer than `radius` to `centre` (strictly), ascending, into `out`; unsorted
    /// (in the grid's order, the same on every call) where the caller does not need them ascending.
    void within(const Eigen::Vector3d& centre, double radius, std::vector<int>& out,
                bool sorted = true) const;

    std::size_t size() const { return points_.size(); }

  private:
    std::vector<Eigen::Vector3d> points_;  // in cell order
    std::vector<std::uint32_t> index_;     // their indices in the caller's array
    CellFrame frame_;
    std::vector<std::uint32_t> start_;  // points of cell c: [start_[c], start_[c+1])
};

}  // namespace partloc
