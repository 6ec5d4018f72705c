#pragma once
// Approximate nearest-sample lookup for the coarse stages of a fit, where a pose is still off by degrees and
// any sample on the right face gives the right plane. Space around the samples is cut into cubic cells, and
// each cell holds a sample near its centre, found when the map is built: every sample seeds its own cell,
// and the seeds spread to the neighbouring cells, each keeping the nearest that reaches it (a vector
// propagation: within a fraction of a cell of the exact nearest sample). A query is then one memory read
// per point instead of a search of 27 cells.
//
// Ours because neither Open3D nor nanoflann offers an approximate search of this kind. Measured (issue 3,
// BENCHMARK.md): the screening of a scan's global-fit candidates, about 20 Gauss-Newton iterations on 1500
// points each for some 60 candidates per scan, spent 6.9 s of the 28 s of seed 106 in exact searches.
// Filling the cells on first use instead (an exact search from the cell's centre) still cost 1.2 s there:
// a cell far from the surface makes the exact search visit thousands of grid cells.
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "partloc/core/sample_grid.hpp"

namespace partloc {

class NearestMap {
  public:
    /// Cells of size `cell` over the samples' bounding box grown by `reach`; a cell whose centre has no
    /// sample within `reach` answers -1. The cell grows if the box would need more than 16 million cells.
    NearestMap(const std::vector<Eigen::Vector3d>& points, double cell, double reach);
    /// A map as built before (frame(), reach(), cells() of one built from `samples` points), e.g. read back
    /// from the model cache. Throws std::invalid_argument when the parts do not fit together: the cell
    /// count is not the frame's, or a cell names a sample outside [0, samples).
    NearestMap(const CellFrame& frame, double reach, std::vector<std::int32_t> cells, std::size_t samples);

    /// A sample near the centre of p's cell (at most a fraction of a cell farther from it than the nearest
    /// sample), or -1. Thread-safe (read only).
    int nearest(const Eigen::Vector3d& p) const;

    double cell_size() const { return frame_.cell; }
    double reach() const { return reach_; }
    const CellFrame& frame() const { return frame_; }
    /// Each cell's sample, -1 for none (the frame's cell order).
    const std::vector<std::int32_t>& cells() const { return nearest_; }

  private:
    CellFrame frame_;
    double reach_ = 0.0;
    std::vector<std::int32_t> nearest_;  // per cell; -1: none within reach
};

}  // namespace partloc
